"""Lateral offsets of path predictions (pirl_sim.lateral), the replay's decomposition of the error into along
the path and across it, and the speed-level features (issue 12)."""

import numpy as np
import pandas as pd
import pytest

from pirl_sim.driving import PathDriverModel, SpeedProfile, roundabout_features
from pirl_sim.dynamics import longitudinal
from pirl_sim.experiments.replay_report import ReplayProtocol, run_replay
from pirl_sim.lateral import MeanOffsetProfile, NeighbourOffsets, predict_offsets
from pirl_sim.paths import ReferencePath
from pirl_sim.scenarios.replay import load_replay


def _profile():
    s = np.concatenate([np.linspace(0, 100, 1001)] * 4)
    seg = np.repeat([0, 0, 1, 1], 1001)
    d = np.where(seg == 0, 0.5 * np.sin(s / 10.0), 1.0)
    return MeanOffsetProfile().fit(seg, s, d)


def test_mean_offset_profile_follows_each_routes_median_path():
    prof = _profile()
    s = np.array([5.0, 30.0, 77.0])
    np.testing.assert_allclose(prof(0, s), 0.5 * np.sin(s / 10.0), atol=0.03)  # 1 m bins, 5 averaged
    np.testing.assert_allclose(prof(1, s), 1.0)
    assert np.isnan(prof(0, np.array([500.0]))).all() and np.isnan(prof(7, s)).all()  # no data there


def test_predict_offsets_keeps_the_cars_own_deviation_and_holds_without_data():
    prof = _profile()
    s_pred = np.linspace(21.0, 40.0, 15)
    d = predict_offsets("mean-path", 0.2, 0, 20.0, s_pred, prof)
    np.testing.assert_allclose(d, prof(0, s_pred) + 0.2 - prof(0, np.array([20.0]))[0])
    np.testing.assert_array_equal(predict_offsets("hold", 0.2, 0, 20.0, s_pred), 0.2)
    np.testing.assert_array_equal(predict_offsets("mean-path", 0.2, 0, 20.0, s_pred + 500.0, prof), 0.2)


@pytest.mark.parametrize("call, match", [
    (lambda: MeanOffsetProfile(bin_width=0.0), "bin_width"),
    (lambda: MeanOffsetProfile(min_count=0), "min_count"),
    (lambda: MeanOffsetProfile(smooth=-1), "smooth"),
    (lambda: MeanOffsetProfile()(0, np.zeros(2)), "not fitted"),
    (lambda: MeanOffsetProfile().fit(np.zeros(3), np.zeros(3), np.zeros(2)), "one length"),
    (lambda: MeanOffsetProfile().fit(np.zeros(2), np.array([0.0, np.nan]), np.zeros(2)), "finite"),
    (lambda: predict_offsets("lane", 0.0, 0, 0.0, np.zeros(3)), "lateral model"),
    (lambda: predict_offsets("mean-path", 0.0, 0, 0.0, np.zeros(3)), "MeanOffsetProfile"),
    (lambda: ReplayProtocol(lateral="centre"), "lateral"),
])
def test_bad_lateral_inputs_name_the_value(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def _weaving_scene(tmp_path, n_tracks=12):
    """Straight lane; every car weaves across it the same way along x (a route-consistent driven path)."""
    from pirl_sim.io.interaction import write_tracks
    from pirl_sim.io.lanelet2_map import write_map

    x = np.linspace(0.0, 400.0, 41)
    write_map({"A": np.column_stack([x, np.zeros_like(x)])}, {}, tmp_path / "map.osm")
    rows, frame = [], 1
    for i in range(n_tracks):
        n = 200
        frames = np.arange(frame, frame + n)
        speed = 8.0 + 0.3 * i
        xx = 10.0 + 3.0 * i + speed * 0.1 * np.arange(n)
        y = 1.2 * np.sin(xx / 15.0) + 0.1 * (i % 3 - 1)
        psi = np.arctan(1.2 / 15.0 * np.cos(xx / 15.0))
        rows.append(pd.DataFrame({"track_id": i + 1, "frame_id": frames, "timestamp_ms": 100 * frames,
                                  "agent_type": "car", "x": xx, "y": y, "vx": speed, "vy": 0.0, "psi_rad": psi,
                                  "length": 4.5, "width": 1.8}))
        frame += n + 10
    write_tracks(pd.concat(rows, ignore_index=True), tmp_path / "vehicle_tracks_000.csv")
    return tmp_path / "vehicle_tracks_000.csv", tmp_path / "map.osm"


def test_mean_path_lateral_model_and_the_error_decomposition(tmp_path):
    tracks, osm = _weaving_scene(tmp_path)
    scene = load_replay([tracks], osm, smoothing=0.0)
    rows = {}
    for lateral in ("hold", "mean-path", "plane"):
        res = run_replay(scene, [], ReplayProtocol(seeds=(0, 1), test_fraction=0.34, lateral=lateral))
        rows[lateral] = res["rows"].set_index(["seed", "method"])
    hold, mean = rows["hold"], rows["mean-path"]
    for seed in (0, 1):  # one route: pooling in the plane finds the same weave
        assert rows["plane"].loc[(seed, "CA (path)"), "med"] < 0.5 * hold.loc[(seed, "CA (path)"), "med"]
    ca = "CA (path)"
    for seed in (0, 1):
        # the weave is the same for every car: following the training tracks' path beats holding the offset
        assert mean.loc[(seed, ca), "med"] < 0.5 * hold.loc[(seed, ca), "med"]
        # along the path (recorded offsets) nothing depends on the lateral model; the floor is below CA
        assert mean.loc[(seed, ca), "med_path"] == pytest.approx(hold.loc[(seed, ca), "med_path"])
        assert mean.loc[(seed, ca), "lateral_floor"] < hold.loc[(seed, ca), "lateral_floor"]
        assert hold.loc[(seed, ca), "lateral_floor"] <= hold.loc[(seed, ca), "med"] + 1e-9
        # constant speed: CA and CV along the path are almost exact
        assert hold.loc[(seed, ca), "med_path"] < 0.1


def test_speed_level_features_blend_the_desired_speed_with_the_drivers_level():
    path = ReferencePath.from_polyline(np.column_stack([np.linspace(0, 400, 81), np.zeros(81)]))
    feats = roundabout_features(SpeedProfile(path, 1.8, 10.0), "speed-level")
    assert feats.names == ("speed_dev", "acc_sq", "jerk_sq", "speed_sq", "speed_hi")
    model = PathDriverModel(longitudinal(0.2), feats, None, path=path)
    x0 = np.array([[0.0, 8.0, 0.0]])
    # preferred speed (w v_des + w_hi v_hi) / (w + w_0 + w_hi): 10 / 2 = 5 and (10 + 20) / 2 = 15 m/s
    for theta, v_pref in (([1.0, 0.1, 0.1, 1.0, 1e-9], 5.0), ([1.0, 0.1, 0.1, 1e-9, 1.0], 15.0)):
        states = model.predict_states(x0, np.array([theta]), 150)[0]
        assert abs(states[100, 1] - v_pref) < 0.1
    vals = feats.values(np.array([[[0, 8, 1.0], [1, 9, 2.0]]]), np.array([[[3.0]]]))
    np.testing.assert_allclose(vals[0, 3:], [81.0, 121.0])
    with pytest.raises(ValueError, match="feature set"):
        roundabout_features(SpeedProfile(path), "lateral")
    with pytest.raises(ValueError, match="features"):
        load_replay([], "nowhere.osm", features="all")


def test_following_dynamics_close_the_gap_by_what_the_car_drives():
    from pirl_sim.dynamics import following

    dyn = following(0.2)
    x0 = np.array([3.0, 5.0, 1.0, 20.0, 4.0])
    xs = dyn.rollout(x0, np.array([[2.0], [-1.0], [0.5]]))
    lon = xs[:, :3]
    np.testing.assert_allclose(xs[:, 3], 20.0 + 4.0 * 0.2 * np.arange(4) - (lon[:, 0] - 3.0))
    np.testing.assert_allclose(xs[:, 4], 4.0)


def test_headway_feature_derivatives_and_a_car_stopping_behind_a_standing_obstacle():
    from pirl_sim.driving import HeadwayResidual
    from pirl_sim.dynamics import following

    res = HeadwayResidual()
    x = np.array([[[0.0, 6.0, 0.5, 4.0, 2.0], [1.0, 7.0, 0.0, 80.0, 7.0]]])
    out = res(x, np.zeros((1, 2, 1)))
    eps = 1e-6
    for i in (1, 3):
        dx = np.zeros(5)
        dx[i] = eps
        fd = (res(x + dx, np.zeros((1, 2, 1))).r - res(x - dx, np.zeros((1, 2, 1))).r)[..., 0] / (2 * eps)
        np.testing.assert_allclose(out.jac_x[..., 0, i], fd, rtol=1e-6, atol=1e-9)
        fd2 = (res(x + dx, np.zeros((1, 2, 1))).jac_x - res(x - dx, np.zeros((1, 2, 1))).jac_x)[..., 0, :] / (2 * eps)
        np.testing.assert_allclose(out.hess_x[..., 0, i, :], fd2, rtol=1e-5, atol=1e-8)
    assert out.r[0, 0, 0] > 3.9 and out.r[0, 1, 0] < 1e-20  # 2 + 6 - 4 below the safe gap; far ahead: none
    path = ReferencePath.from_polyline(np.column_stack([np.linspace(0, 400, 81), np.zeros(81)]))
    model = PathDriverModel(following(0.2), roundabout_features(SpeedProfile(path, 1.8, 10.0), "following"),
                            None, path=path)
    x0 = np.array([[0.0, 8.0, 0.0, 40.0, 0.0]])  # a standing obstacle 40 m ahead
    free, blocked = (model.predict_states(x0, np.array([[1.0, 1.0, 1.0, 1e-3, 1e-3, w]]), 60)[0]
                     for w in (1e-6, 100.0))
    assert free[-1, 0] > 100.0  # no care for the gap: drives through it
    assert blocked[-1, 0] < 40.0 and blocked[-1, 1] < 1.0  # stops short of it
    with pytest.raises(ValueError, match="following"):
        res(np.zeros((1, 2, 3)), np.zeros((1, 2, 1)))
    with pytest.raises(ValueError, match="softness"):
        HeadwayResidual(softness=0.0)


def test_replay_with_following_features_sees_the_recorded_vehicle_ahead(tmp_path):
    from test_replay import LANE_Y, _track_rows

    from pirl_sim.io.interaction import write_tracks
    from pirl_sim.io.lanelet2_map import write_map
    from pirl_sim.scenarios.replay import NO_LEADER_GAP

    x = np.linspace(0.0, 500.0, 41)
    write_map({"A": np.column_stack([x, np.full_like(x, LANE_Y["A"])])}, {}, tmp_path / "map.osm")
    lead = _track_rows(1, 1, 30.0, 150, 0.0, speed=8.0)
    follow = _track_rows(2, 1, 15.0, 150, 0.0, speed=8.0)  # 15 m behind, centre to centre: 10.5 m bumper gap
    alone = _track_rows(3, 400, 0.0, 150, 0.0, speed=8.0)
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


def test_a_learner_on_the_following_features_round_trips_through_the_model_file(tmp_path):
    from pirl_sim.dynamics import following
    from pirl_sim.learners import TIRL
    from pirl_sim.learners.model_io import load_learner
    from pirl_sim.trajectory import Trajectory

    path = ReferencePath.from_polyline(np.column_stack([np.linspace(0, 400, 81), np.zeros(81)]))
    model = PathDriverModel(following(0.2), roundabout_features(SpeedProfile(path, 1.8, 10.0), "following"),
                            None, path=path)
    rng = np.random.default_rng(0)
    x0 = np.column_stack([np.zeros(6), rng.uniform(4, 9, 6), np.zeros(6), rng.uniform(5, 40, 6), rng.uniform(0, 8, 6)])
    theta = np.array([1.0, 1.0, 1.0, 0.05, 0.05, 3.0])
    states = model.predict_states(x0, np.tile(theta, (6, 1)), 20)
    demos = [Trajectory(s, model.dynamics.controls_from_states(s), 0.2) for s in states]
    learner = TIRL(model=model, window=10).fit(demos)
    back = load_learner(learner.save(tmp_path / "tirl.npz"))
    np.testing.assert_array_equal(back.infer_weights(demos), learner.infer_weights(demos))


def test_horizon_scan_fits_the_desired_speed_per_split(tmp_path):
    from pirl_sim.experiments.horizon_scan import scan_horizons

    tracks, osm = _weaving_scene(tmp_path)
    scene = load_replay([tracks], osm, smoothing=0.0, features="speed-level")
    rows = scan_horizons(scene, [5], ReplayProtocol(seeds=(0,), test_fraction=0.34), step_stride=4,
                         desired_speed="fit")
    # cars at 8-11.3 m/s on a nearly straight lane: the fitted cap sits among their speeds, not at 13.9 m/s
    assert 7.5 < rows["v_max"].iloc[0] < 12.0
    assert rows["med"].iloc[0] < 1.0


def test_replay_cli_applies_the_lateral_model_to_a_single_recording(tmp_path):
    from pirl_sim.cli import main

    tracks, osm = _weaving_scene(tmp_path)
    floors = {}
    for lateral in ("hold", "mean-path", "neighbours"):
        out = tmp_path / lateral
        assert main(["replay", "--tracks", str(tracks), "--map", str(osm), "--out", str(out), "--seeds", "1",
                     "--learners", "tirl", "--lateral", lateral, "--quiet"]) == 0
        floors[lateral] = pd.read_csv(out / "rows.csv")["lateral_floor"].iloc[0]
    assert floors["mean-path"] < 0.5 * floors["hold"]
    assert floors["neighbours"] < 0.5 * floors["hold"]


def test_plane_profile_pools_offsets_over_routes_that_share_a_lane():
    """Two routes along one straight lane, each driven by one track that keeps 0.6 m left of the centreline:
    per route no bin has the 3 samples it needs from other tracks; in the plane the other route's track counts."""
    from pirl_sim.driving import CompositePath

    x = np.linspace(0.0, 100.0, 201)
    a = ReferencePath.from_polyline(np.column_stack([x, np.zeros_like(x)]), smoothing=0.0)
    b = ReferencePath.from_polyline(np.column_stack([x[:101], np.zeros(101)]), smoothing=0.0)
    path = CompositePath((a, b))
    xx = np.arange(0.0, 100.0, 0.8)
    tracks = [np.column_stack([xx, np.full_like(xx, 0.6)]), np.column_stack([xx[:60], np.full(60, 0.6)])]
    prof = MeanOffsetProfile().fit_plane(path, tracks)
    s_b = path.offsets[1] + np.array([5.0, 20.0, 40.0])
    np.testing.assert_allclose(prof(1, s_b), 0.6, atol=1e-9)  # route b's bins use route a's track too
    np.testing.assert_allclose(prof(0, np.array([70.0])), 0.6, atol=1e-9)
    # driven the other way, or standing, or far off the lane: not counted
    back = [np.column_stack([xx[::-1], np.full_like(xx, 0.6)]), np.column_stack([np.full(50, 30.0), np.zeros(50)]),
            np.column_stack([xx, np.full_like(xx, 9.0)])]
    assert np.isnan(MeanOffsetProfile().fit_plane(path, back)(0, np.array([10.0, 30.0, 60.0]))).all()
    d = predict_offsets("plane", 0.1, 1, s_b[0], s_b[1:], prof)
    np.testing.assert_allclose(d, 0.1)  # the car's own deviation from the pooled path is kept
    with pytest.raises(ValueError, match="window"):
        MeanOffsetProfile().fit_plane(path, tracks, window=0.0)
    with pytest.raises(ValueError, match=r"xy\[0\]"):
        MeanOffsetProfile().fit_plane(path, [np.zeros((4, 3))])
    with pytest.raises(ValueError, match="moving"):
        MeanOffsetProfile().fit_plane(path, [np.zeros((4, 2))])


def test_backed_by_keeps_the_routes_own_bins_and_fills_the_rest():
    own = MeanOffsetProfile(smooth=0).fit(np.zeros(6, int), np.array([0.1, 0.2, 0.3, 5.1, 5.2, 5.3]),
                                          np.full(6, 1.0))
    pooled = MeanOffsetProfile(smooth=0).fit(np.array([0, 0, 0, 0, 0, 0, 1, 1, 1]),
                                             np.array([0.1, 0.2, 0.3, 9.1, 9.2, 9.3, 0.1, 0.2, 0.3]),
                                             np.array([2.0, 2.0, 2.0, 3.0, 3.0, 3.0, 4.0, 4.0, 4.0]))
    both = own.backed_by(pooled)
    np.testing.assert_allclose(both(0, np.array([0.5, 5.5, 9.5])), [1.0, 1.0, 3.0])
    np.testing.assert_allclose(both(1, np.array([0.5])), [4.0])
    with pytest.raises(ValueError, match="bin_width"):
        own.backed_by(MeanOffsetProfile(bin_width=2.0).fit(np.zeros(3, int), np.zeros(3), np.zeros(3)))


def _lane_change_tracks(n_each: int = 6, dt: float = 0.1):
    """Straight road along x; half the cars keep 1.5 m left of the centreline, half come from 1.5 m right and
    cross to the left between x = 30 and 42 m at 1 m/s (a lane change that the median path cannot show)."""
    from pirl_sim.trajectory import Trajectory

    x = np.arange(0.0, 80.0, 1.0)  # 10 m/s, 0.1 s steps
    tracks = []
    for k in range(2 * n_each):
        shift = 0.13 * k  # start positions differ a little
        xs = x + shift
        if k % 2:
            d = np.clip(-1.5 + (xs - 30.0) / 4.0, -1.5, 1.5)
        else:
            d = np.full_like(xs, 1.5)
        states = np.column_stack([xs, np.full_like(xs, 10.0), np.zeros_like(xs)])
        tracks.append(Trajectory(states, np.zeros((len(xs) - 1, 1)), dt,
                                 {"xy": np.column_stack([xs, d]), "d": d, "segment": 0, "track_id": k}))
    return tracks


def test_neighbour_offsets_carry_a_lane_change_that_the_mean_path_misses():
    tracks = _lane_change_tracks()
    train, test = tracks[:-2], tracks[-2:]  # one of each kind tested
    segment = np.concatenate([np.zeros(t.n_steps + 1, int) for t in train])
    prof = MeanOffsetProfile().fit(segment, np.concatenate([t.states[:, 0] for t in train]),
                                   np.concatenate([t.metadata["d"] for t in train]))
    model = NeighbourOffsets(n_neighbors=3).fit(prof, train, horizon=15)
    # the changing car 2 m into its change (x ~ 32 m), and a car keeping left at the same place
    windows = [(i, int(np.searchsorted(test[i].states[:, 0], 32.0))) for i in (1, 0)]
    s_pred = np.stack([test[i].states[step + 1 : step + 16, 0] for i, step in windows])
    truth = np.stack([test[i].metadata["d"][step + 1 : step + 16] for i, step in windows])
    got = model.predict(test, windows, s_pred)
    plane = np.stack([predict_offsets("mean-path", test[i].metadata["d"][step], 0, test[i].states[step, 0],
                                      s_pred[w], prof) for w, (i, step) in enumerate(windows)])
    assert np.abs(got - truth).max() < 0.1  # both cars' futures
    assert np.abs(plane[0] - truth[0]).max() > 1.0  # the median path does not change lanes with the car
    # no mean path there: held, like the other models
    far = model.predict(test, windows[:1], s_pred[:1] + 500.0)
    np.testing.assert_array_equal(far, test[1].metadata["d"][windows[0][1]])


@pytest.mark.parametrize("call, match", [
    (lambda: NeighbourOffsets(n_neighbors=0), "n_neighbors"),
    (lambda: NeighbourOffsets(position_scale=float("nan")), "position_scale"),
    (lambda: NeighbourOffsets(deviation_times=(0.5, -1.0)), "deviation_times"),
    (lambda: NeighbourOffsets().fit(_profile(), [], 15), "at least"),
    (lambda: NeighbourOffsets().fit(_profile(), [], 0), "horizon"),
    (lambda: NeighbourOffsets().fit(MeanOffsetProfile(), [], 5), "fitted"),
    (lambda: NeighbourOffsets().predict([], [], np.zeros((0, 3))), "not fitted"),
    (lambda: predict_offsets("neighbours", 0.0, 0, 0.0, np.zeros(3), _profile()), "NeighbourOffsets.predict"),
])
def test_bad_neighbour_offsets_inputs_name_the_value(call, match):
    with pytest.raises(ValueError, match=match):
        call()
    with pytest.raises(TypeError, match="deviation_times"):
        NeighbourOffsets(deviation_times=0.5)


def test_neighbour_offsets_read_a_recorded_track_at_its_observed_arc_lengths():
    """A recorded track's states come from a smoother that saw its future; its offsets belong to the observed arc
    lengths ``s_obs``. With ``s_obs`` in the metadata the prediction does not depend on the smoothed s, so
    changing the smoothed states (as a different future would) leaves it unchanged; a window cut from the
    track (whose s_obs is the whole track's) is refused."""
    from pirl_sim.lateral import observed_s
    from pirl_sim.trajectory import Trajectory

    tracks = _lane_change_tracks()
    train, test = tracks[:-2], tracks[-2:]
    segment = np.concatenate([np.zeros(t.n_steps + 1, int) for t in train])
    prof = MeanOffsetProfile().fit(segment, np.concatenate([t.states[:, 0] for t in train]),
                                   np.concatenate([t.metadata["d"] for t in train]))
    model = NeighbourOffsets(n_neighbors=3).fit(prof, train, horizon=15)
    observed = [Trajectory(t.states, t.controls, t.dt, {**t.metadata, "s_obs": t.states[:, 0].copy()}) for t in test]
    smoothed_apart = []
    for t in observed:
        states = t.states.copy()
        states[:, 0] += np.linspace(0.0, 6.0, len(states))  # a smoother pulled by another future
        smoothed_apart.append(Trajectory(states, t.controls, t.dt, t.metadata))
    windows = [(i, 32) for i in (1, 0)]
    s_pred = np.stack([test[i].states[step + 1 : step + 16, 0] for i, step in windows])
    np.testing.assert_array_equal(model.predict(smoothed_apart, windows, s_pred), model.predict(observed, windows, s_pred))
    without = [Trajectory(t.states, t.controls, t.dt, {k: v for k, v in t.metadata.items() if k != "s_obs"})
               for t in smoothed_apart]  # read at the smoothed s instead: another prediction
    assert np.abs(model.predict(without, windows, s_pred) - model.predict(observed, windows, s_pred)).max() > 0.1
    with pytest.raises(ValueError, match="not windows"):
        observed_s(observed[0].window(0, 10))
