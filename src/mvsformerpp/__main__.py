import sys

from mvsformerpp.cli import main

sys.exit(main())
