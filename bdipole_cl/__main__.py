"""``python -m bdipole_cl``: the command line (bdipole_cl/apps/cli.py)."""
import sys

from .apps.cli import main

sys.exit(main())
