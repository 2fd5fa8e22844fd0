"""End to end: a SUMO roundabout population of three styles -> recorded files -> PIRL-GMM -> the styles back."""

import warnings

import numpy as np
import pytest

pytest.importorskip("libsumo")
pytest.importorskip("lanelet2")

from pirl_sim.learners import PIRLGMM  # noqa: E402
from pirl_sim.metrics import adjusted_rand_index  # noqa: E402
from pirl_sim.scenarios.drivers import route_set_model  # noqa: E402
from pirl_sim.scenarios.sumo import SumoScenarioConfig, load_sumo_run, run_sumo_scenario  # noqa: E402

ARI_TARGET = 0.8  # the target; measured 1.0 for seeds 0-7 of this configuration
LEARNING_DT = 0.2  # [s] the learner's model step (see the test's docstring)


@pytest.mark.slow
def test_pirl_gmm_recovers_the_three_styles_from_a_sumo_population(tmp_path):
    """The default scenario (80 vehicles: the paper's three styles in equal shares, 20 % SUMO background
    traffic, one every 4 s, on the default 4-arm roundabout), recorded to disk and read back through the
    replay path; the non-interacting PIRL tracks become (s, v, a) demonstrations on their routes' paths
    (``fit_longitudinal_states``), and PIRL-GMM with three components clusters them.

    The learner's model runs at 0.2 s (every second 100 ms frame): its clustering uses the mean features,
    which barely depend on the step, but its IRL (part of ``fit``) costs ~0.1 s per demonstration of 300
    steps at 0.1 s (~160 s here, ARI also 1.0 for seed 0) and ~5-40 s at 0.2 s.
    """
    res = run_sumo_scenario(SumoScenarioConfig(), seed=0, out_dir=tmp_path)
    run = load_sumo_run(tmp_path)
    demos = run.demonstrations(dt=LEARNING_DT)  # PIRL tracks without interaction, collision or removal
    truth = np.array([d.metadata["style"] for d in demos])
    counts = np.bincount(truth, minlength=3)
    gt = res.recording.ground_truth
    print(f"\n{len(gt)} tracks, {int(gt['is_pirl'].sum())} PIRL, {len(demos)} without interaction "
          f"(per style {counts.tolist()})")
    assert len(demos) >= 24 and counts.min() >= 5
    assert all(not d.metadata["interacted"] for d in demos)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # IRL convergence warnings: weights are not what this test checks
        gmm = PIRLGMM(route_set_model(run.routes, dt=LEARNING_DT), n_components=3, random_state=0).fit(demos)
    ari = adjusted_rand_index(truth, gmm.labels_)
    print(f"ARI of PIRL-GMM (k=3) clusters vs the true styles: {ari:.3f}")
    assert ari >= ARI_TARGET
