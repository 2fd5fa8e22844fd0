"""``python -m pirl_sim`` runs the ``pirl-sim`` command line."""

import sys

from .cli import main

sys.exit(main())
