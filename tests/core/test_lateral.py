"""Lateral offsets of path predictions (pirl_sim.lateral): mean-path and plane profiles, neighbour offsets, and
their bad inputs."""

import numpy as np
import pytest

from pirl_sim.experiments.replay_report import ReplayProtocol
from pirl_sim.lateral import MeanOffsetProfile, NeighbourOffsets, predict_offsets
from pirl_sim.paths import ReferencePath


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
