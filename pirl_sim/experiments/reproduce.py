"""`pirl-sim reproduce synthetic|passage`: the report template of the paper's experiments.

Each experiment is an embedded sweep preset (``pirl_sim/experiments/configs/<name>.toml``, cells of the default
sweep) that `pirl_sim.engine.presets.run_preset` runs into the output directory; `write_reproduction` writes,
from its cells' tidy table (same seed, same bytes): ``table.csv``/``table.md`` (the preset's ``table``
experiment; synthetic: beside the paper's values), ``knn_k.csv``/``knn_k.png`` (its ``knn_k`` experiment: the
paper's "Performance of kNN with different k"), ``README.md``, and for the passage ``clusters.png`` (feature
space), ``s_t.png`` (S-T plots of online predictions) and ``switch.png`` (online inference through a style switch).
"""

from __future__ import annotations

import warnings
from dataclasses import asdict
from pathlib import Path

import numpy as np
import pandas as pd

from pirl_sim.evaluation import figures
from pirl_sim.evaluation.protocols import Protocol
from pirl_sim.evaluation.tables import markdown
from pirl_sim.io.atomic import atomic_write_bytes, atomic_write_text
from pirl_sim.progress import reporter
from pirl_sim.simulate import simulate_receding_horizon
from pirl_sim.experiments.registry import scenario_spec
from pirl_sim.experiments.simulated import generated_config

__all__ = ["PAPER_SYNTHETIC_MED", "PRESETS", "write_reproduction", "report_tables", "ordering_holds"]

#: Table "Experimental results on synthetic data" of the paper [m].
PAPER_SYNTHETIC_MED = {"TIRL": 5.6e-2, "PIRL-GMM (k=2)": 9.8e-3, "PIRL-kNN (k=1)": 3.2e-3}
#: The experiments of this template: embedded presets ``pirl_sim/experiments/configs/<name>.toml``.
PRESETS = ("synthetic", "passage")


def write_reproduction(name: str, cells, tidy: pd.DataFrame, out_dir, *, progress: bool = True) -> pd.DataFrame:
    """Write the files of the experiment ``name`` (module doc) into ``out_dir`` from its finished cells.

    Parameters
    ----------
    name : {"synthetic", "passage"}
    cells : sequence of `pirl_sim.engine.config.Cell`   the preset's cells, in config order
    tidy : DataFrame            their tidy table (`pirl_sim.engine.run.assemble_table`), every cell finished
    out_dir : path              an existing, writable directory
    progress : bool             status lines on stderr

    Returns
    -------
    DataFrame
        The main table (``table.csv``).
    """
    out = Path(out_dir)
    table, ktable = report_tables(name, tidy)
    title = {"synthetic": "synthetic data", "passage": "the roundabout passage"}[name]
    atomic_write_text(out / "table.csv", table.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out / "table.md", markdown(table))
    atomic_write_text(out / "knn_k.csv", ktable.to_csv(index=False, float_format="%.6g"))
    atomic_write_bytes(out / "knn_k.png", figures.knn_vs_k(ktable, f"PIRL-kNN on {title}: MED vs k"))
    first = cells[0]
    scenario = generated_config(first.scenario, dict(first.scenario_params), first.seed)  # its dataclass
    history = next(c.protocol["history_steps"] for c in cells if c.protocol["kind"] != "paper")
    if name == "synthetic":
        readme = _synthetic_summary(table, ktable, scenario, history)
    else:
        reporter(progress)("figures: feature clusters, S-T predictions, style switch")
        readme = _passage_summary(table, _passage_figures(cells, scenario, history, out), scenario)
    atomic_write_text(out / "README.md", readme)
    return table


def report_tables(name: str, tidy: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The main table (``table.csv``) and MED against k (``knn_k.csv``) of the preset ``name`` from the sweep's
    tidy table of its cells (`pirl_sim.engine.run.assemble_table`), rows in config order."""
    t = tidy[tidy["experiment"] == "table"]
    scores = ("med", "med_std", "fde", "weight_error", "ari", "n_styles")
    table = pd.DataFrame({"protocol": t["protocol"], "learner": t["learner_label"],
                          **{c: t[c].astype(float) for c in scores}, "n_test": t["n_test"].astype(int)})
    if name == "synthetic":  # the paper's values beside its protocol's rows
        table.insert(3, "paper_med", [PAPER_SYNTHETIC_MED.get(n, np.nan) if k == "paper" else np.nan
                                      for n, k in zip(table["learner"], t["protocol_kind"])])
    k = tidy[tidy["experiment"] == "knn_k"]
    ktable = pd.DataFrame({"protocol": k["protocol"].to_numpy(), "k": k["k"].astype(int).to_numpy(),
                           "med": k["med"].to_numpy(), "med_std": k["med_std"].to_numpy()})
    return table.reset_index(drop=True), ktable


def ordering_holds(table: pd.DataFrame, protocol_name: str) -> bool:
    """MED(TIRL) > MED(PIRL-GMM (k=2)) > MED(PIRL-kNN (k=1)) under the named protocol."""
    t = table[table["protocol"] == protocol_name].set_index("learner")["med"]
    return bool(t["TIRL"] > t["PIRL-GMM (k=2)"] > t["PIRL-kNN (k=1)"])


def _readme(lines: list[str], config) -> str:
    """The README's text: ``lines``, then the scenario's configuration ``config``."""
    cfg = asdict(config)
    cfg["styles"] = [f"{s.name}: weight {s.weight}, mean {dict(s.mean)}, std {dict(s.std)}" for s in config.styles]
    return "\n".join([*lines, "## Configuration", "", *(f"- {k}: {v}" for k, v in cfg.items())]) + "\n"


def _synthetic_summary(table, ktable, config, history_steps) -> str:
    best = ktable.loc[ktable.groupby("protocol", sort=False)["med"].idxmin()]
    return _readme([
        "# Synthetic reproduction", "",
        "Made by `pirl-sim reproduce synthetic` (see the project README); every number below is read from",
        "`table.csv` and `knn_k.csv` in this directory, written by the same run.", "",
        "## MED [m]", "", markdown(table), "",
        *(f"- {proto}: MED(TIRL) > MED(PIRL-GMM) > MED(PIRL-kNN) "
          f"{'holds' if ordering_holds(table, proto) else 'does NOT hold'}." for proto in table["protocol"].unique()),
        *(f"- {r['protocol']}: best kNN k = {int(r['k'])} (MED {r['med']:.3g} m)." for _, r in best.iterrows()), "",
        "`weight_error`: median over test trajectories of |log(inferred / true)| of the normalised weight q/r.",
        "`ari`: adjusted Rand index of the training clusters against the two true kernels.",
        f"Online protocol: the first {history_steps} steps are observed, the rest predicted.", "",
        "![MED vs k](knn_k.png)", ""], config)


# ---------------------------------------------------------------------------------------------- passage
def _passage_figures(cells, scenario, history_steps: int, out) -> dict:
    """Write ``clusters.png`` (the paper protocol's PIRL-GMM), ``s_t.png`` (the online protocol's learners on the
    first four test passages) and ``switch.png`` from the preset's ``table`` cells; returns the switch summary."""
    from pirl_sim.learners import LEARNERS

    cells = [c for c in cells if c.experiment == "table"]
    spec = cells[0].spec()
    data = scenario_spec(spec["scenario"]).build(spec["scenario_params"], spec["seed"])  # type: ignore[misc]
    model = data.model

    def fitted(cell):
        params = {k: tuple(v) if isinstance(v, list) else v for k, v in dict(cell.learner_params).items()}
        learner = LEARNERS[cell.learner](model=model, **params, **Protocol(**cell.protocol).learner_params())
        with warnings.catch_warnings(action="ignore", category=UserWarning):  # dropped tiny mixture components
            return learner.fit(data.train)

    gmm = fitted(next(c for c in cells if c.learner == "pirl-gmm" and c.protocol["kind"] == "paper"))
    truth = np.array([t.metadata["style"] for t in data.train])
    atomic_write_bytes(out / "clusters.png", figures.feature_clusters(
        model.feature_values(data.train), model.features.names, gmm.labels_, truth, [s.name for s in scenario.styles]))
    shown = data.test[:4]
    t_axis = np.arange(shown[0].n_steps + 1) * model.dynamics.dt
    preds = {c.learner_label: fitted(c).predict_states([t.window(0, history_steps) for t in shown],
                                                        shown[0].n_steps - history_steps)[:, :, 0]
             for c in cells if c.protocol["kind"] == "online"}
    atomic_write_bytes(out / "s_t.png", figures.s_t_predictions(t_axis, np.stack([t.states[:, 0] for t in shown]),
                                                                preds, history_steps))
    switch_png, switch_summary = _style_switch(data, scenario, history_steps)
    atomic_write_bytes(out / "switch.png", switch_png)
    return switch_summary


def _style_switch(data, config, history_steps):
    """Drivers who switch from 'minimises acceleration' to 'tracks desired speed'; kNN follows online."""
    from pirl_sim.learners import PIRLKNN

    model = data.model
    with warnings.catch_warnings(action="ignore", category=UserWarning):
        knn = PIRLKNN(model, n_neighbors=10, prior="population", window=history_steps, stride=2).fit(data.train)
    by_name = {s.name: model.features.weights({**dict(s.mean), "jerk_sq": 1.0}) for s in config.styles}
    before, after = by_name["minimises acceleration"], by_name["tracks desired speed"]
    n_drivers, switch, n_steps, rng = 8, 20, 45, np.random.default_rng(config.seed + 1)
    x0 = np.column_stack([np.zeros(n_drivers), rng.uniform(10, 12, n_drivers), np.zeros(n_drivers)])
    trajs = simulate_receding_horizon(model, x0, lambda k: np.tile(before if k < switch else after, (n_drivers, 1)),
                                      n_steps, 25, rng=rng, control_noise=0.3)
    steps = np.arange(history_steps, n_steps + 1)
    inferred = (knn.infer_weights([tr.window(k - history_steps, k) for tr in trajs]) for k in steps)
    ratio = np.stack([np.log10(th[:, 0] / th[:, 1]) for th in inferred], axis=1)
    true = np.where(steps <= switch, np.log10(before[0] / before[1]), np.log10(after[0] / after[1]))
    dt = model.dynamics.dt
    png = figures.weight_tracking(steps * dt, ratio, true, "log10(w_speed_dev / w_acc_sq)", switch * dt)
    crossed = steps[(steps > switch) & (np.median(ratio, axis=0) > 0.5 * (true[0] + true[-1]))]  # half-way
    return png, {"switch_step": switch, "lag_steps": int(crossed[0] - switch) if len(crossed) else None, "dt": dt}


def _passage_summary(table, switch, config) -> str:
    lag, dt = switch["lag_steps"], switch["dt"]
    crossed = f"{lag} steps ({lag * dt:.1f} s)." if lag is not None else "no step: the switch was NOT followed."
    return _readme([
        "# Roundabout passage: three driving styles of known weights", "",
        "Made by `pirl-sim reproduce passage`; every number below is read from the CSV files of the same run.", "",
        "## MED [m] and style recovery", "", markdown(table), "",
        "`weight_error`: median |log(inferred / true)| over the normalised weights (speed_dev, acc_sq).",
        "`ari`: adjusted Rand index of the training clusters against the three true styles.", "",
        "## Style switch", "",
        f"Drivers switch from 'minimises acceleration' to 'tracks desired speed' at step {switch['switch_step']} "
        f"(dt {dt} s); the median inferred log weight ratio crosses half-way after {crossed}",
        "", "![switch](switch.png) ![clusters](clusters.png) ![S-T](s_t.png) ![MED vs k](knn_k.png)", ""], config)
