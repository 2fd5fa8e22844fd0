"""Feature-space against weight-space mixtures: the measurements behind ``results/weight_space/``.

``pirl-sim weight-space --out results/weight_space`` runs the study through the engine as the kind
``weight-space`` (`SPEC`; a cell: one learner fitted to one experiment's data of one seed and scored under one
protocol, a row of the table; `study_config` lists them; finished cells are kept in ``OUT/cells``).
`experiment_data` builds the data of the experiments `EXPERIMENTS`; `write_study` writes ``table.csv`` /
``table.md``, ``README.md`` and `futures_figure`'s ``futures.png``.

The experiments, learners and columns are explained in the documentation's "Weight recovery on simulated runs"
page (mixtures in weight space).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
import warnings

import numpy as np
import pandas as pd

from pirl_sim.evaluation.protocols import PAPER_PROTOCOL, Protocol, evaluate, style_agreement
from pirl_sim.evaluation.tables import markdown
from pirl_sim.io.atomic import atomic_write_bytes, atomic_write_text
from pirl_sim.metrics import match_styles, weight_recovery_error

from .spec import Param, ScenarioSpec, TrainShape

__all__ = ["EXPERIMENTS", "SPEC", "study_config", "experiment_data", "futures_figure", "write_study"]

#: the study's experiments (module doc) and their training-set sizes
EXPERIMENTS = {"synthetic-spread": 1800, "synthetic": 1800, "lq-3-styles": 600, "passage": 500, "lq-receding": 120}
LQ_STYLE_Q = (0.1, 1.0, 10.0)  # normalised state_sq weight of each LQ style
RANDOM_START_PASSES = 50  # most passes of hard EM from random clusters (PIRL-GMM init="random")
N_FUTURES = 6  # K of the multi-modal scores (the INTERACTION challenge's number of modalities)
LANE_HALF_WIDTH = 1.75  # [m] drawn either side of the passage's path in futures.png
FIGURE_LEARNER = "PIRL-GMM (k=3), weights"  # whose futures of the first test passage futures.png draws
ONLINE = Protocol("online", 10)  # the first 10 steps observed
MULTIMODAL_COLUMNS = ("k_futures", "min_ade_6", "min_fde_6", "miss_rate_6", "nll_6")
COLUMNS = ("experiment", "protocol", "learner", "med", "fde", "weight_error", "ari", "n_styles", "em_passes",
           "style_accuracy", "feature_style_accuracy", "style_error", "min_ade", "min_fde", *MULTIMODAL_COLUMNS)


def _style_means(demos, n_styles: int, K: int) -> np.ndarray:
    """Mean normalised weights of each true style over the demonstrations (n_styles, K)."""
    theta = np.stack([d.metadata["theta"] for d in demos])
    style = np.array([d.metadata["style"] for d in demos])
    return np.stack([np.exp(np.log(theta[style == s]).mean(axis=0)) for s in range(n_styles)])


@functools.lru_cache(maxsize=1)
def experiment_data(experiment: str, seed: int):
    """(model, train, test, mean weights per true style or None) of one experiment and seed (module doc); the
    last one is kept for the next cell."""
    from pirl_sim.model import synthetic_model
    from pirl_sim.population import Population, Style, generate_demonstrations
    from pirl_sim.scenarios.passage import PassageConfig, generate as generate_passage
    from pirl_sim.scenarios.synthetic import SyntheticConfig, generate as generate_synthetic
    from pirl_sim.simulate import simulate_receding_horizon
    from pirl_sim.trajectory import Trajectory

    if experiment.startswith("synthetic"):
        spread = {"position_range": (2.0, 8.0), "velocity_range": (-1.0, 1.0)} if experiment.endswith("spread") else {}
        data = generate_synthetic(SyntheticConfig(seed=seed, **spread))  # type: ignore[arg-type]
        return data.model, data.train, data.test, None
    model, rng = synthetic_model(), np.random.default_rng(seed)
    if experiment == "lq-3-styles":  # Boltzmann-rational, spread starts
        styles = tuple(Style(name, 1.0, {"state_sq": q}, {"state_sq": 0.1 * q})
                       for name, q in zip(("calm", "normal", "eager"), LQ_STYLE_Q))
        x0 = np.column_stack([rng.uniform(2.0, 8.0, 800), rng.uniform(-1.0, 1.0, 800)])
        demos = generate_demonstrations(model, Population(model.features, styles, 100.0), x0, 40, rng)
        return model, demos[:600], demos[600:], _style_means(demos[:600], 3, model.features.n_features)
    if experiment == "passage":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            data = generate_passage(PassageConfig(seed=seed))  # type: ignore[assignment]
        return data.model, data.train, data.test, _style_means(data.train, 3, data.model.features.n_features)
    style = np.repeat([0, 1, 2], 50)  # lq-receding: LQ drivers who re-plan
    q = np.asarray(LQ_STYLE_Q)[style] * np.exp(rng.normal(0.0, 0.1, style.size))
    x0 = np.column_stack([rng.uniform(2.0, 8.0, style.size), rng.uniform(-1.0, 1.0, style.size)])
    theta = np.column_stack([q, np.ones_like(q)])
    drivers = [Trajectory(d.states, d.controls, d.dt, {**d.metadata, "style": int(s), "theta": th})
               for d, s, th in zip(simulate_receding_horizon(model, x0, theta, 30, 15, rng=rng, control_noise=0.05),
                                   style, theta)]
    order = rng.permutation(style.size)
    return (model, [drivers[i] for i in order[:120]], [drivers[i] for i in order[120:]],
            np.array([[qs, 1.0] for qs in LQ_STYLE_Q]))


def _row(experiment, protocol, learner, train, test, style_means, seed: int) -> dict:
    row = {"experiment": experiment, "protocol": protocol.name, "seed": seed}
    multi = {"n_futures": N_FUTURES, "random_state": seed} if protocol.kind == "online" else {}
    scores = evaluate(learner, test, protocol, **multi)
    row.update({k: v for k, v in scores.items() if k in ("med", "fde", "weight_error")})
    row.update({col: scores.get(col.removesuffix("_6")) for col in MULTIMODAL_COLUMNS})
    row.update(ari=style_agreement(learner, train), n_styles=getattr(learner, "n_styles_", 1),
               em_passes=getattr(learner, "n_refined_", None), style_accuracy=None, feature_style_accuracy=None,
               style_error=None, min_ade=None, min_fde=None)
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
    plain = [v.item() if isinstance(v, np.generic) else v for v in row.values()]
    return {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in zip(row, plain)}  # JSON


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


def run_study_cells(specs: list[dict]) -> list[tuple[dict, dict]]:
    """The cells of the ``weight-space`` kind (`pirl_sim.experiments.spec.ScenarioSpec.run_cells`): each cell's
    learner fitted to its experiment's training data and scored, a row of the table (nan as None); online on a
    path model, also the `N_FUTURES` futures it draws for the first test trajectory (``futures``: ``states``,
    ``proba`` and the ``true`` states), which `futures_figure` draws."""
    from pirl_sim.learners import make_learner

    out = []
    for spec in specs:
        t0 = time.perf_counter()
        experiment, seed = spec["scenario_params"]["experiment"], spec["seed"]
        model, train, test, means = experiment_data(experiment, seed)
        protocol = Protocol(**spec["protocol"])
        params = {k: tuple(v) if isinstance(v, list) else v for k, v in spec["learner_params"].items()}
        learner = make_learner(spec["learner"], model=model, **params, **protocol.learner_params())
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # dropped tiny components, IRL notes: counted in the table
            learner.fit(train)
        t1 = time.perf_counter()
        row = _row(experiment, protocol, learner, train, test, means, seed)
        if protocol.kind == "online" and hasattr(model, "path") and hasattr(learner, "predict_futures"):
            h, first = protocol.history_steps, test[0]
            states, proba = learner.predict_futures(first.window(0, h), first.n_steps - h, n_futures=N_FUTURES,
                                                    random_state=np.random.default_rng(seed))
            row["futures"] = {"states": states.tolist(), "proba": proba.tolist(), "true": first.states.tolist()}
        out.append((row, {"fit_s": t1 - t0, "evaluate_s": time.perf_counter() - t1}))
    return out


def _check_protocol(params: dict, protocol: dict) -> None:
    if protocol.get("kind") not in ("paper", "online"):
        raise ValueError(f"scores the paper and online protocols only, got {protocol.get('kind')!r}")


#: the study's engine kind (module doc)
SPEC = ScenarioSpec(
    "weight-space", "one experiment of the weight-space study: mixtures in feature space against weight space "
    "(module pirl_sim.experiments.weight_space)",
    {"experiment": Param("choice", "synthetic", "the experiment of the study", choices=tuple(EXPERIMENTS))},
    dict, None, lambda params: TrainShape(EXPERIMENTS[params["experiment"]], (), exact=False),
    run_cells=run_study_cells, check_protocol=_check_protocol, learners=("tirl", "pirl-knn", "pirl-gmm", "pirl-dpgmm"),
    code=("pirl_sim.experiments.weight_space", "pirl_sim.evaluation.tables"),
)


def study_config(experiments, seeds) -> tuple[dict, list[str]]:
    """The study as a sweep config of the ``weight-space`` kind (an experiment per study experiment and
    protocol; lq-receding under the paper protocol only; a mixture's ``random_state`` is the cell's seed, the
    engine's default) and the table's learner name of each of its cells, in cell order."""
    blocks, names = [], []
    for experiment in experiments:
        k, few = (2, 1) if experiment.startswith("synthetic") else (3, 10)  # styles, neighbours
        knn = [(f"PIRL-kNN (k={few})", "pirl-knn", {"n_neighbors": few}),
               ("PIRL-kNN (k=50), likelihood", "pirl-knn", {"n_neighbors": 50, "weighting": "likelihood"})]
        if experiment == "passage":  # as reproduce passage
            knn = [(name, key, {**p, "prior": "population"}) for name, key, p in knn]  # type: ignore[dict-item]
        for protocol in (PAPER_PROTOCOL,) if experiment == "lq-receding" else (PAPER_PROTOCOL, ONLINE):
            learners = [("TIRL", "tirl", {}), *knn,
                        (f"PIRL-GMM (k={k}), features", "pirl-gmm", {"n_components": k}),
                        (f"PIRL-GMM (k={k}), weights", "pirl-gmm", {"n_components": k, "space": "weights"}),
                        ("PIRL-DPGMM, features", "pirl-dpgmm", {}),
                        ("PIRL-DPGMM, weights", "pirl-dpgmm", {"space": "weights"}),
                        ("PIRL-DPGMM, weights, MML", "pirl-dpgmm", {"space": "weights", "weight_mixture": "mml"})]
            if protocol.kind == "paper":  # the fit does not depend on the protocol: its clusters once
                learners.append((f"PIRL-GMM (k={k}), weights, random start", "pirl-gmm", {
                    "n_components": k, "space": "weights", "init": "random", "refine": RANDOM_START_PASSES}))
            if experiment == "lq-receding":  # the mixtures only, receding-horizon likelihood
                learners = [(name, key, {**p, "likelihood": "receding", "horizon": 15})  # type: ignore[dict-item]
                            for name, key, p in learners[3:]]
            blocks.append({"scenario": "weight-space", "label": f"{experiment}, {protocol.name}",
                           "params": {"experiment": experiment}, "protocols": [dataclasses.asdict(protocol)],
                           "learners": [{"name": key, "params": p} for _, key, p in learners], "seeds": list(seeds)})
            names += [name for name, _, _ in learners for _ in seeds]
    return {"name": "weight-space", "experiments": blocks}, names


def futures_figure(model, true_states, futures, proba, history_steps: int, seed: int) -> bytes:
    """PNG bytes: ``futures`` (K, H + 1, n_x) drawn with probabilities ``proba`` (seed ``seed``) after the first
    ``history_steps`` steps of a trajectory whose states are ``true_states`` (n + 1, n_x), on a path model's map,
    and arc length s [m] against time [s].

    Left: lane edges `LANE_HALF_WIDTH` either side of the model's path (its map), the observed history, the
    true future and each predicted future, with markers every second; right: each future's arc length minus the
    true one [m] against time [s].
    """
    from pirl_sim.evaluation.figures import png_bytes, pyplot

    states, proba, true_states = np.asarray(futures), np.asarray(proba), np.asarray(true_states)
    dt = model.dynamics.dt
    t = np.arange(len(true_states)) * dt
    every = max(1, int(round(1.0 / dt)))  # a marker every second
    plt = pyplot()
    fig, (ax_map, ax_s) = plt.subplots(1, 2, figsize=(11, 4.8), gridspec_kw={"width_ratios": [1.2, 1]})
    s_all = np.linspace(0.0, model.path.length, 600)
    for d in (-LANE_HALF_WIDTH, LANE_HALF_WIDTH):
        edge = model.path.to_cartesian(s_all, np.full_like(s_all, d))
        ax_map.plot(edge[:, 0], edge[:, 1], color="0.6", lw=1)
    centre = model.path.to_cartesian(s_all, np.zeros_like(s_all))
    ax_map.plot(centre[:, 0], centre[:, 1], color="0.8", lw=0.8, ls="--")
    seen = model.positions(true_states[: history_steps + 1])
    true = model.positions(true_states[history_steps:])
    colours = plt.get_cmap("tab10")(np.arange(len(proba)) % 10)
    order = np.argsort(-proba, kind="stable")
    s_true = true_states[history_steps:, 0]
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


def _readme(table: pd.DataFrame, command: str, figure: bool) -> str:
    return (
        "# Mixtures in feature space and in weight space\n\n"
        f"Written by `{command}` (pirl_sim/experiments/weight_space.py; its docstring describes every experiment "
        "and column).\n\n" + markdown(table)
        + ("\n`futures.png`: the six futures of PIRL-GMM (k=3) in weight space after the first 2 s of the first test "
           "passage, with the true future (module docstring).\n" if figure else "")
    )


def write_study(rows: list[dict], names: list[str], out, command: str) -> pd.DataFrame:
    """Write ``table.csv``, ``table.md``, ``futures.png`` (the futures of `FIGURE_LEARNER` on the passage, first
    seed) and ``README.md`` into ``out`` from the cells' rows (`run_study_cells`, in cell order) and learner
    names; returns the table (a ``seed`` column first when the rows have several seeds)."""
    from pirl_sim.scenarios.passage import PassageConfig

    drawn = [(r["futures"], r["seed"]) for r, n in zip(rows, names) if n == FIGURE_LEARNER and "futures" in r]
    for f, seed in drawn[:1]:
        png = futures_figure(PassageConfig().model(), f["true"], f["states"], f["proba"],
                             ONLINE.history_steps, seed)  # type: ignore[arg-type]
        atomic_write_bytes(out / "futures.png", png)
    table = pd.DataFrame([{**{k: np.nan if v is None else v for k, v in r.items()}, "learner": n}
                          for r, n in zip(rows, names)])
    table = table[[*(["seed"] if table["seed"].nunique() > 1 else []), *COLUMNS]]
    atomic_write_text(out / "table.csv", table.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out / "table.md", markdown(table))
    atomic_write_text(out / "README.md", _readme(table, command, bool(drawn)))
    return table
