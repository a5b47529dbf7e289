"""``python -m drive_cli``: the ``drive`` command (drive_cli.entry)."""
import sys

from .entry import main

sys.exit(main())
