"""Rendering colours of the highway-env roundabout (pirl_sim.scenarios.highway.vehicles): PIRL styles have colours
of their own, distinct from highway-env's, and crashed vehicles turn highway-env's crash red."""

import itertools
import math

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("highway_env")

from highway_env.vehicle.graphics import VehicleGraphics  # noqa: E402

from pirl_sim.scenarios.highway.scenario import HighwayScenarioConfig, build_routes  # noqa: E402
from pirl_sim.scenarios.highway.traffic import STEP_LENGTH, DriverConfig, RoundaboutTraffic, TrafficRules  # noqa: E402
from pirl_sim.scenarios.highway.vehicles import STYLE_COLORS  # noqa: E402
from pirl_sim.scenarios.planning import PLAN_COLUMNS  # noqa: E402

MIN_DISTANCE = 60.0  # RGB distance below which two colours are too alike to tell apart on screen
THETA = (3.0, 0.3, 1.0)
HIGHWAY_ENV_COLOURS = {
    "IDM blue": VehicleGraphics.BLUE,
    "linear yellow": VehicleGraphics.YELLOW,
    "ego green": VehicleGraphics.EGO_COLOR,
    "green": VehicleGraphics.GREEN,
    "default": VehicleGraphics.DEFAULT_COLOR,
    "crash red": VehicleGraphics.RED,
    "road grey": (100, 100, 100),
}


def _distance(a, b) -> float:
    return math.dist(tuple(a)[:3], tuple(b)[:3])


@pytest.fixture(scope="module")
def road():
    return build_routes(HighwayScenarioConfig())


def _traffic(road, pirl_ids, record_history=False):
    net, catalogue, routes = road
    plan = pd.DataFrame([(vid, 0.0, "arm0_to_arm2", True, 0, "tracks desired speed", *THETA) for vid in pirl_ids],
                        columns=list(PLAN_COLUMNS))
    traffic = RoundaboutTraffic(net, catalogue, routes, plan, drivers=DriverConfig(),
                                rules=TrafficRules(crash_removal_delay=None),
                                noise_rng=np.random.default_rng(0), behaviour_rng=np.random.default_rng(0),
                                record_history=record_history)
    traffic._pending = []
    return traffic


def _add_pirl(traffic, vid, route_id, s, speed, style):
    return traffic.add_vehicle("pirl", vid, route_id, s, speed, style=style, style_name=f"style {style}",
                               theta=np.array(THETA))


def test_style_colours_differ_from_highway_envs_and_from_each_other():
    assert len(set(STYLE_COLORS)) == len(STYLE_COLORS) >= 2
    for colour in STYLE_COLORS:
        assert len(colour) == 3 and all(0 <= c <= 255 for c in colour)
        for name, theirs in HIGHWAY_ENV_COLOURS.items():
            assert _distance(colour, theirs) >= MIN_DISTANCE, f"style colour {colour} too close to {name} {theirs}"
    for a, b in itertools.combinations(STYLE_COLORS, 2):
        assert _distance(a, b) >= MIN_DISTANCE, f"style colours {a} and {b} too alike"


def test_each_style_renders_in_its_colour_and_background_in_highway_envs_blue(road):
    traffic = _traffic(road, [f"p{k}" for k in range(len(STYLE_COLORS) + 1)])
    for k in range(len(STYLE_COLORS) + 1):  # one more than colours: styles wrap around
        v = _add_pirl(traffic, f"p{k}", "arm0_to_arm2", 10.0 + 12.0 * k, 5.0, style=k)
        assert VehicleGraphics.get_color(v) == STYLE_COLORS[k % len(STYLE_COLORS)]
    b = traffic.add_vehicle("background", "b", "arm2_to_arm0", 10.0, 5.0)
    assert VehicleGraphics.get_color(b) == VehicleGraphics.BLUE


def test_crashed_vehicles_render_in_highway_envs_red(road):
    """A PIRL vehicle and a background vehicle 2 m ahead of it overlap: both crash and render red, as
    highway-env draws its own crashed vehicles; a PIRL vehicle far away keeps its style colour."""
    traffic = _traffic(road, ["a", "far"], record_history=True)
    a = _add_pirl(traffic, "a", "arm0_to_arm1", 50.0, 8.0, style=0)
    b = traffic.add_vehicle("background", "b", "arm0_to_arm2", 52.0, 2.0)  # 2 m ahead: overlapping
    far = _add_pirl(traffic, "far", "arm2_to_arm0", 10.0, 8.0, style=2)
    assert VehicleGraphics.get_color(a) == STYLE_COLORS[0]
    for _ in range(5):
        traffic.act()
        traffic.step(STEP_LENGTH)
    assert a.crashed and b.crashed and not far.crashed
    assert VehicleGraphics.get_color(a) == VehicleGraphics.RED
    assert VehicleGraphics.get_color(b) == VehicleGraphics.RED
    assert VehicleGraphics.get_color(far) == STYLE_COLORS[2]
    assert a._color == STYLE_COLORS[0]  # the style colour is kept, only hidden while crashed
    # trajectory ghosts (show_trajectories) are drawn as the vehicle was
    assert VehicleGraphics.get_color(a.history[0]) == VehicleGraphics.RED
    assert VehicleGraphics.get_color(far.history[0]) == STYLE_COLORS[2]


def test_rendered_frame_shows_style_colours_and_crashed_vehicles_in_red():
    """Offscreen rgb_array render of the env (no window): PIRL vehicles are drawn in their style colours;
    once every vehicle is crashed, all of them are drawn in highway-env's red."""
    gym = pytest.importorskip("gymnasium")
    import pirl_sim.envs  # noqa: F401  (registers the env)

    env = gym.make("pirl_sim/Roundabout-v0", render_mode="rgb_array", config={"offscreen_rendering": True})
    try:
        env.reset(seed=0)
        for _ in range(30):
            env.step(env.action_space.sample())

        def pixels(colour):
            return int((np.abs(frame.astype(int) - np.array(colour)).max(axis=-1) == 0).sum())

        frame = env.render()
        assert sum(pixels(c) for c in STYLE_COLORS) > 0
        assert pixels(VehicleGraphics.RED) == 0
        for v in env.unwrapped.road.vehicles:
            v.crashed = True
        frame = env.render()
        assert pixels(VehicleGraphics.RED) > 0
        assert all(pixels(c) == 0 for c in (*STYLE_COLORS, VehicleGraphics.BLUE, VehicleGraphics.EGO_COLOR))
    finally:
        env.close()
