"""``pirl-sim replay`` end to end: generated and simulated recordings scored, through the sweep engine in one or two
processes and resumed, the next-step kNN, lateral and receding-horizon options, and bad durations refused."""

import dataclasses
import re

import pandas as pd
import pytest

from pirl_sim.cli import main

import replay_scenes
from replay_scenes import straight_scene, two_lane_scene_dir
from weaving import weaving_scene


def test_replay_cli_end_to_end(passage_scene, tmp_path, capsys):
    out, _ = passage_scene
    res = tmp_path / "res"
    assert main(["replay", "--preset", "paper", "--tracks", str(out), "--map", str(out / "map.osm"), "--seeds", "2",
                 "--learners", "tirl,pirl-knn", "--knn-k", "3,10", "--out", str(res), "--quiet"]) == 0
    summary = pd.read_csv(res / "summary.csv")
    assert {"TIRL", "PIRL-kNN (k=3)", "PIRL-kNN (k=10)", "CV (path)", "CA (path)", "CV (x, y)"} <= set(summary["method"])
    conv = summary.set_index("method")["irl_converged"]
    assert conv["TIRL"].endswith(" / 2")  # one group per fit, two split seeds
    assert conv["PIRL-kNN (k=3)"] == conv["PIRL-kNN (k=10)"]  # one shared fit per split
    assert "irl_converged" in (res / "README.md").read_text()
    for name in ("clusters.png", "s_t.png", "knn_k.png"):
        assert (res / name).stat().st_size > 0
    assert (res / "README.md").read_text().count("Tracks read: 160") == 1
    assert main(["replay", "--preset", "paper",
                 "--tracks", str(out), "--map", str(out / "map.osm"), "--learners", "svm",
                 "--out", str(res)]) == 2
    assert "unknown learners ['svm']" in capsys.readouterr().err

def test_replay_cli_runs_through_the_sweep_engine_alike_in_one_or_two_processes(passage_scene, tmp_path):
    """``pirl-sim replay`` keeps one cell per (split seed, method) in OUT/cells/ and gives the same rows with one
    worker process or two."""
    import json

    out, _ = passage_scene
    args = ["replay", "--preset", "paper",
            "--tracks", str(out), "--map", str(out / "map.osm"), "--seeds", "3", "--learners",
            "tirl,pirl-knn", "--knn-k", "3", "--lateral", "neighbours", "--quiet", "--out"]
    assert main(args + [str(tmp_path / "one")]) == 0
    assert main(args + [str(tmp_path / "two"), "--workers", "2"]) == 0
    cells = [json.loads(p.read_text()) for p in (tmp_path / "one" / "cells").glob("*.json")]
    assert sorted((c["cell"]["seed"], c["cell"]["learner"]) for c in cells) == sorted(
        (seed, m) for seed in range(3) for m in ("cv", "ca", "tirl", "pirl-knn", "cv-xy"))
    cols = ["seed", "method", "med", "med_path", "n_windows", "lateral_floor", "irl_converged", "de@3.0s"]
    one, two = (pd.read_csv(tmp_path / d / "rows.csv") for d in ("one", "two"))
    pd.testing.assert_frame_equal(one[cols], two[cols])
    with pytest.raises(SystemExit):
        main(args + [str(tmp_path / "none"), "--workers", "0"])


def test_an_interrupted_replay_resumes_from_its_finished_cells(passage_scene, tmp_path, monkeypatch, capsys):
    """The sweep engine stores each split seed's cells as they finish (``OUT/cells/``); a replay interrupted in
    its last seed runs only that seed again and writes the same results as an uninterrupted run (timings
    aside)."""
    import json

    import pirl_sim.experiments.recorded as recorded

    out, _ = passage_scene
    args = ["replay", "--preset", "paper",
            "--tracks", str(out), "--map", str(out / "map.osm"), "--seeds", "3", "--learners",
            "tirl,pirl-knn", "--knn-k", "3", "--quiet", "--out"]
    run_seed, ran = recorded.replay_seed, []

    def interrupted(scene, seed, *a, **kw):
        if seed == 2:
            raise KeyboardInterrupt
        return run_seed(scene, seed, *a, **kw)

    monkeypatch.setattr(recorded, "replay_seed", interrupted)
    assert main(args + [str(tmp_path / "resumed")]) == 130
    cells = tmp_path / "resumed" / "cells"
    stored = {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json")}
    assert sorted({json.loads(p.read_text())["cell"]["seed"] for p in cells.glob("*.json")}) == [0, 1]
    assert not (tmp_path / "resumed" / "rows.csv").exists()
    capsys.readouterr()
    assert main(args + [str(tmp_path / "resumed"), "--dry-run"]) == 0  # counts, runs nothing
    dry = capsys.readouterr().out
    assert not (tmp_path / "resumed" / "rows.csv").exists()
    monkeypatch.setattr(recorded, "replay_seed", lambda scene, seed, *a, **kw: ran.append(seed)
                        or run_seed(scene, seed, *a, **kw))
    assert main(args + [str(tmp_path / "resumed")]) == 0
    if len({json.loads(p.read_text())["code_version"] for p in cells.glob("*.json")}) > 1:
        pytest.skip("the code changed while the test ran (a shared working tree): every seed ran again")
    assert ran == [2]
    assert "15 cells, 10 already in" in dry and "5 to run" in dry  # CV, CA, TIRL, PIRL-kNN, CV (x, y) x 3 seeds
    assert {p.name: p.stat().st_mtime_ns for p in cells.glob("*.json") if p.name in stored} == stored
    assert main(args + [str(tmp_path / "fresh")]) == 0
    assert ran == [2, 0, 1, 2]
    for name in ("rows.csv", "summary.csv", "paired.csv", "paired_ca.csv"):
        a, b = (pd.read_csv(tmp_path / d / name) for d in ("resumed", "fresh"))
        timings = [c for c in a.columns if c.startswith(("fit_s", "predict_s"))]
        pd.testing.assert_frame_equal(a.drop(columns=timings), b.drop(columns=timings))


def test_replay_cells_are_keyed_by_the_data_files_and_the_settings(passage_scene, tmp_path):
    import argparse
    import shutil

    from pirl_sim.cli.replay import ReplayOptions, add_parser
    from pirl_sim.experiments.recorded import recorded_fingerprint

    out, _ = passage_scene
    scene = tmp_path / "scene"
    shutil.copytree(out, scene)
    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())

    def keys(*extra):
        args = parser.parse_args(["replay", "--preset", "paper", "--tracks", str(scene), "--map",
                                  str(scene / "map.osm"), *extra])
        return [c.key("code") for c in ReplayOptions.from_args(args).resolve().config().cells]

    first = keys("--seeds", "2")
    assert len(set(first)) == len(first) == 2 * 6  # CV, CA, TIRL, PIRL-GMM, PIRL-kNN, CV (x, y) per seed
    assert set(first) < set(keys("--seeds", "3"))  # another seed adds cells, the others are reused
    assert not set(first) & set(keys("--seeds", "2", "--estimate", "positions"))  # loading settings
    assert not set(first) & set(keys("--seeds", "2", "--start", "track"))
    assert not set(first) & set(keys("--seeds", "2", "--lateral", "plane"))  # replay settings
    params = {"tracks": str(scene), "map": str(scene / "map.osm"), "files": 0}
    fingerprints = [recorded_fingerprint(params)]
    for name in ("ground_truth.csv", "map.osm", "vehicle_tracks_000.csv"):  # sidecar, map, tracks
        with open(scene / name, "a") as f:
            f.write("\n")
        fingerprints.append(recorded_fingerprint(params))
    assert len(set(fingerprints)) == 4
    assert not set(first) & set(keys("--seeds", "2"))


def test_replay_cli_refuses_a_scene_with_too_few_tracks_before_any_cell(tmp_path, capsys):
    tracks, osm = straight_scene(tmp_path, [("A", 5.0, 150, None), ("B", 5.0, 150, None), ("A", 9.0, 150, None)])
    out = tmp_path / "out"
    assert main(["replay", "--preset", "paper",
                 "--tracks", str(tracks), "--map", str(osm), "--quiet", "--out", str(out)]) == 2
    assert "only 3 selected tracks" in capsys.readouterr().err
    assert not (out / "cells").exists()


def _replay_args(tmp_path, seed: int, learners: str, knn_k: str) -> list:
    """`pirl-sim replay` arguments (one split seed) on a small simulated three-style passage scene."""
    replay_scenes.passage_scene(tmp_path / "scene", n_trajectories=40, n_train=30, seed=seed)
    return ["replay", "--preset", "paper",
            "--tracks", str(tmp_path / "scene"), "--map", str(tmp_path / "scene" / "map.osm"),
            "--learners", learners, "--knn-k", knn_k, "--seeds", "1"]


def test_replay_cli_runs_the_next_learner_and_keeps_it_out_of_the_papers_ordering(tmp_path):
    import pandas as pd

    from pirl_sim.cli import main

    args = _replay_args(tmp_path, 5, "tirl,pirl-knn,pirl-knn-next", "3,5")
    assert main([*args, "--hindsight", "--out", str(tmp_path / "out")]) == 0
    rows = pd.read_csv(tmp_path / "out" / "rows.csv")
    med = rows.set_index("method")["med"]
    # the oracle row: each test window under the cost fitted on its own future beats every predictor
    assert med["hindsight cost (oracle)"] < 0.5 * med["CA (path)"]
    assert med["hindsight cost (oracle)"] < med.drop("hindsight cost (oracle)").min()
    nxt = rows[rows["method"].str.startswith("PIRL-kNN next")]
    assert sorted(nxt["method"]) == ["PIRL-kNN next (k=3)", "PIRL-kNN next (k=5)"]
    assert (nxt["irl_converged"] == nxt["irl_groups"]).all() and (nxt["irl_groups"] > 30).all()
    assert nxt["med"].notna().all() and (nxt["med"] > 0).all()
    assert nxt.set_index("method").loc["PIRL-kNN next (k=5)", "irl_from"] == "PIRL-kNN next (k=3)"
    assert nxt["ahead_weight"].isin([0.0, 0.5, 1.0]).all()  # the road's weight each split chose
    assert main([*args, "--rollout", "closed", "--mpc-horizon", "15", "--out", str(tmp_path / "bad")]) == 2


def test_replay_cli_sets_the_next_learners_segments_and_road_ahead(tmp_path, capsys):
    """pirl-knn-next: segments re-started at the history estimates and the curvature 0-45 m ahead in the
    look-up by default; --next-segments history needs history starts; bad distances are named."""
    from pirl_sim.cli import build_parser, main
    from pirl_sim.cli.replay import ReplayOptions

    args = _replay_args(tmp_path, 5, "pirl-knn-next", "3")
    ns = build_parser().parse_args(args)
    config = ReplayOptions.from_args(ns).resolve().config()
    (nxt,) = [e for e in config.experiments[0].learners if e.params.get("target") == "next"]
    assert nxt.params["segment_start"] == "history" and nxt.params["lookup_history"] is True
    assert list(nxt.params["lookup_ahead"]) == [0.0, 10.0, 20.0, 30.0, 45.0]
    assert list(nxt.params["ahead_weights"]) == [0.0, 0.5, 1.0]
    ns = build_parser().parse_args([*args, "--next-segments", "track", "--lookup-ahead", ""])
    config = ReplayOptions.from_args(ns).resolve().config()
    (nxt,) = [e for e in config.experiments[0].learners if e.params.get("target") == "next"]
    assert nxt.params["segment_start"] == "track" and list(nxt.params["lookup_ahead"]) == []
    assert main([*args, "--start", "track", "--next-segments", "history", "--out", str(tmp_path / "bad")]) == 2
    assert "--next-segments history" in capsys.readouterr().err
    for bad in ("-1", "5,far", "inf"):
        for option in ("--lookup-ahead", "--ahead-weights"):
            with pytest.raises(SystemExit):
                build_parser().parse_args([*args, f"{option}={bad}"])
    # an empty weight list is refused by the learner's check, named
    assert main([*args, "--ahead-weights=", "--out", str(tmp_path / "bad2")]) == 2
    assert "ahead_weights" in capsys.readouterr().err


def test_replay_cli_runs_the_selected_bank_once_whatever_the_k_grid(tmp_path):
    """pirl-select: the next-segment costs of pirl-knn-next, mixed to follow a forecast (learners/selector.py);
    one row per split (no k), the same segment and road-ahead settings as pirl-knn-next."""
    import pandas as pd

    from pirl_sim.cli import build_parser, main
    from pirl_sim.cli.replay import ReplayOptions

    args = _replay_args(tmp_path, 5, "tirl,pirl-knn-next,pirl-select", "3,5")
    ns = build_parser().parse_args(args)
    config = ReplayOptions.from_args(ns).resolve().config()
    (sel,) = [e for e in config.experiments[0].learners if e.params.get("aggregate") == "selected"]
    assert sel.params["target"] == "next" and sel.params["segment_start"] == "history"
    assert sel.params["target_steps"] == 15 and list(sel.params["lookup_ahead"]) == [0.0, 10.0, 20.0, 30.0, 45.0]
    assert main([*args, "--out", str(tmp_path / "out")]) == 0
    rows = pd.read_csv(tmp_path / "out" / "rows.csv").set_index("method")
    assert "PIRL-select" in rows.index and not any(m.startswith("PIRL-select (") for m in rows.index)
    assert rows.loc["PIRL-select", "irl_converged"] == rows.loc["PIRL-select", "irl_groups"] > 30
    assert 0 < rows.loc["PIRL-select", "med"] < rows.loc["CV (path)", "med"]


def test_replay_scores_k_futures_of_each_learner(tmp_path):
    import pandas as pd

    from pirl_sim.cli import main

    args = [*_replay_args(tmp_path, 6, "tirl,pirl-gmm,pirl-knn-next", "6"), "--futures", "6"]
    assert main([*args, "--out", str(tmp_path / "out")]) == 0
    rows = pd.read_csv(tmp_path / "out" / "rows.csv").set_index("method")
    learners = ["TIRL", "PIRL-GMM (k=3)", "PIRL-kNN next (k=6)"]
    for col in ("min_ade@6", "min_fde@6", "miss_rate@6", "nll_per_step@6"):
        assert rows.loc[learners, col].notna().all(), col
        assert rows.loc[["CA (path)", "CV (path)"], col].isna().all()
    # TIRL has one future: its minADE is its MED; more futures can only lower the best one's error
    assert rows.loc["TIRL", "min_ade@6"] == pytest.approx(rows.loc["TIRL", "med"])
    assert rows.loc["PIRL-kNN next (k=6)", "min_ade@6"] <= rows.loc["PIRL-kNN next (k=6)", "med"] + 1e-9
    assert ((rows.loc[learners, "miss_rate@6"] >= 0) & (rows.loc[learners, "miss_rate@6"] <= 1)).all()
    summary = (tmp_path / "out" / "summary.md").read_text()
    assert "min_ade@6_mean" in summary
    # futures are open-loop plans: a closed-loop rollout is refused before any fit
    assert main([*args, "--rollout", "closed", "--mpc-horizon", "15", "--out", str(tmp_path / "bad")]) == 2


@pytest.mark.parametrize("option,value", [("--history", "-5"), ("--history", "0"), ("--horizon", "-3"),
                                          ("--horizon", "nan"), ("--history", "abc")])
def test_replay_cli_rejects_durations_that_are_not_positive(tmp_path, capsys, option, value):
    tracks, osm = two_lane_scene_dir(tmp_path)
    with pytest.raises(SystemExit) as exc:
        main(["replay", "--preset", "paper",
              "--tracks", str(tracks), "--map", str(osm), option, value, "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert option in err and "> 0" in err and value in err


def test_replay_cli_rejects_a_duration_shorter_than_a_step(tmp_path, capsys):
    tracks, osm = two_lane_scene_dir(tmp_path)
    code = main(["replay", "--preset", "paper",
                 "--tracks", str(tracks), "--map", str(osm), "--history", "0.05", "--quiet",
                 "--out", str(tmp_path / "o")])
    assert code == 2 and "--history 0.05 s is less than one model step" in capsys.readouterr().err


@pytest.mark.slow
def test_replay_cli_receding_beats_constant_acceleration(tmp_path):
    """40 vehicles (on 20, 12 training tracks are too few for the kNN look-up: its weights miss the style)."""
    pytest.importorskip("libsumo")
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION
    from pirl_sim.scenarios.sumo import SumoScenarioConfig, run_sumo_scenario

    run = tmp_path / "run40"
    pop = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=40)
    run_sumo_scenario(SumoScenarioConfig(population=pop), seed=1, out_dir=run)
    out = tmp_path / "res"
    assert main(["replay", "--preset", "paper",
                 "--tracks", str(run), "--map", str(run / "map.osm"), "--likelihood", "receding",
                 "--learners", "tirl,pirl-knn", "--knn-k", "5", "--seeds", "3", "--out", str(out), "--quiet"]) == 0
    summary = pd.read_csv(out / "summary.csv").set_index("method")
    knn = "PIRL-kNN (k=5)"
    assert summary.loc[knn, "irl_weight_error_mean"] < 0.05
    assert summary.loc[knn, "med_mean"] < summary.loc["CA (path)", "med_mean"]
    paired = pd.read_csv(out / "paired_ca.csv").set_index("method")
    assert paired.loc[knn, "mean_difference"] < -2 * paired.loc[knn, "standard_error"]
    readme = (out / "README.md").read_text()
    assert "selection='steps'" in readme and "Paired differences against CA (path)" in readme


def test_receding_without_a_horizon_on_real_data_names_the_option(real_like, capsys):
    base = ["replay", "--preset", "paper", "--tracks", str(real_like), "--map", str(real_like / "map.osm"), "--out",
            str(real_like / "out"), "--quiet"]
    assert main(base + ["--likelihood", "receding"]) == 2
    assert "--mpc-horizon" in capsys.readouterr().err
    assert main(base + ["--rollout", "closed"]) == 2
    assert "--mpc-horizon" in capsys.readouterr().err
    assert main(base + ["--likelihood", "receding", "--mpc-horizon", "10", "--selection", "steps"]) == 2
    assert "driver_steps.csv" in capsys.readouterr().err
    assert main(base + ["--selection", "steps"]) == 2
    assert "--likelihood receding" in capsys.readouterr().err
    for bad in ("0", "-3", "ten"):
        with pytest.raises(SystemExit) as exc:
            main(base + ["--likelihood", "receding", "--mpc-horizon", bad])
        assert exc.value.code == 2
        assert "--mpc-horizon must be a positive number of steps" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(base + ["--dt", "0"])


def test_replay_cli_applies_the_lateral_model_to_a_single_recording(tmp_path):
    from pirl_sim.cli import main

    tracks, osm = weaving_scene(tmp_path)
    floors = {}
    for lateral in ("hold", "mean-path", "neighbours"):
        out = tmp_path / lateral
        assert main(["replay", "--preset", "paper",
                     "--tracks", str(tracks), "--map", str(osm), "--out", str(out), "--seeds", "1",
                     "--learners", "tirl", "--lateral", lateral, "--quiet"]) == 0
        floors[lateral] = pd.read_csv(out / "rows.csv")["lateral_floor"].iloc[0]
    assert floors["mean-path"] < 0.5 * floors["hold"]
    assert floors["neighbours"] < 0.5 * floors["hold"]


def test_table_command_end_to_end(passage_root, tmp_path, capsys):
    out = tmp_path / "table"
    assert main(["replay", "--preset", "paper",
                 "--table", str(passage_root), "--roundabouts", "SIM_Roundabout_A", "--seeds", "2",
                 "--learners", "tirl,pirl-knn", "--knn-k", "5", "--desired-speed", "fit", "--direct", "--out",
                 str(out), "--quiet"]) == 0
    text = (out / "table.md").read_text()
    assert "| SIM_Roundabout_A |" in text and "MED_best / MED_CA" in text and "free-flow runs" in text
    assert (out / "SIM_Roundabout_A" / "summary.csv").is_file()
    table = pd.read_csv(out / "table.csv")
    # the direct regression has its row and its ratio to CA, but is never the best PIRL learner
    assert table["best"].sum() == 1 and table.loc[table["best"], "method"].item() == "PIRL-kNN (k=5)"
    med = table.set_index("method")["med"]
    header, row = [line for line in text.splitlines() if "direct regression (no cost) / CA" in line
                   or line.startswith("| SIM_Roundabout_A | vehicle_tracks")]
    ratio = row.split(" | ")[header.split(" | ").index("direct regression (no cost) / CA")]
    assert float(ratio.split(" ")[0]) == pytest.approx(med["direct regression (no cost)"] / med["CA (path)"], abs=1e-3)
    n_windows = int(row.split(" | ")[header.split(" | ").index("windows")])
    split = [int(line.split(" | ")[1]) for line in text.splitlines()
             if line.startswith(("| SIM_Roundabout_A (entry) |", "| SIM_Roundabout_A (other) |"))]
    assert len(split) == 2 and sum(split) == n_windows  # the entry windows and the others, each counted once
    assert main(["replay", "--preset", "paper", "--table", str(passage_root), "--roundabouts", "NO_SUCH_Roundabout",
                 "--out", str(out)]) == 2
    assert "NO_SUCH_Roundabout" in capsys.readouterr().err  # any name is read; a missing folder is named
    assert main(["replay", "--out", str(out)]) == 2


def _recording(d, steps: bool = True):
    """A tracks directory ``d`` that reads as a pirl_sim recording of MPC drivers (run.json; driver_steps.csv
    when ``steps``): what `ReplayOptions.resolve` looks at, no tracks."""
    import json

    d.mkdir()
    drivers = {"horizon": 30, "smoothing": 2.0, "speed_smoothing": 10.0, "a_lat": 1.7, "v_max": 12.5}
    (d / "run.json").write_text(json.dumps({"format": "pirl_sim scenario recording", "step_length_s": 0.1,
                                            "config": {"drivers": drivers}}))
    if steps:
        (d / "driver_steps.csv").write_text("track_id,frame_id,commanded,overridden,collided\n")
    return d


@pytest.mark.parametrize("field,value,says", [
    ("gmm_k", 0, "expected a positive integer"), ("seeds", 2.5, "expected a positive integer"),
    ("dt", float("nan"), "expected a finite number > 0"), ("mpc_horizon", 0, "positive number of steps"),
    ("knn_k", (), "comma-separated integers >= 1"), ("lookup_ahead", (-1.0,), "numbers >= 0"),
    ("features", "speed", "one of ('paper', 'speed-level', 'following', 'interacting')"), ("hindsight", 1, "a value of type bool"),
    ("learners", "tirl", "a value of type tuple[str, ...]"), ("out", "results", "a value of type Path")])
def test_replay_options_name_a_bad_value_and_what_is_allowed(tmp_path, field, value, says):
    from pirl_sim.cli.replay import ReplayOptions

    with pytest.raises(ValueError) as exc:
        ReplayOptions(tracks=tmp_path, map=tmp_path / "map.osm", **{field: value})
    assert str(exc.value).startswith(f"{field}={value!r}: ") and says in str(exc.value)


def test_replay_options_are_the_parsed_command_line_frozen_and_checked_together(tmp_path):
    from pirl_sim.cli import build_parser
    from pirl_sim.cli.replay import ReplayOptions

    where = {"tracks": tmp_path, "map": tmp_path / "map.osm"}
    argv = ["replay", "--tracks", str(tmp_path), "--map", str(tmp_path / "map.osm")]
    assert ReplayOptions.from_args(build_parser().parse_args(argv)) == ReplayOptions(**where)  # the same defaults
    options = ReplayOptions.from_args(build_parser().parse_args([*argv, "--knn-k", "3,10", "--learners",
                                                                 "pirl-select", "--dt", "0.1"]))
    assert options.knn_k == (3, 10) and options.learners == ("pirl-select",) and options.dt == 0.1
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.dt = 0.2
    for bad, says in [({"learners": ("tirl", "svm")}, "unknown learners ['svm']"),
                      ({"selection": "steps"}, "--selection steps needs --likelihood receding"),
                      ({"start": "track", "next_segments": "history", "learners": ("pirl-knn-next",)},
                       "--next-segments history"), ({"tracks": None}, "replay needs --tracks and --map")]:
        with pytest.raises(ValueError, match=re.escape(says)):
            ReplayOptions(**{**where, **bad})


def _table_command(readme: str) -> list[str]:
    """The options of the README's real-roundabout table command (its ``pirl-sim replay --table`` line)."""
    import shlex

    line = next(x for x in readme.splitlines() if x.startswith("| Real roundabouts"))
    command = next(c for c in line.split("`") if c.startswith("pirl-sim replay --table"))
    return shlex.split(command)[1:]


def test_the_defaults_on_real_data_are_the_readmes_table_configuration_and_paper_is_one_option(tmp_path):
    from pathlib import Path

    from pirl_sim.cli import build_parser
    from pirl_sim.cli.replay import ReplayOptions

    real = tmp_path / "real"
    real.mkdir()
    argv = _table_command((Path(__file__).parents[2] / "README.md").read_text())
    table = ReplayOptions.from_args(build_parser().parse_args(argv))
    data = {"tracks": real, "map": real / "map.osm"}
    plain = ReplayOptions(**data).resolve()
    # the table's command names data, scale and extra rows only: every model setting is the default
    resolved = dataclasses.replace(table, table=None, **data).resolve()
    model = ("dt", "mpc_horizon", "rollout", "selection", "estimate", "noise", "features", "desired_speed")
    assert {k: getattr(resolved, k) for k in model} == {k: getattr(plain, k) for k in model}
    assert resolved.learner_entries()[:-3] == plain.learner_entries()[:-1]  # + hindsight, direct (before CV (x, y))
    assert (plain.features, plain.desired_speed, plain.selection, plain.options.lateral) == (
        "speed-level", "fit", "free", "neighbours")
    assert plain.options.learners == ("tirl", "pirl-gmm", "pirl-knn", "pirl-knn-next", "pirl-select")
    paper = ReplayOptions(**data, preset="paper").resolve()
    assert (paper.features, paper.desired_speed, paper.selection, paper.options.lateral, paper.options.learners) == (
        "paper", "fixed", "tracks", "hold", ("tirl", "pirl-gmm", "pirl-knn"))
    mixed = ReplayOptions(**data, preset="paper", features="speed-level", learners=("tirl",)).resolve()
    assert (mixed.features, mixed.options.learners, mixed.options.lateral) == ("speed-level", ("tirl",), "hold")
    with pytest.raises(ValueError, match=r"preset='fast': expected one of \('best', 'paper'\)"):
        ReplayOptions(**data, preset="fast")


def test_resolved_defaults_of_a_pirl_sim_recording_and_of_real_data(tmp_path):
    from pirl_sim.cli.replay import ReplayOptions
    from pirl_sim.scenarios.replay import MEASURED_NOISE, SIMULATED_NOISE

    run, real = _recording(tmp_path / "run"), tmp_path / "real"
    real.mkdir()
    receding = ReplayOptions(tracks=run, map=run / "map.osm", likelihood="receding").resolve()
    assert (receding.dt, receding.mpc_horizon, receding.rollout, receding.selection, receding.estimate) == (
        0.1, 30, "closed", "steps", "speeds")
    assert receding.noise == SIMULATED_NOISE and len(receding.notes) == 3
    assert {k: receding.load()[k] for k in ("smoothing", "speed_smoothing", "a_lat", "v_max", "arc_length")} == {
        "smoothing": 2.0, "speed_smoothing": 10.0, "a_lat": 1.7, "v_max": 12.5, "arc_length": "observed"}
    p = receding.protocol()
    assert (p.history, p.horizon, p.stride, p.fde_steps, p.mpc_horizon) == (20, 30, 10, (10, 20, 30), 30)
    # the trajectory likelihood keeps the paper's step: the drivers' horizon in their own steps does not apply
    paper = ReplayOptions(tracks=run, map=run / "map.osm", a_lat=2.0).resolve()
    assert (paper.dt, paper.mpc_horizon, paper.rollout, paper.selection) == (0.2, None, "open", "tracks")
    assert paper.load()["a_lat"] == 2.0 and paper.load()["v_max"] == 12.5  # an option beats run.json
    assert (paper.features, paper.desired_speed) == ("paper", "fixed")  # known drivers: their own model
    with pytest.raises(ValueError, match="give --mpc-horizon in steps of --dt"):
        ReplayOptions(tracks=run, map=run / "map.osm", likelihood="receding", dt=0.2).resolve()
    data = ReplayOptions(tracks=real, map=real / "map.osm", sigma_v=0.2).resolve()
    assert (data.dt, data.mpc_horizon, data.selection, data.estimate, data.recording, data.notes) == (
        0.2, None, "free", "speeds", None, ())
    assert data.noise == dataclasses.replace(MEASURED_NOISE, sigma_v=0.2) and "arc_length" not in data.load()
    assert ReplayOptions(tracks=real, map=real, features="following").resolve().selection == "all"
    assert ReplayOptions(tracks=real, map=real, start="track").resolve().estimate == "positions"
    assert ReplayOptions(tracks=real, map=real, scan_horizon=(5, 8), likelihood="receding").resolve().mpc_horizon == 5
    with pytest.raises(ValueError, match="--likelihood receding needs the drivers' MPC horizon"):
        ReplayOptions(tracks=real, map=real, likelihood="receding").resolve()
    with pytest.raises(ValueError, match="--selection steps needs driver_steps.csv"):
        ReplayOptions(tracks=_recording(tmp_path / "no_steps", steps=False), map=real, likelihood="receding",
                      selection="steps").resolve()


@pytest.mark.parametrize("argv, message", [
    (["--tracks", "t.csv", "--map", "m.osm", "--roundabouts", "X"], "--roundabouts names the roundabouts of --table"),
    (["--table", ".", "--tracks", "t.csv"], "--table ROOT replaces --tracks and --map"),
    (["--table", ".", "--map", "m.osm"], "--table ROOT replaces --tracks and --map"),
    (["--tracks", "t.csv", "--map", "m.osm", "--out", "t.csv"], "is a file, not a directory"),
])
def test_replay_refuses_options_that_contradict_each_other(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "t.csv").write_text("track_id\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["replay", *argv, "--dry-run"]) == 2
    assert message in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == before and (tmp_path / "t.csv").read_text() == "track_id\n"


def test_closed_loop_rollouts_refuse_the_learners_that_average_or_choose_futures(tmp_path):
    """--likelihood receding rolls out closed loops by default; PIRL-kNN next and PIRL-select (the defaults of
    --preset best) and --futures predict open-loop plans: the config says so before any cell runs."""
    from pirl_sim.cli.replay import ReplayOptions

    run = _recording(tmp_path / "run")
    for extra in ({}, {"learners": ("tirl",), "futures": 6}):
        options = ReplayOptions(tracks=run, map=run / "map.osm", likelihood="receding", **extra).resolve()
        with pytest.raises(ValueError, match=r"--rollout closed re-plans at every step.*give --rollout open"):
            options.config()
