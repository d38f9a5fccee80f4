"""``python -m planner.cli``: the ``shockplan`` program."""

import sys

from planner.cli import main

sys.exit(main())
