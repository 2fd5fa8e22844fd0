"""libsumo scenario runner: recording, heading convention, controller hook (per vehicle or batched), observation
views, determinism, processes, collisions, errors, and a quiet libsumo import."""

import math
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("libsumo")
pytest.importorskip("sumolib")

import libsumo  # noqa: E402

from pirl_sim.scenarios.sumo import (  # noqa: E402
    COLLISION_ACTIONS,
    RECORD_COLUMNS,
    SUMMARY_COLUMNS,
    BatchController,
    ConstantSpeed,
    RoundaboutSpec,
    SumoRun,
    VehicleSpec,
    build_network,
    routes,
    run_in_subprocess,
    simulate,
    speed_mode,
    sumo_angle_to_psi,
    sumo_command,
)
from pirl_sim.scenarios.sumo.runner import Observation, _OthersView  # noqa: E402


DURATION = 60.0  # [s]
COMMAND = 5.0  # [m/s]
N_VEHICLES = 10


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    spec = RoundaboutSpec(radius=20.0, n_arms=4)
    files = build_network(spec, tmp_path_factory.mktemp("roundabout"))
    rs = routes(spec)
    # every 5th route, so right turns, through routes and left turns from all arms are mixed
    vehicles = [VehicleSpec(f"veh{k}", rs[(5 * k) % len(rs)][0], depart=2.0 * k) for k in range(N_VEHICLES)]
    pirl = frozenset(v.vehicle_id for v in vehicles[::2])
    kwargs = dict(pirl_ids=pirl, controller=ConstantSpeed(COMMAND), until_empty=False)
    return files, rs, vehicles, pirl, kwargs


@pytest.fixture(scope="module")
def recording(scenario):
    files, rs, vehicles, _, kwargs = scenario
    return simulate(files.net, rs, vehicles, DURATION, seed=0, **kwargs)


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi

@pytest.mark.parametrize("angle_deg, psi", [(0.0, math.pi / 2), (90.0, 0.0), (180.0, -math.pi / 2),
                                            (270.0, math.pi), (45.0, math.pi / 4), (359.0, math.radians(91))])
def test_sumo_angle_to_psi(angle_deg, psi):
    assert float(sumo_angle_to_psi(angle_deg)) == pytest.approx(psi)


def test_speed_mode_bits():
    assert speed_mode() == 31  # SUMO's default: every check on
    assert speed_mode(max_accel=False, max_decel=False) == 25
    assert speed_mode(safe_speed=False, max_accel=False, max_decel=False, right_of_way=False,
                      red_light=False, ignore_junction_foes=True) == 32
    assert speed_mode(ignore_junction_foes=True) == 63

def test_recording_has_the_right_columns_and_rows(recording):
    frame, summary = recording.frame, recording.summary
    assert tuple(frame.columns) == RECORD_COLUMNS
    assert tuple(summary.columns) == SUMMARY_COLUMNS
    assert recording.sim_time_s == pytest.approx(DURATION)
    assert recording.wall_time_s < 20.0
    assert set(frame["vehicle_id"]) == {f"veh{k}" for k in range(N_VEHICLES)}
    assert not frame.duplicated(["step", "vehicle_id"]).any()
    assert frame["time"].to_numpy() == pytest.approx(0.1 * frame["step"].to_numpy())
    for _, g in frame.groupby("vehicle_id"):
        assert (np.diff(g["step"].to_numpy()) == 1).all()  # one row per step while in the network
    assert frame[["length", "width"]].to_numpy() == pytest.approx(np.tile([5.0, 1.8], (len(frame), 1)))
    # the box centre lies half a length behind SUMO's front-bumper position
    back = np.hypot(frame["x_front"] - frame["x"], frame["y_front"] - frame["y"])
    assert back.to_numpy() == pytest.approx(np.full(len(frame), 2.5))
    assert frame["vx"].to_numpy() == pytest.approx(frame["speed"] * np.cos(frame["psi_rad"]))
    assert (summary["status"] == "arrived").sum() >= N_VEHICLES // 2
    arrived = summary.loc[summary["status"] == "arrived", "vehicle_id"]
    last_rows = frame.groupby("vehicle_id").tail(1).set_index("vehicle_id")
    assert last_rows.loc[arrived, "arrived"].all()
    assert frame["arrived"].sum() == len(arrived) and not frame["vanished"].any()
    assert not summary["collided"].any() and not summary["removed_early"].any()


def test_heading_matches_the_direction_of_motion(recording):
    errors = []
    for _, g in recording.frame.groupby("vehicle_id"):
        dx, dy = np.diff(g["x"].to_numpy()), np.diff(g["y"].to_numpy())
        psi = g["psi_rad"].to_numpy()
        mid = np.angle(np.exp(1j * psi[:-1]) + np.exp(1j * psi[1:]))  # heading halfway through the step
        moving = np.hypot(dx, dy) > 0.1  # [m] per 0.1 s step, i.e. faster than 1 m/s
        errors.append(np.abs(_wrap(np.arctan2(dy, dx) - mid))[moving])
    errors = np.concatenate(errors)
    assert len(errors) > 1000
    assert errors.max() < 0.1  # [rad]; largest on the S-bends entering the ring (~0.09 rad)


def test_controller_drives_the_pirl_vehicles_and_sumo_the_others(recording, scenario):
    frame, summary = recording.frame, recording.summary
    pirl = scenario[3]
    assert set(frame.loc[frame["pirl"], "vehicle_id"]) == pirl
    mine, others = frame[frame["pirl"]], frame[~frame["pirl"]]
    assert (mine["commanded_speed"] == COMMAND).all()
    assert others["commanded_speed"].isna().all() and others["overridden"].isna().all()
    assert others["speed"].max() > COMMAND + 3.0  # background traffic follows SUMO's model
    for _, g in mine.groupby("vehicle_id"):
        nxt = g["speed"].to_numpy()[1:]
        flag = g["overridden"].to_numpy()[:-1]
        assert (np.abs(nxt[~flag.astype(bool)] - COMMAND) <= 0.01).all()  # obeyed where not flagged
        assert (np.abs(nxt[flag.astype(bool)] - COMMAND) > 0.01).all()
        # departing at the maximum speed, SUMO can brake only at the vehicle type's 4.5 m/s^2
        assert bool(g["overridden"].iloc[0])
    fractions = summary.set_index("vehicle_id").loc[sorted(pirl), "overridden_fraction"]
    assert ((fractions > 0) & (fractions < 0.5)).all()
    assert summary.loc[~summary["pirl"], "overridden_fraction"].isna().all()


def test_controller_none_hands_the_vehicle_back_to_sumo(scenario):
    files, rs, vehicles, _, _ = scenario

    rec = simulate(files.net, rs, vehicles[:1], 30.0, pirl_ids={"veh0"}, controller=_slow_then_free)
    g = rec.frame
    assert (g.loc[g["time"] <= 5.0, "commanded_speed"] == 3.0).all()
    assert g.loc[g["time"] > 5.0, "commanded_speed"].isna().all()
    assert g.loc[g["time"] > 5.0, "speed"].max() > 6.0


def _slow_then_free(time, vehicle_id, observation):
    assert observation.vehicle_id == vehicle_id and observation.time == time
    assert observation.route_edges[0] == observation.ego.edge_id or time > 1.0
    return 3.0 if time <= 5.0 else None


def test_observation_sees_other_vehicles_and_the_leader(scenario):
    files, rs, _, _, _ = scenario
    seen = []

    def ctrl(time, vehicle_id, obs):
        seen.append((time, set(obs.others), obs.leader, obs.ego.speed))
        return None

    vehicles = [VehicleSpec("lead", "arm0_to_arm2", 0.0), VehicleSpec("me", "arm0_to_arm2", 3.0)]
    simulate(files.net, rs, vehicles, 10.0, pirl_ids={"me"}, controller=ctrl)
    assert seen and all(others == {"lead"} for _, others, _, _ in seen[:5])
    leaders = [lead for _, _, lead, _ in seen if lead is not None]
    assert leaders and leaders[0][0] == "lead" and leaders[0][1] > 0.0

def test_same_seed_gives_an_identical_recording(recording, scenario):
    files, rs, vehicles, _, kwargs = scenario
    again = simulate(files.net, rs, vehicles, DURATION, seed=0, **kwargs)
    pd.testing.assert_frame_equal(again.frame, recording.frame)
    pd.testing.assert_frame_equal(again.summary, recording.summary)
    other = simulate(files.net, rs, vehicles, DURATION, seed=1, **kwargs)
    assert not other.frame.equals(recording.frame)  # the seed reaches SUMO (speed factors, dawdling)


def test_runs_inside_a_spawned_subprocess(recording, scenario):
    files, rs, vehicles, _, kwargs = scenario
    rec = run_in_subprocess(simulate, files.net, rs, vehicles, DURATION, seed=0, **kwargs)
    pd.testing.assert_frame_equal(rec.frame, recording.frame)


def test_traci_backend_gives_the_same_recording(recording, scenario):
    pytest.importorskip("traci")
    files, rs, vehicles, _, kwargs = scenario
    rec = simulate(files.net, rs, vehicles, DURATION, seed=0, backend="traci", **kwargs)
    assert rec.backend == "traci"
    pd.testing.assert_frame_equal(rec.frame, recording.frame)

def test_an_interruption_is_not_replaced_by_the_error_of_closing_a_dead_traci_connection(scenario):
    """Ctrl-C reaches SUMO too (one process group): TraCI's close then fails on the dead connection, and the
    interruption, not that error, leaves the run."""
    pytest.importorskip("traci")
    files, rs, vehicles, _, _ = scenario
    with pytest.raises(KeyboardInterrupt):
        with SumoRun(files.net, rs, vehicles[:2], backend="traci") as run:
            run.run(1.0)
            process = run._api._process  # the SUMO server TraCI started
            process.kill()
            process.wait()
            raise KeyboardInterrupt
    assert not run.running
    run2 = SumoRun(files.net, rs, vehicles[:2], backend="traci").start()
    run2._api._process.kill()
    run2._api._process.wait()
    with pytest.raises(Exception) as closing:  # without an exception on its way, a failed close is not hidden
        run2.close()
    assert not isinstance(closing.value, KeyboardInterrupt)


def test_libsumo_one_run_per_process_and_always_closed(scenario):
    files, rs, vehicles, _, _ = scenario
    with SumoRun(files.net, rs, vehicles[:2]) as run:
        assert run.running
        with pytest.raises(RuntimeError, match="one simulation per process"):
            SumoRun(files.net, rs, vehicles[:2]).start()
        run.run(1.0)
    assert not run.running
    with pytest.raises(RuntimeError, match="starts once"):
        run.start()
    # an error inside the run still closes SUMO, so the next run can start
    with pytest.raises(ValueError, match=r"controller returned -1\.0 for vehicle 'veh0'"):
        simulate(files.net, rs, vehicles[:1], 5.0, pirl_ids={"veh0"}, controller=_negative)
    rec = simulate(files.net, rs, vehicles[:1], 1.0)
    assert len(rec.frame) > 0


def _negative(time, vehicle_id, observation):
    return -1.0


def test_collisions_and_vanished_vehicles_are_flagged(scenario):
    files, rs, _, _, _ = scenario
    # a fast follower with every safety check off runs into a slow leader
    vehicles = [VehicleSpec("slow", "arm0_to_arm2", 0.0), VehicleSpec("fast", "arm0_to_arm2", 2.0)]
    rec = simulate(files.net, rs, vehicles, 20.0, pirl_ids={"slow", "fast"}, controller=_rear_end,
                   speed_mode=speed_mode(safe_speed=False, max_decel=False))
    assert rec.summary.set_index("vehicle_id")["collided"].all()
    assert rec.frame.groupby("vehicle_id")["collided"].any().all()
    # a vehicle taken out of the network mid-route has vanished, not arrived
    with SumoRun(files.net, rs, [VehicleSpec("gone", "arm0_to_arm2", 0.0)]) as run:
        run.run(3.0)
        libsumo.vehicle.unsubscribe("gone")  # libsumo 1.28 fails the next step for a removed subscribed one
        libsumo.vehicle.remove("gone")
        rec = run.run(1.0)
    row = rec.summary.set_index("vehicle_id").loc["gone"]
    assert row["status"] == "vanished" and row["removed_early"]
    assert bool(rec.frame["vanished"].iloc[-1]) and not rec.frame["arrived"].any()


def _rear_end(time, vehicle_id, observation):
    return 2.0 if vehicle_id == "slow" else 13.0


@pytest.mark.parametrize("change, match", [
    (dict(routes=[("r", ["arm0_in", "no_such_edge"])]), r"route 'r' is unreachable: unknown edge 'no_such_edge'"),
    (dict(routes=[("r", ["arm0_in", "ring1_2"])]), r"route 'r' is unreachable: edge 'arm0_in' does not lead"),
    (dict(vehicles=[VehicleSpec("v", "no_route", 0.0)]), "unknown route 'no_route'"),
    (dict(vehicles=[VehicleSpec("v", "arm0_to_arm2", 0.0)] * 2), "given twice"),
    (dict(pirl_ids={"ghost"}), "not in the run"),
    (dict(pirl_ids={"v"}, controller=None), "no controller"),
    (dict(backend="sumo-gui"), "backend must be one of"),
    (dict(speed_mode=200), "speed_mode must be"),
    (dict(step_length=0.0), "step_length must be"),
])
def test_bad_inputs_raise_before_sumo_starts(scenario, monkeypatch, change, match):
    files = scenario[0]

    def no_start(*args, **kwargs):
        raise AssertionError("SUMO was started")

    monkeypatch.setattr(libsumo, "start", no_start)
    args = dict(routes=routes(files.spec), vehicles=[VehicleSpec("v", "arm0_to_arm2", 0.0)],
                pirl_ids=(), controller=ConstantSpeed(5.0), backend="libsumo", speed_mode=31,
                step_length=0.1)
    args.update(change)
    with pytest.raises(ValueError, match=match):
        simulate(files.net, args.pop("routes"), args.pop("vehicles"), 10.0, **args)


@pytest.mark.parametrize("kwargs, match", [
    (dict(depart=-1.0), "depart must be"),
    (dict(depart=float("inf")), "depart must be"),
    (dict(depart_speed="fastest"), "unknown depart_speed"),
    (dict(depart_speed=-3.0), "depart_speed must be"),
    (dict(vehicle_id=""), "vehicle_id must be"),
])
def test_vehicle_spec_rejects_bad_values(kwargs, match):
    args = dict(vehicle_id="v", route_id="r", depart=0.0)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        VehicleSpec(**args)


@pytest.fixture(scope="module")
def net(tmp_path_factory):
    spec = RoundaboutSpec()
    return build_network(spec, tmp_path_factory.mktemp("roundabout")), routes(spec)


class Batch:
    """Commands 6 m/s to every vehicle but "skip", and records what it was asked."""

    def __init__(self):
        self.calls = []

    def commands(self, time, observations):
        self.calls.append((time, sorted(observations)))
        return {vid: 6.0 for vid in observations if vid != "skip"}

    def __call__(self, time, vehicle_id, observation):  # pragma: no cover - never used in batch mode
        raise AssertionError("a batch controller is asked once per step")


def test_batch_controller_is_called_once_per_step_with_every_controlled_vehicle(net):
    files, rs = net
    vehicles = [VehicleSpec("a", "arm0_to_arm2", 0.0), VehicleSpec("b", "arm1_to_arm3", 0.0),
                VehicleSpec("skip", "arm2_to_arm0", 0.0), VehicleSpec("bg", "arm3_to_arm1", 0.0)]
    ctrl = Batch()
    assert isinstance(ctrl, BatchController)
    rec = simulate(files.net, rs, vehicles, 5.0, pirl_ids={"a", "b", "skip"}, controller=ctrl)
    assert len(ctrl.calls) == len(rec.frame["step"].unique())
    assert all(ids == ["a", "b", "skip"] for _, ids in ctrl.calls[1:])
    f = rec.frame
    assert (f.loc[f["vehicle_id"].isin(["a", "b"]), "commanded_speed"] == 6.0).all()
    assert f.loc[f["vehicle_id"].isin(["skip", "bg"]), "commanded_speed"].isna().all()  # handed back / SUMO's
    late = f[(f["time"] > 3.0) & f["vehicle_id"].isin(["a", "b"])]
    assert late["speed"].to_numpy() == pytest.approx(6.0)


class Stray(Batch):
    def commands(self, time, observations):
        return {"ghost": 3.0}


def test_batch_controller_answering_for_other_vehicles_is_an_error(net):
    files, rs = net
    with pytest.raises(ValueError, match=r"not asked about at t = .* \['ghost'\]"):
        simulate(files.net, rs, [VehicleSpec("a", "arm0_to_arm2", 0.0)], 2.0, pirl_ids={"a"}, controller=Stray())


def test_collision_action(net):
    files, rs = net
    assert "remove" in COLLISION_ACTIONS
    cmd = sumo_command(files.net, collision_action="remove")
    assert cmd[cmd.index("--collision.action") + 1] == "remove"
    with pytest.raises(ValueError, match="collision_action must be one of"):
        SumoRun(files.net, rs, [], collision_action="explode")


def test_removed_in_a_collision_is_flagged_on_the_last_row(net):
    files, rs = net
    vehicles = [VehicleSpec("slow", "arm0_to_arm2", 0.0), VehicleSpec("fast", "arm0_to_arm2", 2.0)]
    with SumoRun(files.net, rs, vehicles, pirl_ids={"slow", "fast"}, controller=_rear_end,
                 speed_mode=speed_mode(safe_speed=False, max_decel=False), collision_action="remove") as run:
        rec = run.run(20.0)
        assert run.n_finished == 2 and run.n_present == 0 and run.expected() == 0
    summary = rec.summary.set_index("vehicle_id")
    assert summary["collided"].all() and summary["removed_early"].all()
    for vid, g in rec.frame.groupby("vehicle_id"):
        assert bool(g["collided"].iloc[-1]) and bool(g["vanished"].iloc[-1])


def test_simulate_sumo_prints_no_pyarrow_warning(tmp_path):
    code = ("import sys, traci; from pirl_sim.cli import main; "
            f"rc = main(['simulate', 'sumo', '--n-vehicles', '2', '--quiet', '--out', {str(tmp_path / 'run')!r}]); "
            "import os; assert 'LIBSUMO_AS_TRACI' not in os.environ; assert hasattr(traci, 'connect'); sys.exit(rc)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "pyarrow" not in out.stdout and "pyarrow" not in out.stderr


def test_observation_views_are_cheap_and_exact():
    states = {"a": 1, "b": 2, "c": 3}
    view = _OthersView(states, "b")
    assert dict(view) == {"a": 1, "c": 3} and len(view) == 2 and "b" not in view and "a" in view
    with pytest.raises(KeyError):
        view["b"]
    calls = []
    obs = Observation(0.0, "b", None, view, leader_fn=lambda: calls.append(1) or ("a", 5.0))
    assert obs.leader == ("a", 5.0) and obs.leader == ("a", 5.0) and calls == [1]  # asked once, on access
    late = Observation(0.0, "b", None, view, leader_fn=lambda: ("a", 5.0))
    late._expire()
    with pytest.raises(RuntimeError, match="during the step only"):
        late.leader
    assert Observation(0.0, "b", None, view, leader=None).leader is None
