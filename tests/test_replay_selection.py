"""Issue 12: selection by bumper-to-bumper gaps, free-flow runs of interacting tracks, desired speed fitted per
map, and the multi-roundabout table (all on generated data)."""

import warnings

import numpy as np
import pandas as pd
import pytest

from pirl_sim.cli import main
from pirl_sim.driving import smooth_desired_speed
from pirl_sim.experiments.replay_report import ReplayProtocol, run_replay
from pirl_sim.scenarios.replay import (
    CENTRE_RULE,
    SelectionRule,
    leader_frames,
    leader_gaps,
    load_replay,
    selection_counts,
)
from pirl_sim.speed_fit import fit_desired_speed

CAR_LENGTH = 4.6  # [m]


def _rows(track_id, frames, x, speed, y=0.0):
    frames = np.asarray(frames)
    return pd.DataFrame({"track_id": track_id, "frame_id": frames, "timestamp_ms": 100 * frames, "agent_type": "car",
                         "x": np.asarray(x, dtype=float), "y": y, "vx": speed, "vy": 0.0, "psi_rad": 0.0,
                         "length": CAR_LENGTH, "width": 1.8})


def test_a_standing_queue_is_caught_by_bumper_gaps_not_by_centre_distances():
    """Three cars stand 7 m apart centre to centre (bumper gaps 2.4 m): the rule before (5 m centre to
    centre) misses the queue, the bumper rule (3 m) catches it; the front car has no leader."""
    frames = np.arange(1, 11)
    df = pd.concat([_rows(i, frames, np.full(10, 7.0 * i), 0.0) for i in (1, 2, 3)], ignore_index=True)
    gaps = leader_gaps(df, SelectionRule())
    np.testing.assert_allclose(gaps[df["track_id"].to_numpy() < 3], 7.0 - CAR_LENGTH)
    assert np.all(np.isinf(gaps[df["track_id"].to_numpy() == 3]))
    assert not leader_frames(df, CENTRE_RULE).any()
    lead = leader_frames(df, SelectionRule())
    assert lead[df["track_id"].to_numpy() < 3].all() and not lead[df["track_id"].to_numpy() == 3].any()
    with pytest.raises(ValueError, match="length column"):
        leader_gaps(df.drop(columns="length"), SelectionRule())
    with pytest.raises(ValueError, match="gap must be one of"):
        SelectionRule(gap="edge")


@pytest.fixture()
def following_scene(tmp_path):
    """A 30 s follower at 10 m/s on a straight lane; a leader 10 m ahead of it (bumper gap 5.4 m < 3 m +
    1.5 s x 10 m/s) for frames 100-160 only."""
    from pirl_sim.io.interaction import write_tracks
    from pirl_sim.io.lanelet2_map import write_map

    x = np.linspace(0.0, 500.0, 41)
    write_map({"A": np.column_stack([x, np.zeros_like(x)])}, {}, tmp_path / "map.osm")
    f = np.arange(1, 301)
    lead = np.arange(100, 161)
    df = pd.concat([_rows(1, f, 5.0 + (f - 1), 10.0), _rows(2, lead, 15.0 + (lead - 1), 10.0)], ignore_index=True)
    write_tracks(df, tmp_path / "vehicle_tracks_000.csv")
    return tmp_path / "vehicle_tracks_000.csv", tmp_path / "map.osm"


def test_free_selection_keeps_the_free_flow_runs_of_an_interacting_track(following_scene):
    tracks, osm = following_scene
    whole = load_replay([tracks], osm)
    assert {t.metadata["track_id"] for t in whole.selected} == {2}  # the follower interacted
    free = load_replay([tracks], osm, selection="free", max_steps=None)
    pieces = [t for t in free.selected if t.metadata["track_id"] == 1]
    assert len(pieces) == 2  # before and after the leader
    for t in pieces:  # no step of a kept run touches a frame with the leader (follower x 104 .. 164 m)
        x = t.metadata["xy"][:, 0]
        assert np.all((x <= 104.0) | (x >= 164.0)) and (x.max() <= 104.0 or x.min() >= 164.0)
    assert free.steps["steps with a leader (left out)"] == 31  # frames 99-161 at 0.2 s steps (both ends)
    counts = selection_counts(free, 25).set_index("selection")
    assert counts.loc["whole tracks without a leader (the rule before)", "usable"] == 1
    assert counts.loc["whole tracks without a leader", "usable"] == 1
    assert counts.loc["free-flow runs (steps with a leader left out)", "usable"] == 2
    assert set(counts["matched"]) == {2}


def test_desired_speed_fit_recovers_a_lat_and_v_max_despite_braking_outliers():
    rng = np.random.default_rng(0)
    kappa = rng.uniform(0.0, 0.12, 4000)
    v = smooth_desired_speed(kappa, 2.5, 11.0)[0] + rng.normal(0.0, 0.3, kappa.size)
    slow = rng.random(kappa.size) < 0.15  # braking to yield: far below the desired speed
    v[slow] = rng.uniform(1.0, 3.0, slow.sum())
    fit = fit_desired_speed(kappa, v)
    assert fit.a_lat == pytest.approx(2.5, rel=0.05) and fit.v_max == pytest.approx(11.0, rel=0.03)
    assert fit.converged and not fit.at_bound and fit.n_samples == int((v >= 1.0).sum())
    with pytest.raises(ValueError, match="same shape"):
        fit_desired_speed(kappa, v[:-1])
    with pytest.raises(ValueError, match="at least 10 samples"):
        fit_desired_speed(kappa[:5], v[:5])


@pytest.fixture(scope="module")
def passage_root(tmp_path_factory):
    """A simulated roundabout scene laid out as an INTERACTION folder (recorded_trackfiles/NAME, maps/NAME.osm)."""
    from pirl_sim.scenarios.passage import PassageConfig, generate, write_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        data = generate(PassageConfig(n_trajectories=40, n_train=30, seed=4))
    root = tmp_path_factory.mktemp("root")
    scene = root / "recorded_trackfiles" / "SIM_Roundabout_A"
    scene.mkdir(parents=True)
    write_scene(data, scene)
    (root / "maps").mkdir()
    (scene / "map.osm").rename(root / "maps" / "SIM_Roundabout_A.osm")
    return root


def test_run_replay_fits_the_desired_speed_per_split(passage_root):
    name = "SIM_Roundabout_A"
    scene = load_replay([passage_root / "recorded_trackfiles" / name / "vehicle_tracks_000.csv"],
                        passage_root / "maps" / f"{name}.osm")
    proto = ReplayProtocol(seeds=(0, 1))
    fitted = run_replay(scene, [("TIRL", "tirl", {})], proto, desired_speed="fit")["rows"]
    assert fitted.groupby("seed")["a_lat"].nunique().eq(1).all()
    assert fitted["a_lat"].between(0.2, 8.0).all() and fitted["v_max"].between(2.0, 40.0).all()
    fixed = run_replay(scene, [("TIRL", "tirl", {})], proto, desired_speed=(2.0, 12.0))["rows"]
    assert set(fixed["a_lat"]) == {2.0} and set(fixed["v_max"]) == {12.0}
    default = run_replay(scene, [("TIRL", "tirl", {})], proto)["rows"]
    assert set(default["a_lat"]) == {scene.a_lat}


def test_table_command_end_to_end(passage_root, tmp_path, capsys):
    out = tmp_path / "table"
    assert main(["replay", "--table", str(passage_root), "--roundabouts", "SIM_Roundabout_A", "--seeds", "2",
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
    assert main(["replay", "--table", str(passage_root), "--roundabouts", "DR_USA_Roundabout_SR",
                 "--out", str(out)]) == 2
    assert "held-out" in capsys.readouterr().err
    assert main(["replay", "--out", str(out)]) == 2
