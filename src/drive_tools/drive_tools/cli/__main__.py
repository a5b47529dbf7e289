"""``python -m drive_tools.cli``: the ``drive`` command (drive_tools.cli.entry)."""
import sys

from .entry import main

sys.exit(main())
