"""The vehicles of the highway-env roundabout: highway-env vehicle classes that follow one fixed route.

Each class subclasses highway-env's own (``IDMVehicle`` or ``ControlledVehicle``) and keeps its **lateral**
control (lane following along the route). The **longitudinal** command, an acceleration [m/s^2], is set from
outside, by :class:`~.traffic.RoundaboutTraffic` or by the agent, in ``command_acceleration`` before :meth:`act`.
:class:`RouteFollowing` tracks lanes along the route only and keeps a route coordinate ``route_s`` [m]
(:meth:`RouteFollowing.on_state_update`), and advances positions by the mean of the speeds at both ends of a step,
never reversing (:meth:`RouteFollowing.step`).

What changes from highway-env's vehicles, and why, is in the documentation's "highway-env roundabouts" page.
"""

from __future__ import annotations

import math

import numpy as np
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle

from .network import RouteLanes

__all__ = ["PIRL", "BACKGROUND", "EGO", "RouteFollowing", "PirlVehicle", "BackgroundVehicle", "EgoVehicle",
           "place_on_route"]

PIRL = "pirl"  #: ``kind`` of a vehicle driven by a PIRL driver (its MPC)
BACKGROUND = "background"  #: ``kind`` of background traffic (highway-env's IDM)
EGO = "ego"  #: ``kind`` of the agent's vehicle

_NOT_ZERO = 1e-2  # highway_env.utils.not_zero's eps
_QUARTER_PI = 0.25 * math.pi

#: colours (RGB) of PIRL vehicles by style index, for rendering: none is one of highway-env's own
#: ``VehicleGraphics`` colours (IDM/background blue (100, 200, 255), linear yellow (200, 200, 0), ego green
#: (50, 200, 0), crashed red (255, 100, 100)) or close to them, so every PIRL vehicle stands out from
#: background traffic, and a crashed one (red, see :attr:`RouteFollowing.color`) from all of them
STYLE_COLORS = ((200, 100, 255), (255, 150, 0), (0, 150, 150), (150, 80, 40), (60, 60, 200))


class RouteFollowing:
    """Mixin (first base) for highway-env vehicles that drive one fixed route (see the module docstring).

    Attributes
    ----------
    vehicle_id : str
    kind : str                       `PIRL`, `BACKGROUND` or `EGO`
    route_lanes : RouteLanes
    route_pos : int                  position of the current lane in ``route_lanes.lanes``
    route_s : float                  route coordinate [m] of the vehicle's centre
    lane_s, lane_lat : float         coordinates [m] on the current lane
    command_acceleration : float     longitudinal command [m/s^2] applied at the next `act`
    applied_acceleration : float     acceleration [m/s^2] the last step carried out (speed change / dt)
    """

    vehicle_id: str = ""
    kind: str = ""
    _color: tuple | None = None

    @property
    def color(self) -> tuple | None:
        """Rendering colour (RGB) read by highway-env's ``VehicleGraphics.get_color``; ``None`` once crashed.

        ``VehicleGraphics`` uses a vehicle's ``color`` attribute before it looks at ``crashed``, so a
        vehicle given its own colour (PIRL styles, the env's ego) would never turn red; hiding the colour
        while crashed lets highway-env draw it in its crash red (``VehicleGraphics.RED``), as its own vehicles.
        Rendering only: nothing in the simulation reads it.
        """
        return None if self.crashed else self._color

    @color.setter
    def color(self, value) -> None:
        self._color = None if value is None else tuple(value)

    def init_route(self, route: RouteLanes, pos: int, vehicle_id: str) -> None:
        """Attach the route (called once, right after construction, by :func:`place_on_route`)."""
        self.vehicle_id = vehicle_id
        self.route_lanes = route
        self._route_lane_objects = tuple(self.road.network.get_lane(ix) for ix in route.lanes)
        self.route_pos = pos
        self.route = list(route.lanes)  # highway-env's planned route (its observations read the destination)
        self.command_acceleration = 0.0
        self.applied_acceleration = 0.0
        self.committed = False  # entering: decided to enter the ring (no more yielding)
        self.yielding = False  # entering: held back by ring traffic this step
        self._locate()

    def _locate(self) -> None:
        lanes, route = self._route_lane_objects, self.route_lanes
        k = self.route_pos
        lane = lanes[k]
        s, lat = lane.local_coordinates(self.position)
        while s >= lane.length and k + 1 < len(lanes):  # passed the lane's end: on to the next one
            k += 1
            lane = lanes[k]
            s, lat = lane.local_coordinates(self.position)
        self.route_pos = k
        self.lane_index = route.lanes[k]
        self.lane = lane
        self.lane_s, self.lane_lat = float(s), float(lat)
        self.route_s = float(route.offsets[k] + s)

    def on_state_update(self) -> None:
        """Lane tracking along the route (replaces highway-env's search over every lane)."""
        self._locate()
        if self.road.record_history:
            ghost = self.create_from(self)
            ghost._color, ghost.crashed = self._color, self.crashed  # drawn as the vehicle is (rendering only)
            self.history.appendleft(ghost)

    @property
    def remaining(self) -> float:
        """Route coordinate [m] left to the end of the route."""
        return self.route_lanes.length - self.route_s

    @property
    def merge_distance(self) -> float:
        """Route coordinate [m] from the centre to where the route joins the ring (< 0 once past it)."""
        return self.route_lanes.merge_s - self.route_s

    @property
    def entering(self) -> bool:
        """Still before the ring (on the access lane or the entry's S-bend)."""
        return self.route_pos <= self.route_lanes.entry_lane

    def target_lane(self):
        """Lane index to steer along: the next route lane from ``LENGTH / 2`` before the current one's end."""
        k = self.route_pos
        if k + 1 < len(self.route_lanes.lanes) and self.lane_s > self.lane.length - self.LENGTH / 2:
            k += 1
        return self.route_lanes.lanes[k]

    def steering_control(self, target_lane_index) -> float:
        """highway-env's lane-following steering (``ControlledVehicle.steering_control``: lateral offset ->
        lateral speed -> heading -> heading rate -> steering angle [rad]) towards the route lane
        ``target_lane_index``, in scalar arithmetic on the lane coordinates the vehicle already has (the same
        numbers as highway-env's, ~10x faster; tested against it)."""
        if target_lane_index == self.lane_index:
            lane, s, lat = self.lane, self.lane_s, self.lane_lat
        else:
            lane = self._route_lane_objects[self.route_lanes.position_of[target_lane_index[:2]]]
            s, lat = lane.local_coordinates(self.position)
        speed = self.speed
        v = speed if abs(speed) > _NOT_ZERO else (_NOT_ZERO if speed >= 0 else -_NOT_ZERO)  # utils.not_zero
        future_heading = lane.heading_at(s + speed * self.TAU_PURSUIT)
        heading_command = math.asin(min(max(-self.KP_LATERAL * lat / v, -1.0), 1.0))
        heading_ref = future_heading + min(max(heading_command, -_QUARTER_PI), _QUARTER_PI)
        heading_rate = self.KP_HEADING * (((heading_ref - self.heading + math.pi) % (2.0 * math.pi)) - math.pi)
        slip = math.asin(min(max(0.5 * self.LENGTH / v * heading_rate, -1.0), 1.0))
        steering = math.atan(2.0 * math.tan(slip))
        return float(min(max(steering, -self.MAX_STEERING_ANGLE), self.MAX_STEERING_ANGLE))

    def act(self, action=None) -> None:
        """Steer along the route; accelerate by ``command_acceleration`` (crashed vehicles keep braking)."""
        if self.crashed:
            return
        steering = self.steering_control(self.target_lane())
        Vehicle.act(self, {"steering": steering, "acceleration": float(self.command_acceleration)})

    def step(self, dt: float) -> None:
        """Bicycle model as highway-env's ``Vehicle.step``, with the mean speed over the step and no reversing."""
        self.clip_actions()
        beta = math.atan(0.5 * math.tan(self.action["steering"]))
        a = self.action["acceleration"]
        v0 = self.speed
        v1 = v0 + a * dt
        if v1 < 0.0:  # stops within the step
            dist = 0.5 * v0 * v0 / -a if a < 0 else 0.0
            v1 = 0.0
        else:
            dist = 0.5 * (v0 + v1) * dt
        h = self.heading + beta
        self.position += dist * np.array([math.cos(h), math.sin(h)])
        if self.impact is not None:
            self.position += self.impact
            self.crashed = True
            self.impact = None
        self.heading += dist * math.sin(beta) / (self.LENGTH / 2)
        self.speed = v1
        self.applied_acceleration = (v1 - v0) / dt
        self.on_state_update()


class PirlVehicle(RouteFollowing, IDMVehicle):
    """A PIRL driver's vehicle: its MPC under its own weights sets the acceleration (through the traffic);
    highway-env's IDM drives it only when it was handed back at a standstill. Its attributes besides
    :class:`RouteFollowing`'s:

    Attributes
    ----------
    theta : numpy.ndarray
        Normalised weights (3,) over (speed_dev, acc_sq, jerk_sq).
    style : int
    style_name : str
    """

    kind = PIRL
    theta: np.ndarray
    style: int = 0
    style_name: str = ""


class BackgroundVehicle(RouteFollowing, IDMVehicle):
    """Background traffic: highway-env's IDM (its parameters) along the route, desired speed
    ``speed_factor`` x the route's curvature-limited desired speed; yields at entries (through the traffic).
    """

    kind = BACKGROUND
    speed_factor: float = 1.0


class EgoVehicle(RouteFollowing, ControlledVehicle):
    """The agent's vehicle: the agent sets ``command_acceleration``; steering follows the route's lanes."""

    kind = EGO


def place_on_route(cls, road, route: RouteLanes, s: float, speed: float, vehicle_id: str):
    """A vehicle of class ``cls`` at route coordinate ``s`` [m] on the lane centre, heading along the lane.

    Raises
    ------
    ValueError
        If ``s`` is outside the route or ``speed`` negative.
    """
    if not 0.0 <= s <= route.length:
        raise ValueError(f"s = {s!r} m is outside route {route.route_id!r} (length {route.length:.1f} m)")
    if not speed >= 0.0:
        raise ValueError(f"speed must be >= 0 m/s, got {speed!r}")
    k = int(np.clip(np.searchsorted(route.offsets, s, side="right") - 1, 0, len(route.lanes) - 1))
    lane = road.network.get_lane(route.lanes[k])
    s_local = s - route.offsets[k]
    v = cls(road, lane.position(s_local, 0.0), lane.heading_at(s_local), float(speed))
    v.init_route(route, k, vehicle_id)
    if isinstance(v, ControlledVehicle):
        v.target_lane_index = route.lanes[k]
        v.target_speed = float(speed)
    return v
