"""``python -m canguard``."""

import sys

from canguard.cli.main import main

sys.exit(main())
