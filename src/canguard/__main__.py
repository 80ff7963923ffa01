"""``python -m canguard``."""

import sys

from canguard.cli.main import console

sys.exit(console())
