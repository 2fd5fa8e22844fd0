"""Recovery reports of known log errors that the tests of `pirl_sim.recovery` and `pirl_sim.testing` (tests/core)
check: one copy of the hand-made report. Test modules ``from recovery_reports import ...`` (tests/conftest.py puts
tests/ on sys.path)."""

import numpy as np

from pirl_sim.recovery import RecoveryReport

FEATURES = ("speed_dev", "acc_sq")


def error_report(errors, styles=None, **kwargs):
    """Tracks whose |log errors| are ``errors`` (n, 2) exactly: true weights 1..n, fitted true * exp(error)."""
    errors = np.asarray(errors, dtype=float)
    true = np.column_stack([np.arange(1.0, len(errors) + 1), np.full(len(errors), 0.5)])
    return RecoveryReport.from_weights(true, true * np.exp(errors), features=FEATURES, styles=styles, **kwargs)
