"""Demonstrations from recordings (pirl_sim.scenarios.demonstrations): per-step driver flags and step masks, the
steps selection, and recordings without speeds."""

from functools import partial

import numpy as np
import pytest

from pirl_sim.scenarios.demonstrations import EXACT_TOL, SETTLE_FRAMES, settled

pytest.importorskip("lanelet2")

from replay_scenes import check_bad_read_options  # noqa: E402


@pytest.mark.slow
def test_sumo_steps_and_masks_follow_the_runner_flags(sumo_recording_result):
    from pirl_sim.scenarios.sumo import load_sumo_run

    res, out = sumo_recording_result
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

    check_bad_read_options(partial(recorded_demonstrations, small_recording, None),
                           "selection='steps' needs the recording's driver_steps")
    with pytest.raises(ValueError, match="no driver_steps"):
        step_selection_summary(small_recording)


@pytest.mark.slow
def test_recording_without_speeds_is_a_clear_error_with_a_fallback(tmp_path):
    """estimate='speeds' on tracks whose vx, vy are not finite names the track and the fallback, which works."""
    import dataclasses

    from pirl_sim.scenarios.sumo import load_sumo_run, run_sumo_scenario
    from pirl_sim.scenarios.sumo.scenario import SumoScenarioConfig

    cfg = SumoScenarioConfig()
    cfg = dataclasses.replace(cfg, population=dataclasses.replace(cfg.population, n_vehicles=6))
    run_sumo_scenario(cfg, 0, out_dir=tmp_path)
    run = load_sumo_run(tmp_path)
    tracks = run.recording.tracks.copy()
    tracks.loc[tracks.index[::7], "vx"] = np.nan
    rec = dataclasses.replace(run.recording, tracks=tracks)
    from pirl_sim.scenarios.demonstrations import recorded_demonstrations

    with pytest.raises(ValueError, match="estimate='positions'"):
        recorded_demonstrations(rec, run.routes, selection="steps")
    demos = recorded_demonstrations(rec, run.routes, selection="steps", estimate="positions")
    assert demos and all(np.all(np.isfinite(d.states)) for d in demos)
