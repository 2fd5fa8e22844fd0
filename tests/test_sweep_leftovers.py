"""Issue 13's leftovers: the sweep report on a replay's cells, and a missing optional extra at the config check."""

import types
import warnings

import pandas as pd
import pytest

from pirl_sim.cli import main

pytest.importorskip("lanelet2")


@pytest.fixture(scope="module")
def replay_out(tmp_path_factory):
    """A small `pirl-sim replay` (one split seed, TIRL and the baselines) on a generated passage scene."""
    from pirl_sim.scenarios.passage import PassageConfig, generate, write_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate(PassageConfig(n_trajectories=40, n_train=30, seed=2))
    root = tmp_path_factory.mktemp("replay")
    write_scene(data, root / "scene")
    out = root / "out"
    assert main(["replay", "--tracks", str(root / "scene"), "--map", str(root / "scene" / "map.osm"), "--seeds", "1",
                 "--learners", "tirl", "--quiet", "--out", str(out)]) == 0
    return out


def test_report_reads_the_cells_of_a_replay_and_keeps_its_readme(replay_out, capsys):
    from pirl_sim.engine import read_table

    readme = (replay_out / "README.md").read_bytes()
    table = read_table(replay_out)  # no table files: the cells listed in sweep.json
    rows = pd.read_csv(replay_out / "rows.csv").set_index("method")
    assert list(table["learner_label"]) == ["CV (path)", "CA (path)", "TIRL", "CV (x, y)"]
    for _, r in table.iterrows():
        assert r["med"] == pytest.approx(rows.loc[r["learner_label"], "med"], rel=1e-5)
    capsys.readouterr()
    assert main(["report", str(replay_out)]) == 0
    assert f"to {replay_out}/report/" in capsys.readouterr().out
    md = (replay_out / "report" / "README.md").read_text()
    assert "| TIRL |" in md and "| CV (x, y) |" in md and f"the cells stored in {replay_out}/cells/" in md
    assert "numbers are in its cell's file" in md and "`table.csv`" not in md  # a replay writes no table files
    assert (replay_out / "README.md").read_bytes() == readme  # the replay's own README is not overwritten


def test_a_missing_simulator_extra_fails_the_config_check_naming_the_extra(tmp_path, capsys, monkeypatch):
    from pirl_sim.experiments import simulated as scenarios

    def import_module(name):
        raise ModuleNotFoundError(f"No module named {'highway_env'!r}", name="highway_env")

    monkeypatch.setattr(scenarios, "importlib", types.SimpleNamespace(import_module=import_module))
    cfg = tmp_path / "highway.toml"
    cfg.write_text("""
seeds = [0]
[[experiments]]
scenario = "highway"
protocols = [{ kind = "rolling", history_steps = 10, horizon = 10, stride = 20 }]
learners = ["cv"]
""")
    assert main(["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "scenario 'highway' needs the highway extra: pip install -e '.[highway]' (highway_env is not installed)" in err
    assert "Traceback" not in err


def test_recorded_configs_fail_their_check_naming_the_scenario_as_written(replay_out, tmp_path, capsys):
    """``replay`` is the recorded scenario's former name: its errors name the scenario the config names, and both
    take the rolling protocol only and fde_steps within its horizon (rejected at the config check, not in every
    cell)."""
    scene = replay_out.parent / "scene"
    cfg = tmp_path / "recorded.toml"
    for scenario in ("recorded", "replay"):
        text = f"""
seeds = [0]
[[experiments]]
scenario = "{scenario}"
params = {{ tracks = "{scene}", map = "{scene / 'map.osm'}" }}
protocols = [{{ kind = "paper" }}]
learners = ["tirl"]
"""
        cfg.write_text(text)
        assert main(["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "out")]) == 2
        assert f"scenario '{scenario}' runs the rolling protocol, not 'paper'" in capsys.readouterr().err
        rolling = text.replace('kind = "paper"', 'kind = "rolling", history_steps = 5, horizon = 5, stride = 5')
        cfg.write_text(rolling.replace("map = ", "files = -1, map = "))
        assert main(["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "out")]) == 2
        assert f"scenario '{scenario}': files must be >= 0 (0: every file), got -1" in capsys.readouterr().err
        cfg.write_text(rolling.replace("map = ", "replay = { fde_steps = [5, 10] }, map = "))  # beyond the horizon
        assert main(["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "out")]) == 2
        assert (f"scenario '{scenario}' parameter 'replay': fde_steps must lie in [1, horizon=5], got (5, 10)"
                in capsys.readouterr().err)
        cfg.write_text(rolling)
        assert main(["sweep", str(cfg), "--dry-run", "--out", str(tmp_path / "out")]) == 0
        assert "1 cells (1 distinct)" in capsys.readouterr().out
