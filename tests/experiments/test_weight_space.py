"""The weight-space study as the engine kind ``weight-space`` (pirl_sim.experiments.weight_space): its cells are
the rows of the table, in plain JSON, and the report draws the figure from what the cells stored."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pirl_sim.engine.config import parse_config
from pirl_sim.experiments.weight_space import (COLUMNS, EXPERIMENTS, FIGURE_LEARNER, run_study_cells, study_config,
                                               write_study)

REPO = Path(__file__).resolve().parents[2]


def test_the_study_config_has_a_cell_per_row_of_the_table():
    data, names = study_config(EXPERIMENTS, [0])
    cells = parse_config(data).cells
    assert len(cells) == len(names) == 74  # 17 per experiment with both protocols, 6 of lq-receding
    rows = {(c.scenario_params["experiment"], c.protocol["kind"], n): c for c, n in zip(cells, names)}
    start = rows[("passage", "paper", "PIRL-GMM (k=3), weights, random start")]
    assert (start.learner, start.learner_params["init"], start.learner_params["random_state"]) == ("pirl-gmm",
                                                                                                   "random", 0)
    assert ("passage", "online", "PIRL-GMM (k=3), weights, random start") not in rows  # fitted once, paper only
    assert rows[("passage", "online", "PIRL-kNN (k=10)")].learner_params["prior"] == "population"
    assert rows[("synthetic", "paper", "PIRL-kNN (k=1)")].learner_params["prior"] is None
    assert {c.learner_params["likelihood"] for c in cells if c.scenario_params["experiment"] == "lq-receding"} == {
        "receding"}
    assert parse_config(study_config(["synthetic"], [4, 5])[0]).cells[7].learner_params["random_state"] == 5


def test_the_kind_checks_its_experiment_and_protocols():
    block = {"scenario": "weight-space", "seeds": [0], "learners": ["tirl"]}
    with pytest.raises(ValueError, match="scores the paper and online protocols only, got 'rolling'"):
        parse_config({"experiments": [{**block, "protocols": [
            {"kind": "rolling", "history_steps": 5, "horizon": 5, "stride": 5}]}]})
    with pytest.raises(ValueError, match="'experiment' must be one of .*got 'highway'"):
        parse_config({"experiments": [{**block, "params": {"experiment": "highway"}, "protocols": ["paper"]}]})
    with pytest.raises(ValueError, match="runs the learners"):
        parse_config({"experiments": [{**block, "learners": ["cv"], "protocols": ["paper"]}]})


def test_a_cell_is_its_row_of_the_committed_table_in_plain_json(tmp_path):
    data, names = study_config(["lq-receding"], [0])
    cell = parse_config(data).cells[1]
    ((row, timings),) = run_study_cells([cell.spec()])
    json.dumps(row, allow_nan=False)
    assert timings["fit_s"] > 0 and row["n_styles"] == 3 and row["min_ade"] is None
    committed = pd.read_csv(REPO / "results" / "weight_space" / "table.csv", keep_default_na=False, dtype=str)
    expected = committed[(committed["experiment"] == "lq-receding") & (committed["learner"] == names[1])]
    write_study([row], [names[1]], tmp_path, "pirl-sim weight-space")
    assert (tmp_path / "table.csv").read_text() == expected.to_csv(index=False)
    assert not (tmp_path / "futures.png").exists() and "futures.png" not in (tmp_path / "README.md").read_text()


def test_the_report_draws_the_futures_a_cell_stored(tmp_path):
    s = np.linspace(10.0, 40.0, 41)
    true = np.column_stack([s, np.full_like(s, 10.0), np.zeros_like(s)])
    futures = np.stack([true[10:] + [d, 0.0, 0.0] for d in (-2.0, 3.0)])
    row = dict.fromkeys(COLUMNS, None) | {"experiment": "passage", "protocol": "online (history 10 steps)",
                                          "seed": 0, "med": 0.5, "n_styles": 3}
    drawn = {**row, "futures": {"states": futures.tolist(), "proba": [0.25, 0.75], "true": true.tolist()}}
    table = write_study([row, drawn], ["TIRL", FIGURE_LEARNER], tmp_path, "pirl-sim weight-space")
    assert list(table.columns) == list(COLUMNS) and table["learner"].tolist() == ["TIRL", FIGURE_LEARNER]
    assert (tmp_path / "futures.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "`futures.png`" in (tmp_path / "README.md").read_text()
    seeds = write_study([row, {**row, "seed": 1}], ["TIRL", "TIRL"], tmp_path, "pirl-sim weight-space --seeds 0 1")
    assert list(seeds.columns[:2]) == ["seed", "experiment"] and np.isnan(seeds["ari"]).all()
