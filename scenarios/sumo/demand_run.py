"""SUMO's own drivers (Krauss car following) on a network built from a Lanelet2 map, driving a recorded or sampled
demand, recorded as an INTERACTION track file: the car-following baseline of a realism comparison."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from .imports import sumo_module

__all__ = ["run_demand", "TRACK_COLUMNS"]

TRACK_COLUMNS = ("track_id", "frame_id", "timestamp_ms", "agent_type", "x", "y", "vx", "vy", "psi_rad", "length",
                 "width")
_DT = 0.1  # [s] the INTERACTION frame interval


def run_demand(net, departures, out, *, seed: int = 0, end_s: float | None = None, sumo_options=()) -> Path:
    """Drive ``departures`` through a SUMO network with SUMO's default drivers and write their tracks.

    Parameters
    ----------
    net : pirl_sim.scenarios.sumo.lanelet_network.LaneletNetwork or path
        The network (`network_from_lanelet2`), or its ``*.net.xml``: a lanelet of a route that is on no edge of a
        `LaneletNetwork` is a ValueError; a bare path has no record of the chains, and such lanelets are skipped.
    departures : sequence of pirl_sim.scenarios.demand.Departure   routes are lanelet ids, driven on the edges
                                that hold them (a chain of lanelets is one edge ``ll<first id>``, `lanelet_edges`)
    out : path                  the track file to write (INTERACTION vehicle columns, 0.1 s frames; x, y the box centre)
    seed : int                  SUMO's random seed (its drivers' imperfection and speed factors)
    end_s : float, optional     stop at this time [s] (default: all arrived, at most an hour after the last departure)

    Returns
    -------
    path : pathlib.Path         ``out``
    """
    libsumo = sumo_module("libsumo")

    from pirl_sim.io.interaction import write_tracks

    from ..lanelet_graph import edge_id

    net_path = Path(getattr(net, "net", net))
    if not net_path.is_file():
        raise FileNotFoundError(f"no SUMO network at {net_path}")
    chain_of = {lid: e for e, lids in getattr(net, "lanelets", {}).items() for lid in lids}  # lanelet -> its edge
    departures = sorted(departures, key=lambda d: d.time_s)
    if not departures:
        raise ValueError("run_demand: no departures")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    last = departures[-1].time_s
    stop = last + 3600.0 if end_s is None else float(end_s)
    if not (math.isfinite(stop) and stop > 0):
        raise ValueError(f"end_s must be a finite time > 0 [s], got {end_s!r}")
    libsumo.start(["sumo", "-n", str(net_path), "--step-length", f"{_DT}", "--seed", str(int(seed)), "--no-step-log",
                   "--no-warnings", "--collision.action", "warn", "--time-to-teleport", "-1", *sumo_options])
    rows: list[tuple] = []
    try:
        routes: dict[tuple, str] = {}
        known = set(libsumo.edge.getIDList())  # a lanelet inside a chain has no edge of its own: its chain's edge
        for k, d in enumerate(departures):
            if tuple(d.route) not in routes:
                routes[tuple(d.route)] = f"r{len(routes)}"
                if not d.route:
                    raise ValueError("run_demand: a departure has an empty route")
                if chain_of:  # through the chains, so that a lanelet the network lacks is named
                    unknown = [i for i in d.route if int(i) not in chain_of]
                    if unknown:
                        raise ValueError(f"run_demand: lanelet(s) {unknown} of route {tuple(d.route)} are on no edge "
                                         f"of {net_path}")
                    on = [chain_of[int(i)] for i in d.route]
                    edges = [e for j, e in enumerate(on) if j == 0 or e != on[j - 1]]
                else:
                    edges = [e for e in (edge_id(i) for i in d.route) if e in known]
                if not edges or edges[0] != edge_id(d.route[0]) or edges[0] not in known:
                    raise ValueError(f"run_demand: route {tuple(d.route)} does not start on an edge of {net_path}")
                libsumo.route.add(routes[tuple(d.route)], edges)
            rid = routes[tuple(d.route)]
            vid = str(k + 1)
            libsumo.vehicle.add(vid, rid, depart=f"{max(d.time_s, 0.0):.1f}", departSpeed="max", departLane="best")
            libsumo.vehicle.setLength(vid, float(d.length))
            libsumo.vehicle.setWidth(vid, float(d.width))
        step = 0
        while True:
            libsumo.simulationStep()
            step += 1
            t = step * _DT
            for vid in libsumo.vehicle.getIDList():
                x, y = libsumo.vehicle.getPosition(vid)  # the front bumper's middle
                psi = math.radians(90.0 - libsumo.vehicle.getAngle(vid))
                v = libsumo.vehicle.getSpeed(vid)
                half = libsumo.vehicle.getLength(vid) / 2.0
                rows.append((int(vid), step, int(round(t * 1000)), "car", x - half * math.cos(psi),
                             y - half * math.sin(psi), v * math.cos(psi), v * math.sin(psi),
                             math.atan2(math.sin(psi), math.cos(psi)), libsumo.vehicle.getLength(vid),
                             libsumo.vehicle.getWidth(vid)))
            if t >= stop or (t > last and libsumo.simulation.getMinExpectedNumber() == 0):
                break
    finally:
        libsumo.close()
    if not rows:
        raise ValueError("run_demand: no vehicle entered the network")
    df = pd.DataFrame(rows, columns=list(TRACK_COLUMNS)).sort_values(["track_id", "frame_id"], kind="stable")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    return write_tracks(df.reset_index(drop=True), out)
