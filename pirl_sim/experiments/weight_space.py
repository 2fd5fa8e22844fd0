"""Feature-space against weight-space mixtures: the measurements behind
``results/weight_space/``.

``pirl-sim weight-space --out results/weight_space`` (7 min 25 s on one core at a load
average of ~6 from other jobs; ≈4 min before the random-start and MML rows) writes ``table.csv`` / ``table.md``
(one row per experiment, protocol and learner) and ``README.md``. Same seed, same bytes (no timings in the
files). Experiments:

- ``synthetic-spread``: the paper's synthetic problem with start states spread over p in [2, 8] m and v in
  [-1, 1] m/s (the README's ``reproduce synthetic --position-range 2 8 --velocity-range -1 1``: same
  configuration, same data), 1,800 train / 200 test, protocols paper and online (first 10 steps).
- ``synthetic``: the paper's single start (``reproduce synthetic``), weight-space learners beside the paper's.
- ``lq-3-styles``: Boltzmann-rational (beta = 100) LQ drivers of three styles, normalised state weight
  q ~ N(0.1, 0.01), N(1, 0.1), N(10, 1) (control weight 1), start states spread as above, 40 steps, 600 train /
  200 test. Per-style weight error: |log q_hat / q_style| of each learned style against the mean of the true
  style it is matched to (Hungarian on the training labels), worst over the styles.
- ``passage``: the roundabout passage of ``reproduce passage`` (three user-study styles, beta = 100,
  500 train / 100 test), protocols paper and online (first 10 steps = 2 s).
- PIRL-kNN with ``weighting="likelihood"`` (its neighbours vote by their likelihood of the history) beside the
  paper's inverse-distance votes; on the passage with ``prior="population"`` as ``reproduce passage``.
- Weight space without a fixed k or without the deconvolution: ``PIRL-DPGMM, weights`` is the Dirichlet-process
  mixture (`pirl_sim.deconvolution.dp_deconvolution`, truncated stick-breaking variational inference),
  ``PIRL-DPGMM, weights, MML`` the earlier stand-in (extreme deconvolution pruned by minimum message length);
  ``PIRL-GMM (k=K), weights, random start`` is Babeș-Vroman et al.'s hard EM over the IRL likelihoods from random
  equal-size clusters (``init="random"``, at most `RANDOM_START_PASSES` passes, 3 restarts; no per-demonstration
  posteriors), fitted under the paper protocol only (a weight-space fit does not depend on the protocol).
  ``em_passes``: passes of hard EM that moved labels (after the deconvolution: ``refine`` = 1 at most).
- ``lq-receding``: LQ drivers of the three styles (weights spread 10 % in log) who re-plan every step over 15
  steps with control noise 0.05 m/s^2 (`pirl_sim.simulate.simulate_receding_horizon`), 150 drivers of 30
  steps, receding-horizon likelihood.

Columns: ``ari`` of the training clusters against the true styles; ``style_accuracy`` of the most probable
style of each test history under `PIRLGMM.predict_proba` (p(style | history) from each style's likelihood) and,
for feature-space learners, ``feature_style_accuracy`` of the paper's feature look-up; ``style_error`` the
worst per-style weight error; ``med`` [m], ``weight_error`` (median per test trajectory) as
`pirl_sim.evaluation.protocols.evaluate`; online, ``min_ade`` / ``min_fde`` [m] over one future per style
(`PIRLGMM.predict_futures`, K = ``n_styles``; see `_min_over_styles`).

Multi-modal prediction, online rows of every learner: `evaluate` with ``n_futures=6``
(K = 6 futures asked for, seed ``--seed``): ``k_futures`` the number a learner returns (TIRL 1, a feature-space
mixture at most its styles, weight-space mixtures and PIRL-kNN 6 draws from their posterior over the weights),
``min_ade_6`` / ``min_fde_6`` [m], ``miss_rate_6`` (the INTERACTION challenge's rule) and ``nll_6`` [nats per
predicted step, Gaussian mixture of sigma 0.5 m around the futures]; definitions in `pirl_sim.metrics`. With
fewer than 6 futures the scores are those of the smaller set (the challenge accepts fewer than 6 modalities).

``futures.png``: the six futures of PIRL-GMM (k=3) in weight space after the first 2 s of the first test
passage (seed ``--seed``), on the passage's map (lane edges 1.75 m either side of the path), and their arc
length minus the true future's against time.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from pirl_sim.evaluation.protocols import PAPER_PROTOCOL, Protocol, evaluate, style_agreement
from pirl_sim.evaluation.tables import markdown
from pirl_sim.io.atomic import atomic_write_bytes, atomic_write_text
from pirl_sim.metrics import match_styles, weight_recovery_error

__all__ = ["run_study", "write_study", "lq_three_styles", "futures_figure"]

LQ_STYLE_Q = (0.1, 1.0, 10.0)  # normalised state_sq weight of each LQ style
RANDOM_START_PASSES = 50  # most passes of hard EM from random clusters (PIRL-GMM init="random")
N_FUTURES = 6  # K of the multi-modal scores (the INTERACTION challenge's number of modalities)
LANE_HALF_WIDTH = 1.75  # [m] drawn either side of the passage's path in futures.png
MULTIMODAL_COLUMNS = ("k_futures", "min_ade_6", "min_fde_6", "miss_rate_6", "nll_6")


def lq_three_styles(n: int, rationality: float, seed: int, n_steps: int = 40):
    """Boltzmann-rational LQ demonstrations of three styles from spread start states (module doc)."""
    from pirl_sim.model import synthetic_model
    from pirl_sim.population import Population, Style, generate_demonstrations

    model = synthetic_model()
    styles = tuple(Style(name, 1.0, {"state_sq": q}, {"state_sq": 0.1 * q})
                   for name, q in zip(("calm", "normal", "eager"), LQ_STYLE_Q))
    rng = np.random.default_rng(seed)
    x0 = np.column_stack([rng.uniform(2.0, 8.0, n), rng.uniform(-1.0, 1.0, n)])
    return model, generate_demonstrations(model, Population(model.features, styles, rationality), x0, n_steps, rng)


def _style_means(demos, n_styles: int, K: int) -> np.ndarray:
    """Mean normalised weights of each true style over the demonstrations (n_styles, K)."""
    theta = np.stack([d.metadata["theta"] for d in demos])
    style = np.array([d.metadata["style"] for d in demos])
    return np.stack([np.exp(np.log(theta[style == s]).mean(axis=0)) for s in range(n_styles)])


def _row(experiment, protocol, name, learner, train, test, style_means=None, seed: int = 0) -> dict:
    row = {"experiment": experiment, "protocol": protocol.name, "learner": name}
    multi = {"n_futures": N_FUTURES, "random_state": seed} if protocol.kind == "online" else {}
    scores = evaluate(learner, test, protocol, **multi)
    row.update({k: v for k, v in scores.items() if k in ("med", "fde", "weight_error")})
    for col in MULTIMODAL_COLUMNS:
        row[col] = scores.get(col.removesuffix("_6"), np.nan)
    ari = style_agreement(learner, train)
    row["ari"] = np.nan if ari is None else ari
    row["n_styles"] = getattr(learner, "n_styles_", 1)
    row["em_passes"] = getattr(learner, "n_refined_", np.nan)
    row["style_accuracy"] = row["feature_style_accuracy"] = row["style_error"] = np.nan
    row["min_ade"] = row["min_fde"] = np.nan
    if hasattr(learner, "predict_proba") and all("style" in t.metadata for t in test):
        to_true = match_styles(np.array([t.metadata["style"] for t in train]), learner.labels_)
        truth = np.array([t.metadata["style"] for t in test])
        seen = test if protocol.kind == "paper" else [t.window(0, protocol.history_steps) for t in test]
        guess = learner.predict_proba(seen).argmax(axis=1)
        row["style_accuracy"] = float(np.mean([to_true.get(int(j), -1) == s for j, s in zip(guess, truth)]))
        if learner.space == "features":
            look = learner.predict_style(seen)
            row["feature_style_accuracy"] = float(np.mean([to_true.get(int(j), -1) == s for j, s in zip(look, truth)]))
        if protocol.kind == "online":
            row.update(_min_over_styles(learner, test, protocol.history_steps))
        if style_means is not None:
            ref = learner.model_.features.reference_index
            row["style_error"] = float(max(weight_recovery_error(learner.theta_[j], style_means[s], ref)
                                           for j, s in to_true.items()))
    return row


def _min_over_styles(learner, test, history: int) -> dict:
    """minADE_K and minFDE_K [m] with one future per style (K = n_styles_, `PIRLGMM.predict_futures`): per test
    trajectory the smallest over the K futures of the mean (ADE) and of the last (FDE) Euclidean position error
    over the predicted steps, averaged over the test trajectories (the usual definitions, as in the INTERACTION
    and Argoverse prediction benchmarks); all K = n_styles_ futures are the learner's own, so K differs between learners (its ``n_styles``)."""
    from pirl_sim.metrics import euclidean_errors

    model = learner.model_
    lengths = np.array([t.n_steps for t in test])
    ade, fde = np.empty(len(test)), np.empty(len(test))
    for n in np.unique(lengths):
        idx = np.flatnonzero(lengths == n)
        futures, _ = learner.predict_futures([test[i].window(0, history) for i in idx], int(n) - history)
        truth = np.stack([test[i].states[history + 1:] for i in idx])  # (m, H, n_x)
        pred = model.positions(futures[:, :, 1:])  # (m, K, H, P)
        err = euclidean_errors(pred, np.broadcast_to(model.positions(truth)[:, None], pred.shape))  # (m, K, H)
        ade[idx] = err.mean(axis=2).min(axis=1)
        fde[idx] = err[:, :, -1].min(axis=1)
    return {"min_ade": float(ade.mean()), "min_fde": float(fde.mean())}


def _fit(key, params, train):
    from pirl_sim.learners import make_learner

    learner = make_learner(key, **params)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # dropped tiny components, IRL notes: counted in the table
        return learner.fit(train)


def run_study(seed: int = 0, say=lambda m: None, figures: dict | None = None) -> pd.DataFrame:
    """All experiments of the module doc; one row per (experiment, protocol, learner). ``figures``, a dict,
    receives {file name: PNG bytes} of the study's figures."""
    from pirl_sim.scenarios.passage import PassageConfig, generate as generate_passage
    from pirl_sim.scenarios.synthetic import SyntheticConfig, generate as generate_synthetic
    from pirl_sim.simulate import simulate_receding_horizon
    from pirl_sim.trajectory import Trajectory

    rows = []
    online = Protocol("online", 10)
    knn_pair = [("PIRL-kNN (k=10)", "pirl-knn", {"n_neighbors": 10}),
                ("PIRL-kNN (k=50), likelihood", "pirl-knn", {"n_neighbors": 50, "weighting": "likelihood"})]
    def mixtures(k, protocol=PAPER_PROTOCOL):  # the learners compared in every experiment
        out = [
            (f"PIRL-GMM (k={k}), features", "pirl-gmm", {"n_components": k, "random_state": seed}),
            (f"PIRL-GMM (k={k}), weights", "pirl-gmm", {"n_components": k, "random_state": seed, "space": "weights"}),
            ("PIRL-DPGMM, features", "pirl-dpgmm", {"random_state": seed}),
            ("PIRL-DPGMM, weights", "pirl-dpgmm", {"random_state": seed, "space": "weights"}),
            ("PIRL-DPGMM, weights, MML", "pirl-dpgmm", {"random_state": seed, "space": "weights",
                                                        "weight_mixture": "mml"}),
        ]
        if protocol.kind == "paper":  # the fit does not depend on the protocol: its clusters once
            out.append((f"PIRL-GMM (k={k}), weights, random start", "pirl-gmm",
                        {"n_components": k, "random_state": seed, "space": "weights", "init": "random",
                         "refine": RANDOM_START_PASSES}))
        return out
    # the paper's synthetic problem, spread starts and the single start
    for experiment, ranges in (("synthetic-spread", {"position_range": (2.0, 8.0), "velocity_range": (-1.0, 1.0)}),
                               ("synthetic", {})):
        data = generate_synthetic(SyntheticConfig(seed=seed, **ranges))
        specs = [("TIRL", "tirl", {}), ("PIRL-kNN (k=1)", "pirl-knn", {"n_neighbors": 1}),
                 ("PIRL-kNN (k=50), likelihood", "pirl-knn", {"n_neighbors": 50, "weighting": "likelihood"})]
        for protocol in (PAPER_PROTOCOL, online):
            for name, key, params in specs + mixtures(2, protocol):
                learner = _fit(key, {"model": data.model, **params, **protocol.learner_params()}, data.train)
                rows.append(_row(experiment, protocol, name, learner, data.train, data.test, seed=seed))
                say(f"{experiment} {protocol.name} {name}: MED {rows[-1]['med']:.4g} ARI {rows[-1]['ari']:.3g}")
    # three LQ styles, Boltzmann-rational, spread starts
    model, demos = lq_three_styles(800, 100.0, seed)
    train, test = demos[:600], demos[600:]
    means = _style_means(train, 3, model.features.n_features)
    for protocol in (PAPER_PROTOCOL, online):
        for name, key, params in [("TIRL", "tirl", {}), *knn_pair] + mixtures(3, protocol):
            learner = _fit(key, {"model": model, **params, **protocol.learner_params()}, train)
            rows.append(_row("lq-3-styles", protocol, name, learner, train, test, means, seed))
            say(f"lq-3-styles {protocol.name} {name}: ARI {rows[-1]['ari']:.3g} "
                f"style error {rows[-1]['style_error']:.3g}")
    # the roundabout passage
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        passage = generate_passage(PassageConfig(seed=seed))
    means = _style_means(passage.train, 3, passage.model.features.n_features)
    for protocol in (PAPER_PROTOCOL, online):
        for name, key, params in [("TIRL", "tirl", {}), *knn_pair] + mixtures(3, protocol):
            if key == "pirl-knn":
                params = {**params, "prior": "population"}  # as reproduce passage
            learner = _fit(key, {"model": passage.model, **params, **protocol.learner_params()}, passage.train)
            rows.append(_row("passage", protocol, name, learner, passage.train, passage.test, means, seed))
            if figures is not None and protocol.kind == "online" and name == "PIRL-GMM (k=3), weights":
                figures["futures.png"] = futures_figure(learner, passage.test[0], protocol.history_steps, seed)
            say(f"passage {protocol.name} {name}: MED {rows[-1]['med']:.4g} ARI {rows[-1]['ari']:.3g}")
    # LQ drivers who re-plan, receding-horizon likelihood
    rng = np.random.default_rng(seed)
    style = np.repeat([0, 1, 2], 50)
    q = np.asarray(LQ_STYLE_Q)[style] * np.exp(rng.normal(0.0, 0.1, style.size))
    x0 = np.column_stack([rng.uniform(2.0, 8.0, style.size), rng.uniform(-1.0, 1.0, style.size)])
    theta = np.column_stack([q, np.ones_like(q)])
    drivers = [Trajectory(d.states, d.controls, d.dt, {**d.metadata, "style": int(s), "theta": th})
               for d, s, th in zip(simulate_receding_horizon(model, x0, theta, 30, 15, rng=rng, control_noise=0.05),
                                   style, theta)]
    order = rng.permutation(style.size)
    train, test = [drivers[i] for i in order[:120]], [drivers[i] for i in order[120:]]
    means = np.array([[qs, 1.0] for qs in LQ_STYLE_Q])
    for name, key, params in mixtures(3):
        learner = _fit(key, {"model": model, "likelihood": "receding", "horizon": 15, **params}, train)
        rows.append(_row("lq-receding", PAPER_PROTOCOL, name, learner, train, test, means))
        say(f"lq-receding {name}: ARI {rows[-1]['ari']:.3g}")
    cols = ["experiment", "protocol", "learner", "med", "fde", "weight_error", "ari", "n_styles", "em_passes",
            "style_accuracy",
            "feature_style_accuracy", "style_error", "min_ade", "min_fde", *MULTIMODAL_COLUMNS]
    return pd.DataFrame(rows)[cols]


def futures_figure(learner, trajectory, history_steps: int, seed: int) -> bytes:
    """PNG bytes: the `N_FUTURES` futures ``learner.predict_futures`` draws (seed ``seed``) after the first
    ``history_steps`` steps of ``trajectory`` on a path model's map, and arc length s [m] against time [s].

    Left: lane edges `LANE_HALF_WIDTH` either side of the model's path (its map), the observed history, the
    true future and each predicted future, with markers every second; right: each future's arc length minus the
    true one [m] against time [s].
    """
    from pirl_sim.evaluation.figures import png_bytes, pyplot

    model = learner.model_
    if not hasattr(model, "path"):
        raise TypeError(f"futures_figure draws on a path model's map, got a {type(model).__name__}")
    horizon = trajectory.n_steps - history_steps
    states, proba = learner.predict_futures(trajectory.window(0, history_steps), horizon, n_futures=N_FUTURES,
                                            random_state=np.random.default_rng(seed))
    dt = model.dynamics.dt
    t = np.arange(trajectory.n_steps + 1) * dt
    every = max(1, int(round(1.0 / dt)))  # a marker every second
    plt = pyplot()
    fig, (ax_map, ax_s) = plt.subplots(1, 2, figsize=(11, 4.8), gridspec_kw={"width_ratios": [1.2, 1]})
    s_all = np.linspace(0.0, model.path.length, 600)
    for d in (-LANE_HALF_WIDTH, LANE_HALF_WIDTH):
        edge = model.path.to_cartesian(s_all, np.full_like(s_all, d))
        ax_map.plot(edge[:, 0], edge[:, 1], color="0.6", lw=1)
    centre = model.path.to_cartesian(s_all, np.zeros_like(s_all))
    ax_map.plot(centre[:, 0], centre[:, 1], color="0.8", lw=0.8, ls="--")
    seen = model.positions(trajectory.states[: history_steps + 1])
    true = model.positions(trajectory.states[history_steps:])
    colours = plt.get_cmap("tab10")(np.arange(len(proba)) % 10)
    order = np.argsort(-proba, kind="stable")
    s_true = trajectory.states[history_steps:, 0]
    for rank, k in enumerate(order):
        xy = model.positions(states[k])
        label = f"future {rank + 1}, p = {proba[k]:.2f}"
        ax_map.plot(xy[:, 0], xy[:, 1], color=colours[rank], lw=1.2, alpha=0.8)
        ax_map.plot(xy[::every, 0], xy[::every, 1], "o", ms=4, color=colours[rank], alpha=0.8)
        ax_s.plot(t[history_steps:], states[k][:, 0] - s_true, color=colours[rank], lw=1.5, label=label)
    ax_map.plot(seen[:, 0], seen[:, 1], "k-", lw=2.5, label=f"observed ({history_steps * dt:g} s)")
    ax_map.plot(true[::every, 0], true[::every, 1], "kx", ms=7, mew=2, label="true future")
    ax_s.axhline(0.0, color="k", ls="--", lw=2, label="true future")
    pts = np.vstack([seen, true, model.positions(states.reshape(-1, states.shape[-1]))])
    lo, hi = pts.min(axis=0) - 6.0, pts.max(axis=0) + 6.0
    ax_map.set_xlim(lo[0], hi[0])
    ax_map.set_ylim(lo[1], hi[1])
    ax_map.set_aspect("equal")
    ax_map.set_xlabel("x [m]")
    ax_map.set_ylabel("y [m]")
    ax_map.set_title("on the map (markers every 1 s)")
    ax_map.legend(fontsize=8, loc="upper left")
    ax_s.set_xlabel("time [s]")
    ax_s.set_ylabel("predicted minus true arc length [m]")
    ax_s.set_title(f"along the path, after the first {history_steps * dt:g} s")
    ax_s.legend(fontsize=8, loc="best")
    fig.suptitle(f"{len(proba)} futures of one passage, weights drawn from the style mixture (seed {seed})")
    fig.tight_layout()
    return png_bytes(fig)


def _readme(table: pd.DataFrame, command: str) -> str:
    return (
        "# Mixtures in feature space and in weight space\n\n"
        f"Written by `{command}` (pirl_sim/experiments/weight_space.py; its docstring describes every experiment "
        "and column).\n\n" + markdown(table)
        + "\n`futures.png`: the six futures of PIRL-GMM (k=3) in weight space after the first 2 s of the first test "
        "passage, with the true future (module docstring).\n"
    )


def write_study(table: pd.DataFrame, figures: dict, out, command: str) -> None:
    """Write ``table.csv``, ``table.md``, the figures {file name: PNG bytes} and ``README.md`` into ``out``."""
    for name, png in figures.items():
        atomic_write_bytes(out / name, png)
    atomic_write_text(out / "table.csv", table.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out / "table.md", markdown(table))
    atomic_write_text(out / "README.md", _readme(table, command))
