"""``python -m pirl_sim.sweep sweep CONFIG`` / ``python -m pirl_sim.sweep report RESULTS``."""

import sys

from pirl_sim.sweep.cli import main

if __name__ == "__main__":
    sys.exit(main())
