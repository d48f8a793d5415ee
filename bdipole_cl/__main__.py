"""``python -m bdipole_cl``: the command line (bdipole_cl/apps/cli.py)."""
import sys

from .apps.cli import console_main

sys.exit(console_main())
