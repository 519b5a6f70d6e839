"""``python -m scrppl`` runs the command-line program."""

import sys

from scrppl.cli import main

sys.exit(main())
