"""A single-lane roundabout passage with drivers of three known styles (the paper's driving model, simulated).

The reference path is a straight approach, part of a ring, and a straight exit (the path a car drives through
a roundabout); every driver follows the paper's longitudinal model (`pirl_sim.driving`) with its own weights
over (speed_dev, acc_sq, jerk_sq). The styles are the three answers of the paper's user study. On the
approach the desired speed is the speed limit, on the ring sqrt(a_lat / |kappa|), so the styles differ in how
they brake into the ring — which is what makes them identifiable from features.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pirl_sim.driving import PathDriverModel, roundabout_model
from pirl_sim.paths import ReferencePath
from pirl_sim.population import Population, Style, generate_demonstrations
from pirl_sim.trajectory import Trajectory
from pirl_sim.scenarios.synthetic import MAX_STEPS, MAX_TRAJECTORIES

__all__ = [
    "PassageConfig",
    "PassageData",
    "THREE_STYLES",
    "passage_polyline",
    "generate",
    "recording",
    "lanelet_centerlines",
    "write_scene",
]

#: The user-study styles of the paper, as normalised weights (jerk_sq = 1).
THREE_STYLES = (
    Style("tracks desired speed", 1.0, {"speed_dev": 3.0, "acc_sq": 0.3}, {"speed_dev": 0.3, "acc_sq": 0.03}),
    Style("minimises acceleration", 1.0, {"speed_dev": 0.1, "acc_sq": 3.0}, {"speed_dev": 0.01, "acc_sq": 0.3}),
    Style("no preference", 1.0, {"speed_dev": 0.3, "acc_sq": 0.3}, {"speed_dev": 0.03, "acc_sq": 0.03}),
)


def passage_polyline(radius: float, approach: float, ring_angle_deg: float, exit_length: float, step: float = 2.0):
    """Vertices (P, 2) [m] of approach -> counter-clockwise ring arc -> exit, ring centred at the origin."""
    for name, v in (("radius", radius), ("approach", approach), ("exit_length", exit_length), ("step", step)):
        if not np.isfinite(v) or v <= 0:
            raise ValueError(f"{name} must be > 0 m, got {v!r}")
    if not 0 < ring_angle_deg < 360:
        raise ValueError(f"ring_angle_deg must be in (0, 360), got {ring_angle_deg!r}")
    n_app = max(2, int(np.ceil(approach / step)) + 1)
    app = np.column_stack([np.linspace(-approach, 0.0, n_app), np.full(n_app, -radius)])
    sweep = np.deg2rad(ring_angle_deg)
    n_ring = max(3, int(np.ceil(radius * sweep / step)) + 1)
    ang = -np.pi / 2 + np.linspace(0.0, sweep, n_ring)[1:]
    ring = radius * np.column_stack([np.cos(ang), np.sin(ang)])
    end, heading = ring[-1], ang[-1] + np.pi / 2
    n_exit = max(2, int(np.ceil(exit_length / step)) + 1)
    t = np.linspace(0.0, exit_length, n_exit)[1:]
    exit_ = end + t[:, None] * np.array([np.cos(heading), np.sin(heading)])
    return np.vstack([app, ring, exit_])


@dataclass(frozen=True)
class PassageConfig:
    """A population of drivers through a roundabout passage.

    Attributes
    ----------
    radius, approach, ring_angle_deg, exit_length : geometry [m, m, deg, m]
    styles : tuple of Style          over (speed_dev, acc_sq, jerk_sq)
    rationality : float or None      Boltzmann scale beta (None: exact optima)
    n_trajectories, n_train : int
    n_steps : int                    steps per demonstration at dt
    dt : float [s]
    start_s : (float, float)         start positions along the path [m]
    start_v : (float, float)         start speeds [m/s]
    seed : int
    """

    radius: float = field(default=20.0, metadata={"doc": "ring radius [m]"})
    approach: float = field(default=50.0, metadata={"doc": "straight approach [m]"})
    ring_angle_deg: float = field(default=270.0, metadata={"doc": "part of the ring driven [deg]"})
    exit_length: float = field(default=50.0, metadata={"doc": "straight exit [m]"})
    styles: tuple[Style, ...] = field(
        default=THREE_STYLES, metadata={"doc": "styles over (speed_dev, acc_sq, jerk_sq); default: the three user-study styles"})
    rationality: float | None = field(default=100.0, metadata={"doc": "Boltzmann beta; inf: exactly optimal drivers"})
    n_trajectories: int = field(default=600, metadata={"doc": "passages in all (train + test)"})
    n_train: int = field(default=500, metadata={"doc": "training passages; the rest are the test set"})
    n_steps: int = field(default=40, metadata={"doc": "steps per passage"})
    dt: float = field(default=0.2, metadata={"doc": "step [s]"})
    start_s: tuple[float, float] = field(default=(10.0, 40.0), metadata={"doc": "start positions along the path [m]"})
    start_v: tuple[float, float] = field(default=(9.0, 12.0), metadata={"doc": "start speeds [m/s]"})
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("n_trajectories", "n_train", "n_steps"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise TypeError(f"{name} must be an integer, got {v!r}")
        if not 2 <= self.n_trajectories <= MAX_TRAJECTORIES:
            raise ValueError(f"n_trajectories must be in [2, {MAX_TRAJECTORIES}], got {self.n_trajectories}")
        if self.n_steps > MAX_STEPS:
            raise ValueError(f"n_steps must be in [2, {MAX_STEPS}], got {self.n_steps}")
        if not 1 <= self.n_train < self.n_trajectories:
            raise ValueError(f"n_train must be in [1, n_trajectories - 1], got {self.n_train} of {self.n_trajectories}")
        if self.n_steps < 2:
            raise ValueError(f"n_steps must be >= 2, got {self.n_steps}")
        for name in ("start_s", "start_v"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ValueError(f"{name} must be (low, high) with low <= high, got {(lo, hi)}")
        if self.start_v[0] < 0:
            raise ValueError(f"start speeds must be >= 0 m/s, got {self.start_v}")
        passage_polyline(self.radius, self.approach, self.ring_angle_deg, self.exit_length)  # validates geometry

    def path(self) -> ReferencePath:
        return ReferencePath.from_polyline(
            passage_polyline(self.radius, self.approach, self.ring_angle_deg, self.exit_length)
        )

    def model(self) -> PathDriverModel:
        return roundabout_model(self.path(), dt=self.dt)


@dataclass(frozen=True)
class PassageData:
    config: PassageConfig
    model: PathDriverModel
    train: list[Trajectory]
    test: list[Trajectory]


def generate(config: PassageConfig = PassageConfig()) -> PassageData:
    """Draw the data set; same config (seed included), same bytes."""
    rng = np.random.default_rng(config.seed)
    model = config.model()
    n = config.n_trajectories
    x0 = np.column_stack([rng.uniform(*config.start_s, n), rng.uniform(*config.start_v, n), np.zeros(n)])
    pop = Population(model.features, config.styles, config.rationality)
    demos = generate_demonstrations(model, pop, x0, config.n_steps, rng)
    order = rng.permutation(n)
    return PassageData(config, model, [demos[i] for i in order[: config.n_train]], [demos[i] for i in order[config.n_train :]])


def recording(data: PassageData, *, frames_apart: int = 100):
    """The passages as a `pirl_sim.scenarios.recording.ScenarioRecording` (tracks at 0.1 s frames, ground
    truth, the three lanelets of the passage).

    States at the model's dt are refined to 0.1 s frames through the exact dynamics (the jerk is constant
    over a step) and placed on the path (x, y, heading; vx, vy along the heading). Track k starts at
    frame 1 + k * ``frames_apart`` so that drivers do not meet (the passage has no interaction).
    """
    import pandas as pd

    from pirl_sim.dynamics import longitudinal
    from pirl_sim.scenarios.recording import GROUND_TRUTH_COLUMNS, TRACK_COLUMNS, ScenarioRecording

    model = data.model
    dt = model.dynamics.dt
    sub = int(round(dt / 0.1))
    fine = longitudinal(dt / sub)
    names = model.features.names
    rows, truth = [], []
    for k, t in enumerate(data.train + data.test):
        X = fine.rollout(t.states[0], np.repeat(t.controls, sub, axis=0))
        s, v = X[:, 0], X[:, 1]
        xy = model.path.position(s, extrapolate=True)  # type: ignore[union-attr]
        psi = model.path.heading_at(s, extrapolate=True)  # type: ignore[union-attr]
        frame = 1 + k * frames_apart + np.arange(len(s))
        rows.append(pd.DataFrame({
            "track_id": k + 1, "time_s": frame / 10.0, "agent_type": "car", "x": xy[:, 0], "y": xy[:, 1],
            "vx": v * np.cos(psi), "vy": v * np.sin(psi), "psi_rad": np.arctan2(np.sin(psi), np.cos(psi)),
            "length": 4.5, "width": 1.8,
        }))
        truth.append({
            "track_id": k + 1, "agent_id": f"passage_{k + 1}", "route_id": "passage", "is_pirl": True,
            "style": t.metadata["style"], "style_name": t.metadata["style_name"],
            **{f"theta_{n}": float(w) for n, w in zip(names, t.metadata["theta"])},
            "interacted": False, "collided": False, "removed_early": False, "overridden_fraction": 0.0,
            "status": "arrived", "n_frames": len(s),
        })
    lanes, successors = lanelet_centerlines(data.config)
    return ScenarioRecording(
        tracks=pd.concat(rows, ignore_index=True)[list(TRACK_COLUMNS)],
        ground_truth=pd.DataFrame(truth)[list(GROUND_TRUTH_COLUMNS)],
        lanes=lanes,
        successors=successors,
        info={"simulator": "pirl_sim passage", "seed": data.config.seed, "n_trajectories": data.config.n_trajectories},
    )


def lanelet_centerlines(config: PassageConfig, spacing: float = 1.0) -> tuple[dict, dict]:
    """The passage as three lanelets (approach, ring, exit): centerlines (P, 2) [m] and successors."""
    path = config.path()
    ring_start = config.approach
    ring_end = ring_start + np.deg2rad(config.ring_angle_deg) * config.radius
    cuts = [0.0, ring_start, ring_end, path.length]
    lines = {}
    for name, a, b in zip(("approach", "ring", "exit"), cuts[:-1], cuts[1:]):
        n = max(2, int(np.ceil((b - a) / spacing)) + 1)
        lines[name] = path.position(np.linspace(a, b, n))
    return lines, {"approach": ["ring"], "ring": ["exit"], "exit": []}


def write_scene(data: PassageData, out_dir) -> dict:
    """Write the passages as a recorded scene with the one recording writer
    (`pirl_sim.scenarios.recording.write_recording`): tracks, ground truth, Lanelet2 map. Returns the paths."""
    from pathlib import Path

    from pirl_sim.scenarios.recording import GROUND_TRUTH_FILE, MAP_FILE, TRACKS_FILE, write_recording

    out = Path(out_dir)
    write_recording(recording(data), out)
    return {"tracks": out / TRACKS_FILE, "truth": out / GROUND_TRUTH_FILE, "map": out / MAP_FILE}
