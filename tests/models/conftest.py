import sys
from pathlib import Path

# Let the tests here import their helper module (parity_utils) under pytest's importlib mode.
sys.path.insert(0, str(Path(__file__).parent))
