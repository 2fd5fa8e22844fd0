"""Demonstrations of drivers with known styles that several learner test modules fit (tests/learners,
tests/evaluation, tests/core): plain functions; the module fixtures built from them (``styles_data``, ``fitted``,
``three_styles``) are in tests/conftest.py, the test modules' ``passage`` fixtures call `roundabout_passages`; and
`assert_pirl_gmm_finds_the_styles`, the simulated scenarios' clustering check (tests/scenarios/highway, sumo). Test
modules ``from style_demos import ...`` (tests/conftest.py puts tests/ on sys.path)."""

import numpy as np

STYLE_Q = np.array([0.1, 1.0, 10.0])  # normalised state_sq weight of each style (control_sq = 1)


def three_style_population(model, rationality):
    """Three LQ styles, calm, normal and eager (state_sq weight `STYLE_Q`, 10 % spread), equally likely."""
    from pirl_sim.population import Population, Style

    styles = tuple(Style(name, 1.0, {"state_sq": q}, {"state_sq": 0.1 * q})
                   for name, q in zip(("calm", "normal", "eager"), STYLE_Q))
    return Population(model.features, styles, rationality)


def three_style_demonstrations(seed, n, n_steps, n_train):
    """(model, train, test): ``n`` Boltzmann-rational (rationality 100) drivers of `three_style_population` on the
    synthetic model from spread start states, ``n_steps`` steps each, the first ``n_train`` for training."""
    from pirl_sim.model import synthetic_model
    from pirl_sim.population import generate_demonstrations

    model = synthetic_model()
    rng = np.random.default_rng(seed)
    x0 = np.column_stack([rng.uniform(2.0, 8.0, n), rng.uniform(-1.0, 1.0, n)])
    demos = generate_demonstrations(model, three_style_population(model, 100.0), x0, n_steps, rng)
    return model, demos[:n_train], demos[n_train:]


def roundabout_passages(n_trajectories=240, n_train=200, seed=1, **config):
    """A generated roundabout passage (`pirl_sim.scenarios.passage.generate`: drivers of its known styles), its
    UserWarnings silenced: ``n_trajectories`` passages, the first ``n_train`` for training; ``config``: other
    `PassageConfig` fields."""
    import warnings

    from pirl_sim.scenarios.passage import PassageConfig, generate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return generate(PassageConfig(n_trajectories=n_trajectories, n_train=n_train, seed=seed, **config))


def assert_pirl_gmm_finds_the_styles(demos, routes, ground_truth, dt, ari_target):
    """``demos``, a simulated scenario's PIRL tracks without interaction, are at least 24, at least 5 of each of the
    three styles, and PIRL-GMM with three components (on `route_set_model` of ``routes`` at step ``dt`` [s]) clusters
    them into their true styles with an adjusted Rand index >= ``ari_target``; prints the counts (``ground_truth``:
    the recording's table of all tracks) and the index."""
    import warnings

    from pirl_sim.learners import PIRLGMM
    from pirl_sim.metrics import adjusted_rand_index
    from pirl_sim.scenarios.drivers import route_set_model

    truth = np.array([d.metadata["style"] for d in demos])
    counts = np.bincount(truth, minlength=3)
    print(f"\n{len(ground_truth)} tracks, {int(ground_truth['is_pirl'].sum())} PIRL, {len(demos)} without "
          f"interaction (per style {counts.tolist()})")
    assert len(demos) >= 24 and counts.min() >= 5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # IRL convergence warnings: weights are not what this test checks
        gmm = PIRLGMM(route_set_model(routes, dt=dt), n_components=3, random_state=0).fit(demos)
    ari = adjusted_rand_index(truth, gmm.labels_)
    print(f"ARI of PIRL-GMM (k=3) clusters vs the true styles: {ari:.3f}")
    assert ari >= ari_target


def _phase(model, x0, theta, n):
    return model.predict_states(np.atleast_2d(x0), np.atleast_2d(theta), n)[0]


def switching_drivers(model, rng, n=40):
    """Point mass regulated to 0: gently (q/r = 0.05) for 20 steps, then hard (q/r = 20) for 20 more, each
    phase the optimum of its own cost from where the last one ended."""
    from pirl_sim.trajectory import Trajectory

    out = []
    for _ in range(n):
        x0 = np.array([rng.uniform(1.0, 3.0), 0.0])
        a = _phase(model, x0, [0.05, 1.0], 20)
        b = _phase(model, a[-1], [20.0, 1.0], 20)
        states = np.vstack([a, b[1:]])
        controls = np.diff(states[:, 1])[:, None] / model.dynamics.dt
        out.append(Trajectory(states, controls, model.dynamics.dt))
    return out
