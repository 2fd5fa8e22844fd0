"""Recovery curves: the recovery_curves.toml preset, the simulated scenarios' n_train parameter,
and the report's curves (pirl_sim.experiments.recovery_curves), on a hand-made table and on a tiny real SUMO sweep."""

from __future__ import annotations

import json
from importlib import resources

import numpy as np
import pandas as pd
import pytest

from pirl_sim.engine import load_config, run_sweep, write_report
from pirl_sim.experiments.recovery_curves import CURVE_AXES, curves_markdown, curves_summary, curves_table, recovery_curves_figure
from pirl_sim.experiments.sweep_report import _fmt

from sweep_configs import sweep_config, sweep_toml


def _preset_curves(name: str) -> dict[str, tuple[list, list]]:
    """{experiment: (its cells, the curve axes it varies)} of a preset config shipped with the package."""
    cfg = load_config(str(resources.files("pirl_sim.experiments") / "configs" / name))
    by_exp: dict[str, list] = {}
    for cell in cfg.cells:
        by_exp.setdefault(cell.experiment, []).append(cell)
    return {exp: (cells, [axis for axis, (where, _) in CURVE_AXES.items()
                          if len({json.dumps((c.scenario_params if where == "scenario" else c.learner_params).get(axis))
                                  for c in cells}) > 1])
            for exp, cells in by_exp.items()}


def test_the_preset_varies_one_recovery_parameter_per_experiment():
    curves = _preset_curves("recovery_curves.toml")
    assert len(curves) == 6
    for exp, (cells, varied) in curves.items():
        assert len(varied) == 1, (exp, varied)
        assert all(c.learner_params["likelihood"] == "receding" for c in cells)
        assert sorted({c.seed for c in cells}) == [0, 1, 2]
    horizons = {c.learner_params["horizon"] for c in curves["SUMO assumed horizon"][0]}
    assert horizons == {10, 20, 30, 45, 60}
    # the drivers' horizon is 30 in every run: the other experiments' learners assume the right one
    assert {c.learner_params["horizon"] for c in curves["SUMO control noise"][0]} == {30}


def test_the_interacting_preset_varies_density_or_noise_over_drivers_who_interact():
    curves = _preset_curves("interacting_curves.toml")
    assert len(curves) == 4
    for exp, (cells, varied) in curves.items():
        assert len(varied) == 1, (exp, varied)
        assert sorted({c.seed for c in cells}) == [0, 1, 2]
        for c in cells:  # every style weighs headway and yielding: the drivers interact by their own cost
            assert all({"headway", "yielding"} <= set(s["mean"]) for s in c.scenario_params["styles"])
            assert c.learner_params["likelihood"] == "receding"
    assert sorted(v[0] for _, v in curves.values()) == ["control_noise", "control_noise", "depart_interval",
                                                        "depart_interval"]


@pytest.mark.parametrize("params, match", [
    ("n_train = -1", r"parameter 'n_train' must be >= 0, got -1"),
    ("n_train = 20", r"parameter 'n_train' = 20 exceeds the 9 training tracks a run of 12 vehicles"),
    ("n_train = 2.5", r"parameter 'n_train' must be an integer, got 2.5"),
])
def test_n_train_is_checked_when_the_config_is_built(params, match):
    text = sweep_toml(None, [0], f"""
scenario = "sumo"
params = {{ n_vehicles = 12, {params} }}
protocols = [{{ kind = "rolling", history_steps = 10, horizon = 20, stride = 20 }}]
learners = ["tirl"]
""")
    with pytest.raises(ValueError, match=match):
        sweep_config(text)


def _table():
    """A sweep table by hand: one n_train curve (2 learners x 3 sizes x 2 seeds), one horizon curve, one
    experiment that varies nothing (not a curve)."""
    rows = []
    for seed in (0, 1):
        for n, err in ((3, 1.0), (6, 0.5), (12, 0.25)):
            for learner, scale in (("TIRL (likelihood=receding)", 1.0), ("PIRL-kNN (k=1, likelihood=receding)", 0.1)):
                rows.append({"experiment": "size", "scenario_params": json.dumps({"n_train": n, "horizon": 30}),
                             "learner_params": json.dumps({"horizon": 30}), "learner_label": learner, "n_train": n,
                             "seed": seed, "weight_error": err * scale * (1 + 0.1 * seed)})
        for h in (10, 30, 60):
            rows.append({"experiment": "horizon", "scenario_params": json.dumps({"n_train": 0, "horizon": 30}),
                         "learner_params": json.dumps({"horizon": h}), "learner_label": f"TIRL (horizon={h})",
                         "n_train": 24, "seed": seed, "weight_error": abs(h - 30) / 30 + 0.01})
        rows.append({"experiment": "flat", "scenario_params": json.dumps({"n_train": 0}),
                     "learner_params": json.dumps({"horizon": 30}), "learner_label": "TIRL", "n_train": 24,
                     "seed": seed, "weight_error": 0.2})
    return pd.DataFrame(rows)


def test_curves_from_a_table():
    points = curves_table(_table())
    assert set(points["experiment"]) == {"size", "horizon"}  # "flat" varies nothing
    s = curves_summary(points)
    size = s[(s["experiment"] == "size") & (s["learner"] == "TIRL (likelihood=receding)")]
    assert list(size["x"]) == [3, 6, 12]
    assert size["mean"].to_numpy() == pytest.approx([1.05, 0.525, 0.2625])
    assert size["ci"].iloc[0] == pytest.approx(12.706 * 0.05 * np.sqrt(2) / np.sqrt(2), rel=1e-3)
    hor = s[s["experiment"] == "horizon"]
    assert set(hor["learner"]) == {"TIRL"} and list(hor["truth"]) == [30, 30, 30]  # label without horizon=
    assert hor.set_index("x").loc[30, "mean"] == pytest.approx(0.01)
    fig = recovery_curves_figure(s)
    assert len([ax for ax in fig.axes if ax.get_visible()]) == 2
    text = "\n".join(curves_markdown(_table(), _fmt))
    assert "**size**: weight error against training tracks" in text and "drivers' horizon 30" in text
    assert recovery_curves_figure(curves_summary(curves_table(_table().query("experiment == 'flat'")))) is None


CURVE = sweep_toml(None, [0], """
scenario = "sumo"
label = "SUMO training tracks"
params = { n_vehicles = 16, depart_interval = 3.0 }
grid = { n_train = [2, 6] }
protocols = [{ kind = "rolling", history_steps = 10, horizon = 20, stride = 20 }]
learners = [{ name = "pirl-knn", params = { n_neighbors = 1, likelihood = "receding", step_stride = 2 } }]
""")


@pytest.mark.slow
def test_a_real_sweep_draws_its_curve(tmp_path):
    pytest.importorskip("libsumo")
    run = run_sweep(sweep_config(CURVE), tmp_path, workers=0, progress=False)
    assert not run.failed and len(run.simulated) == 1  # both sizes read one simulation
    t = run.table.set_index("n_train")
    assert list(t.index) == [2, 6] and (t["weight_error"] > 0).all()
    assert (t["n_test"].iloc[0] == t["n_test"]).all()  # the same test tracks at every size
    files = write_report(tmp_path)
    assert "recovery_curves.png" in files
    readme = files["README.md"].read_text()
    assert "## Recovery curves" in readme and "![Recovery curves](recovery_curves.png)" in readme
