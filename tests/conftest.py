import os
import sys
from pathlib import Path

import numpy as np
import pytest

from pirl_sim.model import synthetic_model

# One OpenMP thread in the test process: scikit-learn's gradient boosting (PIRL-select's forecast, the direct
# regression) runs OpenMP threads that spin in barriers, and on a loaded 2-core machine two of them made single
# tests take minutes instead of seconds. Sweep cells limit every runtime to one thread themselves
# (`pirl_sim.engine.worker`); BLAS stays as it is here (tests/engine/test_worker.py checks cells restore it).
import sklearn.ensemble  # noqa: E402,F401  loads the OpenMP runtime, so that the limit applies to it
from threadpoolctl import threadpool_limits  # noqa: E402

threadpool_limits(limits=1, user_api="openmp")

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


# Scenes that several test modules replay, built once per session by the helpers of tests/replay_scenes.py (read
# them, never write into them: every module shares the same files).
@pytest.fixture(scope="session")
def passage_scene(tmp_path_factory):
    """(directory, PassageData) of a generated 160-passage scene (seed 4) written as a pirl_sim recording."""
    import replay_scenes

    return replay_scenes.passage_scene(tmp_path_factory.mktemp("scene"))


@pytest.fixture(scope="session")
def passage_root(tmp_path_factory):
    """A simulated roundabout scene laid out as an INTERACTION folder (recorded_trackfiles/NAME, maps/NAME.osm)."""
    import replay_scenes

    return replay_scenes.passage_root(tmp_path_factory.mktemp("root"))


@pytest.fixture(scope="session")
def replay_out(tmp_path_factory):
    """A small `pirl-sim replay` (one split seed, TIRL and the baselines) on a generated passage scene
    (``replay_out.parent / "scene"``)."""
    import replay_scenes

    return replay_scenes.small_replay(tmp_path_factory.mktemp("replay"))


@pytest.fixture(scope="session")
def sumo_recording_result(tmp_path_factory):
    """(result, directory) of a small SUMO run written as a recording (`replay_scenes.run_small_sumo`)."""
    import replay_scenes

    out = tmp_path_factory.mktemp("receding_replay") / "run"
    return replay_scenes.run_small_sumo(out), out


@pytest.fixture(scope="session")
def sumo_recording(sumo_recording_result):
    """The directory of the small SUMO recording (20 vehicles, drivers re-planning over 30 steps of 0.1 s)."""
    return sumo_recording_result[1]


@pytest.fixture
def real_like(tmp_path):
    """One straight lane and six tracks, no run.json: data as real data come (`replay_scenes.real_like_scene`)."""
    import replay_scenes

    return replay_scenes.real_like_scene(tmp_path)


@pytest.fixture
def small_recording():
    """A three-track `ScenarioRecording` in memory (`replay_scenes.make_recording`)."""
    import replay_scenes

    return replay_scenes.make_recording()


# Learners fitted on drivers of three known styles (tests/style_demos.py), built once per test module that uses
# them (tests/learners/test_base.py, tests/evaluation/test_protocols.py).
@pytest.fixture(scope="module")
def styles_data():
    """(model, train, test): 200 Boltzmann-rational LQ drivers of three styles (q = 0.1, 1, 10; 10 % spread) from
    spread starts, 30 steps each, the first 160 for training (`style_demos.three_style_demonstrations`, seed 3)."""
    import style_demos

    return style_demos.three_style_demonstrations(3, 200, 30, 160)


@pytest.fixture(scope="module")
def styles_learners(styles_data):
    """{name: learner} fitted on `styles_data`'s training set on its first 10 steps: TIRL, PIRL-GMM in weight and
    in feature space, PIRL-DPGMM in weight space, PIRL-kNN (k = 10) weighted by likelihood and by distance."""
    import warnings

    from pirl_sim.learners import PIRLDPGMM, PIRLGMM, PIRLKNN, TIRL

    model, train, _ = styles_data
    common = {"window": 10, "windows": "first"}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return {
            "tirl": TIRL(model, **common).fit(train),
            "gmm-weights": PIRLGMM(model, n_components=3, random_state=0, space="weights", **common).fit(train),
            "gmm-features": PIRLGMM(model, n_components=3, random_state=0, **common).fit(train),
            "dpgmm-weights": PIRLDPGMM(model, random_state=0, space="weights", **common).fit(train),
            "knn-likelihood": PIRLKNN(model, n_neighbors=10, weighting="likelihood", **common).fit(train),
            "knn-distance": PIRLKNN(model, n_neighbors=10, **common).fit(train),
        }


@pytest.fixture(scope="module")
def route_set(tmp_path_factory):
    """The SUMO roundabout's default paths on one arc-length axis (the default network built once per module):
    geometry smoothed by 2 m, curvature for the desired speed by 10 m. Needs sumolib."""
    from pirl_sim.scenarios.sumo import DEFAULT_NETWORK, build_network, routes
    from pirl_sim.scenarios.sumo.network import route_set as network_route_set

    net = build_network(DEFAULT_NETWORK, tmp_path_factory.mktemp("roundabout"))
    return network_route_set(net, routes(DEFAULT_NETWORK), smoothing=2.0, speed_smoothing=10.0)
