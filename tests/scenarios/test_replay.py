"""Recordings loaded for the replay (pirl_sim.scenarios.replay): the INTERACTION format in, bad files counted,
interaction flags and free-flow selection, routes and their cuts, start states, recording settings, ground-truth
sidecars, and track files with broken rows read leniently."""

from functools import partial

import numpy as np
import pandas as pd
import pytest

from pirl_sim.experiments.replay_report import ReplayProtocol
from pirl_sim.io.interaction import read_tracks
from pirl_sim.scenarios.passage import recording
from pirl_sim.scenarios.replay import (
    CENTRE_RULE,
    SelectionRule,
    _estimate,
    interaction_flags,
    leader_frames,
    leader_gaps,
    load_replay,
    selection_counts,
)

from replay_scenes import (
    LANE_Y,
    check_bad_read_options,
    load_sumo_scene,
    straight_scene,
    track_rows,
    two_lane_scene_dir,
    write_ground_truth,
)
from shared_sample import needs_sample
from shared_sample import DATA as SHARED


def test_simulated_scene_round_trips_through_the_interaction_format(passage_scene):
    out, data = passage_scene
    tracks = recording(data).tracks.sort_values(["track_id", "time_s"])
    back = read_tracks(out / "vehicle_tracks_000.csv")
    np.testing.assert_allclose(back[["x", "y"]].to_numpy(), tracks[["x", "y"]].to_numpy(), atol=1e-6)
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm")
    assert scene.n_tracks == 160 and len(scene.trajectories) == 160 and not scene.skipped
    # positions rebuilt from the estimated states on the matched path follow the recording; the state
    # estimate smooths the Boltzmann-noisy jerks (least squares with a jerk penalty), hence decimetres
    for t in scene.trajectories[:20]:
        xy = scene.model.positions(t.states, t.metadata["d"])
        assert np.abs(xy - t.metadata["xy"]).max() < 0.3
    assert "theta" in t.metadata and "style" in t.metadata  # from the ground-truth sidecar


@needs_sample
def test_shared_interaction_sample_loads_end_to_end():
    scene = load_replay(
        [SHARED / "recorded_trackfiles" / "TestScenarioForScripts" / "vehicle_tracks_000.csv"],
        SHARED / "maps" / "TestScenarioForScripts.osm",
    )
    assert len(scene.trajectories) == 2 and not scene.skipped
    for t in scene.trajectories:
        assert t.dt == 0.2 and t.n_steps >= 30
        np.testing.assert_allclose(t.states[:, 1], 10.0, atol=1e-6)  # the sample drives at 10 m/s


def test_bad_files_are_counted_not_fatal(passage_scene, tmp_path):
    out, _ = passage_scene
    good = out / "vehicle_tracks_000.csv"
    truncated = tmp_path / "vehicle_tracks_001.csv"
    text = good.read_text().splitlines()
    truncated.write_text("\n".join(text[:50]) + "\n" + text[50][:12] + "\n")
    nan_file = tmp_path / "vehicle_tracks_002.csv"
    nan_file.write_text(text[0] + "\n" + text[1].replace(text[1].split(",")[4], "nan", 1) + "\n")
    far = read_tracks(good).query("track_id == 1").copy()
    far["x"] += 5000.0
    far_file = tmp_path / "vehicle_tracks_003.csv"
    from pirl_sim.io.interaction import write_tracks

    write_tracks(far, far_file)
    dup_file = tmp_path / "vehicle_tracks_004.csv"
    dup_file.write_text("\n".join(text[:200] + [text[5]]) + "\n")  # a repeated frame of track 1
    scene = load_replay([good, truncated, nan_file, far_file, dup_file], out / "map.osm")
    # a cut-off row, a NaN and a repeated frame each drop their own track only; the good file is untouched
    assert scene.skipped["invalid rows (track dropped)"] == 3
    assert "unreadable file" not in scene.skipped
    assert scene.skipped["no route on the map"] == 1
    files = [t.metadata["file"] for t in scene.trajectories]
    assert files.count(str(good)) == 160  # the good file's tracks are all still there
    assert files.count(str(dup_file)) >= 1
    broken_map = tmp_path / "broken.osm"
    broken_map.write_text((out / "map.osm").read_text()[:200])
    with pytest.raises(ValueError):
        load_replay([good], broken_map)


def test_interaction_rule_flags_a_close_follower():
    rows = []
    for frame in range(1, 30):
        for tid, x0 in ((1, 0.0), (2, 8.0), (3, 200.0)):
            rows.append({"track_id": tid, "frame_id": frame, "x": x0 + frame, "y": 0.0, "vx": 10.0, "vy": 0.0,
                         "psi_rad": 0.0})
    flags = interaction_flags(pd.DataFrame(rows), SelectionRule(time_gap=2.0, standstill=5.0, gap="centre"))
    assert flags == {1: True, 2: False, 3: False}  # 1 follows 2 at 8 m < 5 m + 2 s * 10 m/s


def test_track_starting_before_its_route_stays_on_its_route(tmp_path):
    """Track 2 starts 20 m before lane B (its first 2 s off-map, at negative arc lengths of its route, the
    second path of the composite). Those steps were placed on lane A's extension, 300-400 m away."""
    tracks, osm = straight_scene(tmp_path, [("A", 5.0, 150, None), ("B", -20.0, 150, None)])
    scene = load_replay([tracks], osm, max_steps=None)
    t = {tr.metadata["track_id"]: tr for tr in scene.trajectories}[2]
    assert t.metadata["segment"] == 1 and t.states[0, 0] < scene.model.path.offsets[1]
    xy = scene.model.positions(t.states, t.metadata["d"])
    assert np.abs(xy - t.metadata["xy"]).max() < 0.1
    # the replay scores on the same axis: CV along the path from the first window is exact on this track
    from pirl_sim.experiments.recorded import _errors

    proto = ReplayProtocol(history=2, horizon=10, fde_steps=(10,))
    x0 = t.states[2]
    s_pred = x0[0] + x0[1] * 0.2 * np.arange(1, 11)
    assert _errors(scene.model, [t], [(0, 2)], s_pred[None], proto).max() < 0.1


def test_unconnected_positions_are_bridged_or_cut_not_fatal(tmp_path):
    """Lanes A and B have no routing-graph link. Track 1 drives A with one frame recorded on B (a stray
    position); track 2 drives A for 8 s, then B for 3 s (a break). Each was dropped as 'no route on the map'."""
    stray = np.zeros(150)
    stray[70] = LANE_Y["B"]
    jump = np.where(np.arange(110) < 80, LANE_Y["A"], LANE_Y["B"])
    tracks, osm = straight_scene(tmp_path, [("A", 5.0, 150, stray), ("A", 5.0, 110, jump), ("B", 5.0, 100, None)])
    scene = load_replay([tracks], osm, max_steps=None)
    assert not scene.skipped
    by_id = {t.metadata["track_id"]: t for t in scene.trajectories}
    assert set(by_id) == {1, 2, 3}
    assert scene.repairs == {"unconnected positions bridged": 1, "unconnected positions cut off": 30,
                             "tracks cut at a break in the route": 1}
    t1, t2 = by_id[1], by_id[2]
    assert t1.n_steps == 74 and t2.n_steps == 39  # 150 frames -> 75 samples; the 80 frames on A -> 40
    np.testing.assert_allclose(t1.states[:, 1], 10.0, atol=0.05)  # the bridged frame does not disturb the speed
    assert np.all(t2.metadata["xy"][:, 1] == LANE_Y["A"])


def test_history_start_states_see_no_step_after_the_window(passage_scene):
    """A prediction at step k starts from states estimated from the history's observations alone: changing
    the recording after k leaves them as they were, while the whole-track estimate (a smoother) moves."""
    out, _ = passage_scene
    scene = load_replay([out / "vehicle_tracks_000.csv"], out / "map.osm")
    t = max(scene.trajectories, key=lambda tr: tr.n_steps)
    start, stop = 5, 15
    hist = scene.history_window(t, start, stop)
    assert hist.states.shape == (stop - start + 1, 3) and hist.metadata["window_start"] == start
    np.testing.assert_allclose(hist.states[:, 0], t.states[start : stop + 1, 0], atol=0.2)  # same motion
    bent = dict(t.metadata, s_obs=t.metadata["s_obs"].copy(), v_obs=t.metadata["v_obs"].copy())
    bent["s_obs"][stop + 1 :] += np.linspace(0.0, 20.0, t.n_steps - stop)  # the car sped off after step `stop`
    np.testing.assert_array_equal(scene.history_window(t.with_metadata(**bent), start, stop).states, hist.states)
    own = _estimate(t.metadata["s_obs"][start : stop + 1], {"v": None}, None, 0.2, "positions", None, 1e-2)
    np.testing.assert_allclose(hist.states, own[0], atol=1e-9)  # the window's own estimate ...
    assert not np.allclose(hist.states, t.states[start : stop + 1], atol=1e-3)  # ... not the smoother's
    refit = _estimate(bent["s_obs"], {"v": bent["v_obs"]}, None, 0.2, "positions", None, 1e-2)[0]
    assert abs(refit[stop, 2] - t.states[stop, 2]) > 0.05  # the smoother's acceleration at `stop` moved


def test_a_track_that_leaves_its_route_for_a_far_part_of_it_is_cut_at_the_jump():
    """A U-shaped route: out along y = 0, a turn, back along y = 15 m. A vehicle drives out to x = 60 m, then cuts
    across to the return leg (not on its route, as a car on a bypass lane its matched route does not take) and
    drives back on it. Its arc length along the route jumps by the skipped turn; the track is cut there and the
    longer part kept."""
    from pirl_sim.paths import TRACK_STEP, ReferencePath
    from pirl_sim.scenarios.replay import _project_track, _without_jumps

    th = np.linspace(-np.pi / 2, np.pi / 2, 40)
    out = np.column_stack([np.linspace(0.0, 100.0, 50), np.zeros(50)])
    turn = np.column_stack([100.0 + 7.5 * np.cos(th[1:-1]), 7.5 + 7.5 * np.sin(th[1:-1])])
    back = np.column_stack([np.linspace(100.0, 0.0, 50), np.full(50, 15.0)])
    route = ReferencePath.from_polyline(np.vstack([out, turn, back]))
    x_out = np.arange(0.0, 60.0, 0.8)  # 75 frames out, then 10 frames across, then 40 back
    across = np.column_stack([np.full(10, 60.0), np.linspace(1.5, 13.5, 10)])
    xy = np.vstack([np.column_stack([x_out, np.zeros_like(x_out)]), across,
                    np.column_stack([np.arange(59.2, 27.0, -0.8), np.full(41, 15.0)])])
    s, d = _project_track(route, xy, np.zeros(len(xy), dtype=bool))
    assert np.abs(np.diff(s)).max() > TRACK_STEP  # the jump onto the return leg
    part = _without_jumps(s)
    assert part.start == 0 and 75 <= part.stop < 85  # out and part of the way across
    np.testing.assert_allclose(s[:75], x_out, atol=1e-6)
    assert np.all(np.abs(np.diff(s[part])) <= TRACK_STEP)


def test_recording_settings_and_masks_match_the_recorded_demonstrations(sumo_recording):
    from pirl_sim.scenarios.replay import recording_settings
    from pirl_sim.scenarios.sumo import load_sumo_run

    scene, rec = load_sumo_scene(sumo_recording)
    assert rec == recording_settings(sumo_recording / "vehicle_tracks_000.csv")
    assert rec.horizon == 30 and rec.dt == pytest.approx(0.1)
    run = load_sumo_run(sumo_recording)
    demos = {d.metadata["track_id"]: d for d in run.demonstrations(selection="steps", min_steps=10)}
    n_background = int((~run.recording.ground_truth["is_pirl"]).sum())
    assert scene.skipped["no driver steps (not a PIRL driver)"] == n_background
    assert {t.metadata["track_id"] for t in scene.selected} == set(demos)
    assert any(t.metadata["interacted"] for t in scene.selected)  # interacting tracks kept, masked
    for t in scene.selected:
        d = demos[t.metadata["track_id"]]
        np.testing.assert_array_equal(t.metadata["step_mask"], d.metadata["step_mask"])
        assert t.n_steps == d.n_steps and "theta" in t.metadata
        np.testing.assert_allclose(t.metadata["theta"], d.metadata["theta"], rtol=1e-12)
        # same speeds: both estimate from the recorded speeds with the same noise model
        assert np.abs(t.states[:, 1] - d.states[:, 1]).max() < 1e-3
    assert scene.steps["steps kept (driver's own)"] == sum(int(d.metadata["step_mask"].sum()) for d in demos.values())


def test_load_replay_rejects_bad_options(real_like):
    from pirl_sim.experiments.replay_report import ReplayProtocol
    from pirl_sim.scenarios.replay import EstimateNoise, load_replay

    files, osm = [real_like / "vehicle_tracks_000.csv"], real_like / "map.osm"
    check_bad_read_options(partial(load_replay, files, osm), "driver_steps.csv")
    with pytest.raises(ValueError, match="sigma_v must be a finite number > 0"):
        EstimateNoise(0.1, 0.0, 1.0)
    with pytest.raises(ValueError, match="rollout='closed' needs mpc_horizon"):
        ReplayProtocol(rollout="closed")
    with pytest.raises(ValueError, match="mpc_horizon must be a positive number of steps"):
        ReplayProtocol(mpc_horizon=0)
    scene = load_replay(files, osm, estimate="speeds", dt=0.1)  # measured-noise defaults on a clean track
    for t in scene.trajectories:
        np.testing.assert_allclose(t.states[:, 1], 10.0, atol=1e-3)


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


@pytest.mark.parametrize("content", [b"", b"\x00\xff\xfe\x81binary\x00", b"id,style\n1,0\n", b"track_id,style\n1,0\n1,1\n",
                                     b"track_id,style\n1.5,0\n", b"track_id,theta_acc_sq\n1,heavy\n"])
def test_an_unusable_ground_truth_sidecar_is_an_error_naming_it(tmp_path, content):
    tracks, osm = two_lane_scene_dir(tmp_path)
    (tmp_path / "ground_truth.csv").write_bytes(content)
    with pytest.raises(ValueError, match="ground_truth.csv"):
        load_replay([tracks], osm)


def test_each_directory_gets_its_own_ground_truth(tmp_path):
    """Files from two directories: the second never takes the first one's truth."""
    t1, osm = two_lane_scene_dir(tmp_path / "a", n_tracks=4)
    t2, _ = two_lane_scene_dir(tmp_path / "b", n_tracks=4)
    write_ground_truth(tmp_path / "a", [1, 2, 3, 4], [0, 0, 0, 0])
    # no sidecar in b: its tracks have no truth
    scene = load_replay([t1, t2], osm)
    by_dir = {d: [t for t in scene.trajectories if f"/{d}/" in t.metadata["file"]] for d in "ab"}
    assert by_dir["a"] and all(t.metadata["style"] == 0 and "theta" in t.metadata for t in by_dir["a"])
    assert by_dir["b"] and all("style" not in t.metadata and "theta" not in t.metadata for t in by_dir["b"])
    # an unusable sidecar in b is an error, not a's truth
    (tmp_path / "b" / "ground_truth.csv").write_text("")
    with pytest.raises(ValueError, match=r"b/ground_truth.csv"):
        load_replay([t1, t2], osm)
    # b's own truth (another style) goes to b's tracks
    write_ground_truth(tmp_path / "b", [1, 2, 3, 4], [2, 2, 2, 2])
    scene = load_replay([t1, t2], osm)
    styles = {(t.metadata["file"].split("/")[-2], t.metadata["style"]) for t in scene.trajectories}
    assert styles == {("a", 0), ("b", 2)}


def test_replay_drops_a_fractional_track_id_and_backwards_timestamps(tmp_path):
    tracks, osm = two_lane_scene_dir(tmp_path, n_tracks=6)
    df = pd.read_csv(tracks, dtype=str)
    t6 = df["track_id"] == "6"
    df.loc[df.index[t6][-1], "track_id"] = "6.5"  # the last row of track 6: a track id of 6.5
    t5 = df.index[df["track_id"] == "5"]
    df.loc[t5, "timestamp_ms"] = df.loc[t5, "timestamp_ms"].astype(int).to_numpy()[::-1].astype(str)  # backwards
    df.to_csv(tracks, index=False)
    scene = load_replay([tracks], osm)
    # one row that belongs to no track (6.5) and one track (5) whose timestamps run backwards
    assert scene.skipped["invalid rows (track dropped)"] == 2
    ids = {t.metadata["track_id"] for t in scene.trajectories}
    assert ids == {1, 2, 3, 4, 6}
    # track 6 keeps its own rows only: 6.5 was not read as 6
    last_x6 = max(t.metadata["xy"][-1, 0] for t in scene.trajectories if t.metadata["track_id"] == 6)
    assert last_x6 < 5.0 + 10.0 * 0.1 * 148 + 1e-6


def test_replay_with_following_features_sees_the_recorded_vehicle_ahead(tmp_path):
    from pirl_sim.io.interaction import write_tracks
    from pirl_sim.io.lanelet2_map import write_map
    from pirl_sim.scenarios.replay import NO_LEADER_GAP

    x = np.linspace(0.0, 500.0, 41)
    write_map({"A": np.column_stack([x, np.full_like(x, LANE_Y["A"])])}, {}, tmp_path / "map.osm")
    lead = track_rows(1, 1, 30.0, 150, 0.0, speed=8.0)
    follow = track_rows(2, 1, 15.0, 150, 0.0, speed=8.0)  # 15 m behind, centre to centre: 10.5 m bumper gap
    alone = track_rows(3, 400, 0.0, 150, 0.0, speed=8.0)
    write_tracks(pd.concat([lead, follow, alone], ignore_index=True), tmp_path / "vehicle_tracks_000.csv")
    scene = load_replay([tmp_path / "vehicle_tracks_000.csv"], tmp_path / "map.osm", features="following",
                        selection="all")
    assert scene.model.dynamics.n_x == 5 and scene.model.features.names[-1] == "headway"
    by_id = {t.metadata["track_id"]: t for t in scene.selected}
    assert set(by_id) == {1, 2, 3}  # the follower is kept: selection 'all'
    np.testing.assert_allclose(by_id[2].states[:, 3], 10.5, atol=1e-6)
    np.testing.assert_allclose(by_id[2].states[:, 4], 8.0)
    np.testing.assert_allclose(by_id[3].states[:, 3], NO_LEADER_GAP)
    np.testing.assert_allclose(by_id[3].states[:, 4], 8.0)  # alone: the car's own speed (the gap stays put)
    assert not any(t.metadata["yielding"].any() for t in scene.selected)  # one lane: nobody crosses
    assert scene.steps["steps behind a vehicle ahead"] == by_id[2].n_steps
    inter = load_replay([tmp_path / "vehicle_tracks_000.csv"], tmp_path / "map.osm", features="interacting",
                        selection="all")
    assert inter.model.dynamics.n_x == 7 and inter.model.features.names[-2:] == ("headway", "yielding")
    got = {t.metadata["track_id"]: t for t in inter.selected}
    np.testing.assert_allclose(got[2].states[:, :5], by_id[2].states, atol=1e-9)  # the vehicle ahead as before
    np.testing.assert_allclose(got[2].states[:, 5], NO_LEADER_GAP)  # nobody to yield to on one lane
    np.testing.assert_allclose(got[2].states[:, 6], 8.0)


def test_pieces_keep_the_recorded_heading_beside_positions_and_speeds(following_scene):
    """psi_obs: the track file's psi_rad at the same steps as xy and v_obs (whole pieces and free-flow runs)."""
    tracks, osm = following_scene
    df = pd.read_csv(tracks)
    df["psi_rad"] = 0.01 * df["frame_id"]  # a heading the positions do not show
    df.to_csv(tracks, index=False)
    for selection in ("tracks", "free"):
        scene = load_replay([tracks], osm, selection=selection, max_steps=None)
        for t in scene.trajectories:
            meta = t.metadata
            assert len(meta["psi_obs"]) == len(meta["xy"]) == len(meta["v_obs"])
            rows = df[df["track_id"] == meta["track_id"]].set_index("x")
            np.testing.assert_allclose(meta["psi_obs"], rows.loc[meta["xy"][:, 0], "psi_rad"].to_numpy())
