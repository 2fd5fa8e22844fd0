"""``python -m pirl_sim.sweep sweep CONFIG`` / ``python -m pirl_sim.sweep report RESULTS``: the ``pirl-sim``
command line (`pirl_sim.cli.main`), whose ``sweep`` and ``report`` these are."""

import sys

from pirl_sim.cli import main

if __name__ == "__main__":
    sys.exit(main())
