import os
import sys
from pathlib import Path

import numpy as np
import pytest

from pirl_sim.model import synthetic_model

# The tests mirror the package (tests/<package path>/test_<module>.py) and run with --import-mode=importlib,
# which puts no test folder on sys.path: the folders of the helper modules go there, and the test modules
# import the helpers by their unique names (shared_sample, viz_testdata).
_TESTS = Path(__file__).resolve().parent
for _folder in (_TESTS / "viz", _TESTS):
    if str(_folder) not in sys.path:
        sys.path.insert(0, str(_folder))

# Under CI (CI=true, as GitHub Actions and most CI services set it) every optional extra is installed
# (pip install -e ".[test]"), so a test module's pytest.importorskip of one that fails to import is a broken
# install: it fails the run instead of turning into silent skips. Locally a missing extra still skips.
if os.environ.get("CI", "").strip().lower() in ("1", "true", "yes"):
    _importorskip = pytest.importorskip

    def _import_or_fail(modname, minversion=None, reason=None, **kwargs):
        try:
            return _importorskip(modname, minversion=minversion, reason=reason, **kwargs)
        except pytest.skip.Exception as exc:
            pytest.fail(f"CI=true: {modname!r} (an optional extra of the test install) cannot be imported: {exc}",
                        pytrace=False)

    pytest.importorskip = _import_or_fail

# Hypothesis fuzz tests draw the same examples on every run (derandomize): a suite that passes once passes
# again. Explore with fresh random examples by HYPOTHESIS_PROFILE=explore.
try:
    from hypothesis import settings as _hyp_settings

    _hyp_settings.register_profile("reproducible", derandomize=True)
    _hyp_settings.register_profile("explore", derandomize=False)
    _hyp_settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "reproducible"))
except ImportError:  # hypothesis is a test extra; without it the fuzz modules skip on their own
    pass


@pytest.fixture
def model():
    return synthetic_model(0.1)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
