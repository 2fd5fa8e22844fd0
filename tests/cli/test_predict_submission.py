"""``pirl-sim predict --futures K``: the INTERACTION prediction challenge's submission layout (INTERPRET,
single-agent regular track) and its ``<OUT stem>_proba.csv``, on a generated passage recording."""

import csv
import itertools
import math
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from pirl_sim.scenarios.passage import PassageConfig, write_scene
from pirl_sim.scenarios.passage import generate as generate_passage

from pirl_sim.cli import main

HEADER = ["case_id", "frame_id", "timestamp_ms", "track_id", "agent_role", "agent_type"]


def check_submission(path: Path, n_futures: int, n_cases: int) -> pd.DataFrame:
    """Assert that ``path`` is a submission of ``n_cases`` cases with ``n_futures`` modes as the challenge reads
    it, with its ``<stem>_proba.csv``; returns the submission as a DataFrame."""
    with path.open(newline="") as fh:
        lines = list(csv.reader(fh))
    header, rows = lines[0], lines[1:]
    assert header[:6] == HEADER
    assert header[6:] == [f"{c}{k}" for k in range(1, n_futures + 1) for c in "xy"]  # K pairs and nothing else
    assert rows and all(len(r) == len(header) for r in rows)
    ids = [r[0] for r in rows]
    groups = [ids[0]] + [b for a, b in itertools.pairwise(ids) if b != a]
    assert len(groups) == len(set(groups)) == n_cases  # each case's rows together, one case per predicted track
    table = pd.read_csv(path)
    assert all(np.isfinite(table.iloc[:, 6:].to_numpy(dtype=float)).ravel())
    assert set(table["agent_role"]) == {"agent"} and set(table["agent_type"]) == {"car"}
    for _, case in table.groupby("case_id", sort=False):
        assert case["track_id"].nunique() == 1
        assert np.all(np.diff(case["frame_id"]) == 1)  # one row per 0.1 s frame, in time order
        assert np.all(np.diff(case["timestamp_ms"]) == 100)
        offset = case["timestamp_ms"] - 100 * case["frame_id"]
        assert offset.nunique() == 1  # timestamp_ms consistent with frame_id, as in INTERACTION files
    proba = pd.read_csv(path.with_name(f"{path.stem}_proba.csv"))
    assert list(proba.columns) == ["case_id"] + [f"p{k}" for k in range(1, n_futures + 1)]
    assert sorted(proba["case_id"]) == sorted(table["case_id"].unique())
    p = proba.iloc[:, 1:].to_numpy(dtype=float)
    assert np.all(p >= 0) and np.allclose(p.sum(axis=1), 1.0, atol=1e-9)
    return table


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A passage recording and pirl-gmm (3 styles; ``gmm-w``: in the weight space, which draws its futures) and
    TIRL model files fitted on it."""
    tmp = tmp_path_factory.mktemp("submission")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate_passage(PassageConfig(n_trajectories=40, n_train=30, n_steps=25, seed=4))
    scene = tmp / "scene"
    write_scene(data, scene)
    for name, learner, extra in (("pirl-gmm", "pirl-gmm", ["--k", "3"]), ("tirl", "tirl", []),
                                 ("gmm-w", "pirl-gmm", ["--k", "3", "--space", "weights"])):
        assert main(["fit-model", "--tracks", str(scene), "--map", str(scene / "map.osm"), "--learner", learner,
                     *extra, "--out", str(tmp / name), "--quiet"]) == 0
    return tmp


def _predict(tmp, model, out, *extra):
    scene = tmp / "scene"
    return main(["predict", "--model", str(tmp / f"{model}.npz"), "--tracks", str(scene), "--map",
                 str(scene / "map.osm"), "--out", str(out), "--quiet", *extra])


def test_a_pirl_gmm_submission_has_its_styles_as_modes(fitted, capsys):
    out = fitted / "gmm_sub.csv"
    assert _predict(fitted, "pirl-gmm", out, "--futures", "6", "--horizon", "3") == 0
    assert "40 cases, 6 futures, 30 frames" in capsys.readouterr().out
    table = check_submission(out, 6, 40)
    assert table.groupby("case_id").size().eq(30).all()  # 3 s at 0.1 s
    proba = pd.read_csv(fitted / "gmm_sub_proba.csv")
    assert (proba[["p4", "p5", "p6"]] == 0).all().all()  # 3 styles, padded to 6 at probability 0
    assert (proba["p1"] >= proba["p2"]).all() and (proba["p2"] >= proba["p3"]).all()  # most probable first
    assert np.allclose(table[["x4", "y4"]], table[["x1", "y1"]])  # the padding repeats the most probable
    assert np.abs(table["x2"] - table["x1"]).max() > 0.1  # the styles predict different futures


def test_a_tirl_submission_is_its_one_future_padded(fitted):
    out = fitted / "tirl_sub.csv"
    assert _predict(fitted, "tirl", out, "--futures", "6") == 0
    table = check_submission(out, 6, 40)
    proba = pd.read_csv(fitted / "tirl_sub_proba.csv")
    assert (proba["p1"] == 1).all() and (proba[[f"p{k}" for k in range(2, 7)]] == 0).all().all()
    for k in range(2, 7):
        assert (table[f"x{k}"] == table["x1"]).all() and (table[f"y{k}"] == table["y1"]).all()


def test_the_first_predicted_frame_follows_the_history_in_the_track_file(fitted):
    out = fitted / "frames.csv"
    history_s = 2.4  # 12 steps of 0.2 s: 24 frames after the track's first
    assert _predict(fitted, "tirl", out, "--futures", "2", "--history", str(history_s), "--horizon", "1") == 0
    table = check_submission(out, 2, 40)
    recorded = pd.read_csv(fitted / "scene" / "vehicle_tracks_000.csv")
    firsts = table.groupby("case_id", sort=False).head(1)
    for _, row in firsts.iterrows():
        track = recorded[recorded["track_id"] == row["track_id"]].sort_values("frame_id")
        last = track["frame_id"].iloc[0] + round(history_s / 0.1)  # the history's last recorded frame
        assert row["frame_id"] == last + 1
        at = track[track["frame_id"] == last + 1]
        assert len(at) == 1 and int(at["timestamp_ms"].iloc[0]) == row["timestamp_ms"]
        gap = math.hypot(row["x1"] - at["x"].iloc[0], row["y1"] - at["y"].iloc[0])
        assert gap < 2.0, (row["track_id"], gap)  # metres, 0.1 s after the history


def test_a_submission_may_go_to_any_file_name_and_the_draws_follow_the_seed(fitted):
    a, b, c = fitted / "draws_a.txt", fitted / "draws_b.txt", fitted / "draws_c.txt"
    for out, seed in ((a, "7"), (b, "7"), (c, "8")):
        assert _predict(fitted, "gmm-w", out, "--futures", "3", "--seed", seed, "--horizon", "1") == 0
    first = check_submission(a, 3, 40)
    proba = pd.read_csv(fitted / "draws_a_proba.csv")
    assert np.allclose(proba[["p1", "p2", "p3"]], 1 / 3)  # weights drawn from the posterior: equally likely
    assert a.read_bytes() == b.read_bytes()
    assert (fitted / "draws_a_proba.csv").read_bytes() == (fitted / "draws_b_proba.csv").read_bytes()
    other = check_submission(c, 3, 40)
    assert not np.allclose(first[["x1", "x2", "x3"]], other[["x1", "x2", "x3"]])  # another seed, other draws


@pytest.mark.parametrize("option, value", [("--futures", "0"), ("--futures", "two"), ("--seed", "-1")])
def test_bad_values_exit_2_naming_the_option(fitted, capsys, option, value):
    out = fitted / "bad.csv"
    extra = [option, value] + ([] if option == "--futures" else ["--futures", "2"])
    with pytest.raises(SystemExit) as stop:
        _predict(fitted, "tirl", out, *extra)
    assert stop.value.code == 2
    assert f"argument {option}" in capsys.readouterr().err
    assert not out.exists()


def test_the_proba_file_never_overwrites_an_input(fitted, capsys):
    scene = fitted / "scene"
    taken = fitted / "sub_proba.csv"  # given as the map: predict --out sub.csv would write its probabilities there
    taken.write_bytes((scene / "map.osm").read_bytes())
    before = taken.read_bytes()
    assert main(["predict", "--model", str(fitted / "tirl.npz"), "--tracks", str(scene), "--map", str(taken),
                 "--out", str(fitted / "sub.csv"), "--futures", "1", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "the probabilities of --out" in err and "is one of the inputs" in err
    assert taken.read_bytes() == before and not (fitted / "sub.csv").exists()


def test_a_track_whose_frames_are_not_in_its_file_is_a_clear_error(fitted):
    from pirl_sim.cli.predict import history_end_frames
    from pirl_sim.trajectory import Trajectory

    recorded = pd.read_csv(fitted / "scene" / "vehicle_tracks_000.csv")
    track = recorded[recorded["track_id"] == 3].sort_values("frame_id")
    xy = track[["x", "y"]].to_numpy()[::2]
    meta = {"file": str(fitted / "scene" / "vehicle_tracks_000.csv"), "track_id": 3, "xy": xy}
    t = Trajectory(np.zeros((len(xy), 3)), np.zeros((len(xy) - 1, 1)), 0.2, meta)
    frame, stamp = history_end_frames([t], 5, 2)[0]
    assert frame == track["frame_id"].iloc[10] and stamp == track["timestamp_ms"].iloc[10]
    moved = Trajectory(t.states, t.controls, 0.2, dict(meta, xy=xy + [0.0, 0.01]))
    with pytest.raises(ValueError, match=r"vehicle_tracks_000\.csv: no frames of track 3"):
        history_end_frames([moved], 5, 2)


def test_a_horizon_too_long_to_hold_is_refused_before_any_work(tmp_path, capsys):
    from pirl_sim.cli.predict import MAX_HORIZON_S

    out = tmp_path / "p.csv"
    code = main(["predict", "--model", str(tmp_path / "no_model.npz"), "--tracks", str(tmp_path), "--map",
                 str(tmp_path / "map.osm"), "--horizon", "1e9", "--out", str(out), "--quiet"])
    assert code == 2 and not out.exists()
    err = capsys.readouterr().err
    assert f"--horizon 1e+09 s is longer than {MAX_HORIZON_S:g} s" in err


def test_a_sidecar_beside_the_track_file_is_never_overwritten(fitted, capsys):
    """Given one track file, the recording's files beside it (ground truth, run.json, ...) are inputs too."""
    scene = fitted / "scene"
    sidecars = [p for p in scene.iterdir() if p.name in ("ground_truth.csv", "run.json")]
    assert sidecars
    for target in sidecars:
        before = target.read_bytes()
        assert main(["predict", "--model", str(fitted / "tirl.npz"), "--tracks", str(scene / "vehicle_tracks_000.csv"),
                     "--map", str(scene / "map.osm"), "--out", str(target), "--quiet"]) == 2
        assert "is one of the inputs" in capsys.readouterr().err
        assert target.read_bytes() == before


def test_too_many_futures_is_a_clear_error_before_anything_is_allocated(fitted, capsys):
    assert _predict(fitted, "tirl", fitted / "many.csv", "--futures", "1000000000") == 2
    assert "--futures 1000000000: at most 100 modes per case" in capsys.readouterr().err
