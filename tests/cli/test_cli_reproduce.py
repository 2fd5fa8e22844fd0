import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from pirl_sim.cli import main


def test_reproduce_quick_config_end_to_end_and_byte_identical(tmp_path, capsys):
    args = ["reproduce", "synthetic", "--n-trajectories", "240", "--n-train", "200", "--quiet"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out
    assert "MED(TIRL) > MED(PIRL-GMM) > MED(PIRL-kNN)" in out
    names = ["table.csv", "table.md", "knn_k.csv", "knn_k.png", "README.md"]
    for n in names:
        assert (tmp_path / "a" / n).read_bytes() == (tmp_path / "b" / n).read_bytes(), n
    table = pd.read_csv(tmp_path / "a" / "table.csv")
    assert set(table["learner"]) == {"TIRL", "PIRL-GMM (k=2)", "PIRL-kNN (k=1)", "PIRL-DPGMM"}
    assert table["med"].notna().all() and (table["med"] >= 0).all()


def test_cli_rejects_bad_arguments(tmp_path, capsys):
    assert main(["reproduce", "synthetic", "--n-trajectories", "10", "--n-train", "10", "--out", str(tmp_path)]) == 2
    assert "n_train must be in" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["reproduce", "highway"])
    with pytest.raises(SystemExit):
        main(["reproduce", "synthetic", "--n-train", "-3"])


def test_reproduce_help_in_a_fresh_process():
    out = subprocess.run(
        [sys.executable, "-m", "pirl_sim", "reproduce", "--help"], capture_output=True, text=True, check=True
    )
    assert "--history-steps" in out.stdout


def test_reproduce_passage_quick_config(tmp_path, capsys):
    out = tmp_path / "p"
    assert main(["reproduce", "passage", "--n-trajectories", "150", "--n-train", "120", "--quiet", "--out", str(out)]) == 0
    table = pd.read_csv(out / "table.csv")
    assert len(table) == 12 and table["med"].notna().all()
    for name in ("knn_k.png", "clusters.png", "s_t.png", "switch.png", "README.md"):
        assert (out / name).stat().st_size > 0
    assert "crosses half-way after" in (out / "README.md").read_text()


def test_reproduce_presets_are_cells_of_the_default_sweep():
    """The presets run the default sweep's synthetic and passage cells (same keys: same numbers)."""
    from pirl_sim.engine.presets import preset_config
    from pirl_sim.engine.config import default_config

    default = {c.key("v") for c in default_config().cells}
    for name in ("synthetic", "passage"):
        cells = preset_config(name).cells
        assert {c.experiment for c in cells} == {"table", "knn_k"}
        assert {c.key("v") for c in cells} <= default, name


def test_reproduce_options_map_onto_the_preset(capsys):
    from pirl_sim.engine.presets import preset_config

    config = preset_config("synthetic", seed=3, params={"n_train": 30, "n_trajectories": 40}, history_steps=7)
    assert {c.seed for c in config.cells} == {3}
    assert {c.scenario_params["n_train"] for c in config.cells} == {30}
    assert {c.protocol["history_steps"] for c in config.cells if c.protocol["kind"] == "online"} == {7}
    assert sorted({c.k for c in config.cells if c.experiment == "knn_k"}) == [1, 2, 3, 5, 8, 13, 21]  # k <= n_train
    with pytest.raises(ValueError, match="unknown experiment 'highway'"):
        preset_config("highway")
    assert main(["reproduce", "passage", "--position-range", "2", "8", "--out", "/nonexistent/never"]) == 2
    assert "--position-range apply to the synthetic experiment only" in capsys.readouterr().err


def test_an_interrupted_reproduce_resumes_without_recomputing_finished_cells(tmp_path, monkeypatch):
    """`reproduce synthetic` killed (SIGKILL) after its first cells: the same command computes only the missing
    cells, leaves the finished ones untouched and writes the same files as an uninterrupted run."""
    import json
    import os
    import signal
    import time

    import pirl_sim.engine.run as sweep_run
    from pirl_sim.engine.presets import preset_config
    from pirl_sim.engine.store import code_version

    args = ["reproduce", "synthetic", "--quiet"]
    killed = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "pirl_sim", *args, "--out", str(killed)],
                            env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    cells = killed / "cells"
    deadline = time.monotonic() + 300
    while proc.poll() is None and time.monotonic() < deadline and len(list(cells.glob("*.json"))) < 3:
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL
    kept = {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json")}
    if kept and json.loads(next(cells.glob("*.json")).read_text())["code_version"] != code_version():
        pytest.skip("the cell code changed while the test ran (a shared working tree): every cell would rerun")
    n_cells = len({c.key(code_version()) for c in preset_config("synthetic").cells})
    assert 3 <= len(kept) < n_cells and not (killed / "table.csv").exists()

    computed = []
    run_cells = sweep_run.run_cells
    monkeypatch.setattr(sweep_run, "run_cells", lambda specs, *a: computed.extend(specs) or run_cells(specs, *a))
    assert main(args + ["--out", str(killed)]) == 0
    assert len(computed) == n_cells - len(kept)
    assert {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json") if p.name in kept} == kept
    fresh = tmp_path / "fresh"
    assert main(args + ["--out", str(fresh)]) == 0
    for name in ("table.csv", "table.md", "knn_k.csv", "knn_k.png", "README.md"):
        assert (killed / name).read_bytes() == (fresh / name).read_bytes(), name


@pytest.mark.parametrize("name", ["synthetic", "passage"])
def test_committed_reproductions_are_the_committed_sweeps_seed_0_cells(name):
    """results/<name>/table.csv and knn_k.csv are what the report template makes of the committed default sweep's
    cells (results/sweep/cells of the code version in its sweep.json, matched by their full configuration): the
    README's tables of both come from one path."""
    import json

    from pirl_sim.engine.presets import preset_config
    from pirl_sim.experiments.reproduce import report_tables
    from pirl_sim.engine.config import canonical_json
    from pirl_sim.engine.run import assemble_table

    repo = Path(__file__).resolve().parents[2]
    version = json.loads((repo / "results" / "sweep" / "sweep.json").read_text())["code_version"]
    by_spec = {}
    for path in (repo / "results" / "sweep" / "cells").glob("*.json"):
        record = json.loads(path.read_text())
        if record["code_version"] == version:  # the sweep's own cells, not stale ones
            by_spec[canonical_json(record["cell"])] = record
    config = preset_config(name)
    keys = [c.key("committed") for c in config.cells]
    records = {k: by_spec[canonical_json(c.spec())] for k, c in zip(keys, config.cells)}
    table, ktable = report_tables(name, assemble_table(config, keys, records))
    committed = repo / "results" / name
    assert table.to_csv(index=False, float_format="%.6g") == (committed / "table.csv").read_text()
    assert ktable.to_csv(index=False, float_format="%.6g") == (committed / "knn_k.csv").read_text()
