"""State estimation from positions and speeds, per-step driver flags in recordings, step-masked demonstrations."""

import dataclasses

import numpy as np
import pandas as pd
import pytest

from pirl_sim import Trajectory
from pirl_sim.driving import estimate_longitudinal_states, fit_longitudinal_states
from pirl_sim.dynamics import longitudinal
from pirl_sim.scenarios.demonstrations import EXACT_TOL, SETTLE_FRAMES, settled

DT = 0.1


def _synthetic(n=120, seed=0):
    """A track through the dynamics: smooth jerks, start (0 m, 10 m/s, 0.5 m/s^2)."""
    rng = np.random.default_rng(seed)
    dyn = longitudinal(DT)
    t = DT * np.arange(n - 1)
    U = (0.8 * np.sin(0.7 * t) + 0.3 * np.cos(1.9 * t + rng.uniform(0, 6)))[:, None]
    X = dyn.rollout(np.array([0.0, 10.0, 0.5]), U)
    return dyn, X, U, rng


# ----------------------------------------------------------------------------------------------
# the estimator
# ----------------------------------------------------------------------------------------------

def test_exact_positions_and_speeds_give_the_states_back():
    dyn, X, U, _ = _synthetic()
    Xe, Ue = estimate_longitudinal_states(X[:, 0], dyn, v_obs=X[:, 1], sigma_s=1e-3, sigma_v=1e-4, sigma_j=10.0)
    assert Xe.shape == X.shape and Ue.shape == U.shape
    np.testing.assert_allclose(Xe, X, atol=2e-3)
    assert np.sqrt(np.mean((Ue - U) ** 2)) < 0.02  # [m/s^3], true jerk RMS ~0.6


def test_noisy_speeds_beat_positions_only_within_stated_bounds():
    dyn, X, U, rng = _synthetic(n=200, seed=1)
    errs = {"positions": [], "speeds": []}
    for _ in range(10):
        s = X[:, 0] + 0.01 * rng.standard_normal(len(X))  # 1 cm
        v = X[:, 1] + 0.005 * rng.standard_normal(len(X))  # 5 mm/s
        _, Up = estimate_longitudinal_states(s, dyn, sigma_s=0.01, sigma_j=0.1)
        _, Uv = estimate_longitudinal_states(s, dyn, v_obs=v, sigma_s=0.01, sigma_v=0.005, sigma_j=0.1)
        errs["positions"].append(np.sqrt(np.mean((Up - U) ** 2)))
        errs["speeds"].append(np.sqrt(np.mean((Uv - U) ** 2)))
    assert np.mean(errs["speeds"]) < 0.6 * np.mean(errs["positions"])
    assert np.mean(errs["speeds"]) < 0.08  # [m/s^3] (measured 0.057; positions only 0.126)


def test_position_only_estimate_is_the_old_fit():
    dyn, X, _, rng = _synthetic()
    s = X[:, 0] + 0.05 * rng.standard_normal(len(X))
    Xa, Ua = fit_longitudinal_states(s, dyn, jerk_weight=0.04)
    Xb, Ub = estimate_longitudinal_states(s, dyn, sigma_s=1.0, sigma_j=5.0)
    np.testing.assert_allclose(Xa, Xb, atol=1e-8)
    np.testing.assert_allclose(Ua, Ub, atol=1e-8)


def test_step_mask_fits_each_run_on_its_own_and_anchors_restarts():
    dyn, X, U, _ = _synthetic(n=80)
    X2 = X.copy()  # the driver re-started at frame 40 from another acceleration: dynamics broken there
    U2 = U.copy()
    X2[40:] = dyn.rollout(np.array([X[40, 0], X[40, 1], X[40, 2] - 1.5]), U[40:])
    mask = np.ones(79, dtype=bool)
    mask[39] = False
    a_obs = np.full(80, np.nan)
    a_obs[40] = X2[40, 2]
    Xe, Ue = estimate_longitudinal_states(X2[:, 0], dyn, v_obs=X2[:, 1], sigma_s=1e-3, sigma_v=1e-4, sigma_j=10.0,
                                          step_mask=mask, a_obs=a_obs)
    ok = mask
    assert np.abs(Ue[ok] - U2[ok]).max() < 0.05
    np.testing.assert_allclose(Xe[:, 2], X2[:, 2], atol=5e-3)
    # fitted through the break, the jerks near it are far off
    _, Ubad = estimate_longitudinal_states(X2[:, 0], dyn, v_obs=X2[:, 1], sigma_s=1e-3, sigma_v=1e-4, sigma_j=10.0)
    assert np.abs(Ubad[ok] - U2[ok]).max() > 1.0


@pytest.mark.parametrize("kwargs, match", [
    ({"s_obs": np.array([0.0, np.nan, 2.0])}, r"s_obs contains non-finite values \(nan at index 1\)"),
    ({"s_obs": np.zeros((3, 2))}, r"s_obs must be a 1-D array"),
    ({"s_obs": np.array([1.0])}, r"s_obs must be a 1-D array of at least 2"),
    ({"v_obs": np.ones(4)}, r"v_obs must have one speed per position: got 4 speeds for 3 positions"),
    ({"v_obs": np.array([1.0, np.inf, 1.0])}, r"v_obs contains non-finite values"),
    ({"sigma_s": 0.0}, r"sigma_s must be a finite number > 0, got 0.0"),
    ({"sigma_v": -1.0}, r"sigma_v must be a finite number > 0"),
    ({"sigma_j": float("nan")}, r"sigma_j must be a finite number > 0"),
    ({"sigma_a": True}, r"sigma_a must be a finite number > 0"),
    ({"a_obs": np.array([np.inf, np.nan, np.nan])}, r"a_obs contains infinite values"),
    ({"a_obs": np.zeros(2)}, r"a_obs must have one value"),
    ({"step_mask": np.ones(3, dtype=bool)}, r"step_mask must be a boolean array of shape \(2,\)"),
    ({"step_mask": np.ones(2)}, r"step_mask must be a boolean array"),
])
def test_bad_input_raises(kwargs, match):
    args = {"s_obs": np.array([0.0, 1.0, 2.0]), **kwargs}
    s = args.pop("s_obs")
    with pytest.raises(ValueError, match=match):
        estimate_longitudinal_states(s, longitudinal(DT), **args)


# ----------------------------------------------------------------------------------------------
# Trajectory.window
# ----------------------------------------------------------------------------------------------

def test_window_slices_the_step_mask():
    mask = np.array([True, False, True, True, False])
    tr = Trajectory(np.zeros((6, 3)), np.zeros((5, 1)), DT, {"step_mask": mask, "track_id": 3})
    w = tr.window(1, 4)
    np.testing.assert_array_equal(w.metadata["step_mask"], mask[1:4])
    np.testing.assert_array_equal(w.window(-2).metadata["step_mask"], mask[2:4])
    assert w.metadata["track_id"] == 3 and tr.window(2).metadata["window_start"] == 2
    bad = Trajectory(np.zeros((6, 3)), np.zeros((5, 1)), DT, {"step_mask": mask[:3]})
    with pytest.raises(ValueError, match=r"step_mask has shape \(3,\), expected one flag per step \(5,\)"):
        bad.window(1)


# ----------------------------------------------------------------------------------------------
# the sidecar: write, read, validate
# ----------------------------------------------------------------------------------------------

lanelet2 = pytest.importorskip("lanelet2")

from pirl_sim.scenarios.recording import (  # noqa: E402
    DRIVER_STEP_COLUMNS,
    DRIVER_STEPS_FILE,
    INFO_FILE,
    ScenarioRecording,
    read_recording,
    write_recording,
)


def _with_steps(rec: ScenarioRecording, steps) -> ScenarioRecording:
    return ScenarioRecording(rec.tracks, rec.ground_truth, rec.lanes, rec.successors, rec.info, steps)


def _steps_for(rec: ScenarioRecording, seed=0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    t = rec.tracks[rec.tracks["track_id"].isin(rec.pirl_track_ids)]
    n = len(t)
    commanded = rng.random(n) < 0.9
    return pd.DataFrame({"track_id": t["track_id"].to_numpy(), "frame_id": np.round(t["time_s"] * 10).astype(np.int64),
                         "commanded": commanded, "overridden": commanded & (rng.random(n) < 0.2),
                         "collided": np.zeros(n, dtype=bool)}, columns=list(DRIVER_STEP_COLUMNS))


@pytest.fixture
def small_recording():
    from test_recording import _recording
    return _recording()


def test_sidecar_round_trip_and_determinism(small_recording, tmp_path):
    rec = _with_steps(small_recording, _steps_for(small_recording))
    files = write_recording(rec, tmp_path / "a")
    assert files.driver_steps == tmp_path / "a" / DRIVER_STEPS_FILE
    back = read_recording(tmp_path / "a")
    pd.testing.assert_frame_equal(back.driver_steps, rec.driver_steps)
    write_recording(_with_steps(small_recording, _steps_for(small_recording)), tmp_path / "b")
    for name in (DRIVER_STEPS_FILE, INFO_FILE):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    # a recording without steps written over it leaves no stale sidecar, and reads back with None
    write_recording(small_recording, tmp_path / "a")
    assert not (tmp_path / "a" / DRIVER_STEPS_FILE).exists()
    assert read_recording(tmp_path / "a").driver_steps is None


def test_sidecar_validation(small_recording):
    steps = _steps_for(small_recording)
    with pytest.raises(ValueError, match="one row per frame of every PIRL track and nothing else; 1 missing"):
        _with_steps(small_recording, steps.iloc[1:])
    bg = small_recording.tracks[small_recording.tracks["track_id"] == 3].iloc[:1]
    extra = pd.concat([steps, pd.DataFrame({"track_id": [3], "frame_id": np.round(bg["time_s"] * 10).astype(np.int64),
                                            "commanded": [True], "overridden": [False], "collided": [False]})])
    with pytest.raises(ValueError, match="1 not PIRL track frames"):
        _with_steps(small_recording, extra)
    bad = steps.assign(commanded=False, overridden=True)
    with pytest.raises(ValueError, match="overridden but not commanded"):
        _with_steps(small_recording, bad)
    with pytest.raises(ValueError, match="driver_steps must have the columns"):
        _with_steps(small_recording, steps[["track_id", "frame_id", "commanded", "overridden"]])
    with pytest.raises(ValueError, match="driver_steps.commanded must be booleans"):
        _with_steps(small_recording, steps.assign(commanded=steps["commanded"].astype(int)))


# ----------------------------------------------------------------------------------------------
# a real SUMO run: flags, masks, counts, RecordedRun
# ----------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def sumo_run(tmp_path_factory):
    pytest.importorskip("libsumo")
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION
    from pirl_sim.scenarios.sumo import SumoScenarioConfig, run_sumo_scenario

    out = tmp_path_factory.mktemp("steps") / "run"
    pop = dataclasses.replace(DEFAULT_POPULATION, n_vehicles=20, depart_interval=1.5)
    return run_sumo_scenario(SumoScenarioConfig(population=pop), seed=1, out_dir=out), out


@pytest.mark.slow
def test_sumo_steps_and_masks_follow_the_runner_flags(sumo_run):
    from pirl_sim.scenarios.sumo import load_sumo_run

    res, out = sumo_run
    run = load_sumo_run(out)
    steps = run.recording.driver_steps
    frame = res.sumo.frame[res.sumo.frame["pirl"]]
    gt = run.recording.ground_truth.set_index("track_id")
    assert len(steps) == len(frame)
    np.testing.assert_array_equal(np.sort(steps["commanded"].to_numpy()), np.sort(frame["commanded_speed"].notna()))
    assert run.horizon == res.config.drivers.horizon == 30 and run.dt == 0.1
    assert run.control_noise == res.config.population.control_noise
    demos = run.demonstrations(selection="steps", min_steps=1)
    unsettled = {d.metadata["track_id"]: d for d in run.demonstrations(selection="steps", min_steps=1,
                                                                        settle_frames=0)}
    loose = {d.metadata["track_id"]: d for d in run.demonstrations(selection="steps", min_steps=1,
                                                                    settle_frames=0, exact_tol=1.0)}
    assert {d.metadata["track_id"] for d in demos} == set(run.recording.pirl_track_ids)
    n_masked = 0
    for d in demos:
        agent = gt.loc[d.metadata["track_id"], "agent_id"]
        f = frame[frame["vehicle_id"] == agent]
        own = (f["commanded_speed"].notna() & ~f["overridden"].fillna(False).astype(bool)
               & ~f["collided"]).to_numpy()
        expect = own[:-1] & ~f["collided"].to_numpy()[1:]
        # carried out exactly: the speed one frame on is the command to EXACT_TOL
        exact = ~(np.abs(f["speed"].to_numpy()[1:] - f["commanded_speed"].to_numpy()[:-1]) > EXACT_TOL)
        np.testing.assert_array_equal(d.metadata["step_mask"], settled(expect & exact, SETTLE_FRAMES))
        np.testing.assert_array_equal(unsettled[d.metadata["track_id"]].metadata["step_mask"], expect & exact)
        assert loose[d.metadata["track_id"]].metadata["step_mask"].tolist() == expect.tolist()
        n_masked += int((~expect).sum())
        # usable steps: the recorded speed one step on is the command (SUMO carried it out) ...
        cmd = f["commanded_speed"].to_numpy()[:-1][expect]
        np.testing.assert_allclose(f["speed"].to_numpy()[1:][expect], cmd, atol=res.config.override_tol)
        # ... and the estimate's speeds follow the recorded ones there (isolated frames between unusable
        # steps come from the whole-track fit, which rings across the breaks)
        assert np.abs(d.states[:-1, 1] - f["speed"].to_numpy()[:-1])[expect].max(initial=0.0) < 0.01
        if not gt.loc[d.metadata["track_id"], "interacted"]:
            assert d.metadata["step_mask"].all()
    assert n_masked > 0  # the run has interaction
    table = run.step_selection_summary(min_steps=1)
    assert table.loc["all", "usable"] == sum(int(d.metadata["step_mask"].sum()) for d in demos)
    assert table.loc["all", "tracks"] == len(demos)
    assert table.loc["all", "tracks_interacted"] == int(gt["interacted"].fillna(False).astype(bool).sum())
    # the default selection is unchanged: whole non-interacting tracks
    default = run.demonstrations()
    assert all(not d.metadata["interacted"] and d.metadata["step_mask"].all() for d in default)
    coarse = run.demonstrations(selection="steps", dt=0.2, min_steps=1)
    for d2 in coarse:
        d1 = next(d for d in demos if d.metadata["track_id"] == d2.metadata["track_id"])
        m = d1.metadata["step_mask"][: 2 * d2.n_steps].reshape(-1, 2).all(axis=1)
        np.testing.assert_array_equal(d2.metadata["step_mask"], m)


def test_steps_selection_needs_driver_steps(small_recording):
    from pirl_sim.scenarios.demonstrations import recorded_demonstrations, step_selection_summary

    with pytest.raises(ValueError, match="selection='steps' needs the recording's driver_steps"):
        recorded_demonstrations(small_recording, None, selection="steps")
    with pytest.raises(ValueError, match="selection must be one of"):
        recorded_demonstrations(small_recording, None, selection="frames")
    with pytest.raises(ValueError, match="estimate must be one of"):
        recorded_demonstrations(small_recording, None, estimate="magic")
    with pytest.raises(ValueError, match="no driver_steps"):
        step_selection_summary(small_recording)
