"""SumoRun extensions: batch controllers (one call per step), collision actions, run bookkeeping."""

import pytest

pytest.importorskip("libsumo")

from pirl_sim.scenarios.sumo import (  # noqa: E402
    COLLISION_ACTIONS,
    BatchController,
    RoundaboutSpec,
    SumoRun,
    VehicleSpec,
    build_network,
    routes,
    simulate,
    speed_mode,
    sumo_command,
)


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


def _rear_end(time, vehicle_id, observation):
    return 2.0 if vehicle_id == "slow" else 13.0


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
