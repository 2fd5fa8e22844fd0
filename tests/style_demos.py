"""Demonstrations of drivers with known styles that several learner test modules fit (tests/learners,
tests/evaluation): plain functions; the module fixtures built from them (``styles_data``, ``fitted``,
``three_styles``) are in tests/conftest.py. Test modules ``from style_demos import ...`` (tests/conftest.py puts
tests/ on sys.path)."""

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
