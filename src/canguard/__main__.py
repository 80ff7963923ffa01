"""``python -m canguard``."""

import sys

from .cli import main

sys.exit(main())
