import sys

from mvsformerpp.cli import entry

sys.exit(entry())
