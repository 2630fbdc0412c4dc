"""``python -m fracref``: the command line."""

import sys

from fracref.cli import main

sys.exit(main())
