"""How real simulated traffic is: per-vehicle kinematic, interactive and map features of a recording against
their distribution in simulated rollouts, scored as likelihoods and a weighted meta-metric.

The score follows the realism meta-metric of the Waymo Open Sim Agents Challenge (Montali et al., 2023): the
recorded values of each feature are scored under a histogram of the simulated values, a feature's likelihood is
the mean over recorded vehicles of ``exp(mean log-probability)``, and the meta-metric is their weighted mean.
The docs' "Realism" page explains the features, the weights and how this differs from the challenge.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pirl_sim.validation import int_at_least, number

__all__ = ["FeatureSpec", "FEATURES", "TrackFeatures", "track_features", "score_realism", "RealismScore",
           "compare_sources", "box_distance", "realism_figure", "OVERLAP_COLUMNS", "overlap_map"]


@dataclass(frozen=True)
class FeatureSpec:
    """One realism feature: its histogram's range and bins, its weight in the meta-metric, and how it is sampled.

    Parameters
    ----------
    name, unit : str          the feature's name (a key of `TrackFeatures`) and unit
    low, high : float         the histogram's range; values outside it count in the first or last bin
    bins : int                number of equal bins (>= 2)
    weight : float            weight in the meta-metric (>= 0; weights are normalised over the features scored)
    per : {"step", "vehicle"}   one value per recorded time step of a vehicle, or one per vehicle
    needs_map : bool          computed only when a Lanelet2 map is given
    """

    name: str
    unit: str
    low: float
    high: float
    bins: int
    weight: float
    per: str = "step"
    needs_map: bool = False

    def __post_init__(self):
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low < self.high):
            raise ValueError(f"feature {self.name!r}: low={self.low!r}, high={self.high!r}; need finite low < high")
        int_at_least(f"feature {self.name!r}: bins", self.bins, 2)
        number(f"feature {self.name!r}: weight", self.weight, low=0)
        if self.per not in ("step", "vehicle"):
            raise ValueError(f"feature {self.name!r}: per={self.per!r}; allowed: 'step', 'vehicle'")

    @property
    def edges(self) -> np.ndarray:
        """Bin edges, shape (bins + 1,)."""
        return np.linspace(self.low, self.high, self.bins + 1)

    def bin_of(self, values: np.ndarray) -> np.ndarray:
        """Bin index of each value (clipped into the range), shape of ``values``."""
        i = np.floor((np.asarray(values, dtype=float) - self.low) / (self.high - self.low) * self.bins)
        return np.clip(i, 0, self.bins - 1).astype(np.intp)


_NO_GAP = 10.0           # s: the accepted gap of a vehicle that enters with no ring vehicle closing in within _NEAR

#: The features and their default weights. The challenge's weights where a feature corresponds to one of its
#: metrics (speed, acceleration, yaw rate and acceleration 0.05 each; distance to the nearest object 0.10;
#: collision 0.25; time to collision 0.10; lane-centre offset in place of the distance to the road edge 0.10);
#: the roundabout's own features (jerk, gap and time headway to the leader, stopped time, lateral acceleration)
#: 0.05 each. They sum to 1. The entry features (the wait before entering the ring and the time gap accepted there)
#: are scored and drawn for reading, with weight 0 (``score_realism(weights=...)`` gives them one).
FEATURES: tuple[FeatureSpec, ...] = (
    FeatureSpec("speed", "m/s", 0.0, 20.0, 20, 0.05),
    FeatureSpec("acceleration", "m/s^2", -6.0, 6.0, 24, 0.05),
    FeatureSpec("jerk", "m/s^3", -10.0, 10.0, 20, 0.05),
    FeatureSpec("yaw_rate", "rad/s", -1.0, 1.0, 20, 0.05),
    FeatureSpec("yaw_acceleration", "rad/s^2", -2.0, 2.0, 20, 0.05),
    FeatureSpec("lateral_acceleration", "m/s^2", -4.0, 4.0, 16, 0.05),
    FeatureSpec("nearest_distance", "m", 0.0, 30.0, 30, 0.10),
    FeatureSpec("gap", "m", 0.0, 50.0, 25, 0.05),
    FeatureSpec("time_headway", "s", 0.0, 5.0, 25, 0.05),
    FeatureSpec("time_to_collision", "s", 0.0, 5.0, 10, 0.10),
    FeatureSpec("stopped_time", "s", 0.0, 30.0, 15, 0.05, per="vehicle"),
    FeatureSpec("collision", "0/1", 0.0, 1.0, 2, 0.25, per="vehicle"),
    FeatureSpec("lane_offset", "m", 0.0, 3.0, 15, 0.10, needs_map=True),
    FeatureSpec("entry_wait", "s", 0.0, 30.0, 15, 0.0, per="vehicle", needs_map=True),
    FeatureSpec("accepted_gap", "s", 0.0, _NO_GAP, 20, 0.0, per="vehicle", needs_map=True))

_LEADER_RANGE = 50.0     # m: vehicles further ahead are not a leader
_LEADER_LATERAL = 1.8    # m: |lateral offset| in the follower's frame
_LEADER_COS = 0.7        # cos of the largest heading difference (about 45 deg)
_STOPPED = 0.5           # m/s: below this speed a vehicle counts as stopped
_MIN_HEADWAY_SPEED = 1.0  # m/s: time headway only above this speed
_NEAR = 50.0             # m: pairs of vehicles further apart (centres) are neither measured nor leaders
_CLOSING = 0.5           # m/s: a ring vehicle closes in on the entry point at least this fast


@dataclass(frozen=True)
class TrackFeatures:
    """The realism features of one recording or rollout: per feature, one array per vehicle.

    Attributes
    ----------
    values : dict[str, list[numpy.ndarray]]
        Feature name -> per vehicle, its samples (shape (n_steps,) or (1,)); a vehicle without samples of a
        feature (e.g. no leader) has an empty array.
    n_vehicles : int
    duration_s : float
        Sum over vehicles of their tracked time [s].
    overlaps : pandas.DataFrame or None
        Every pair of vehicles whose boxes overlap at some frame, one row each (`OVERLAP_COLUMNS`); the
        ``collision`` feature counts the vehicles in them. None when not computed.
    """

    values: dict[str, list[np.ndarray]]
    n_vehicles: int
    duration_s: float
    overlaps: pd.DataFrame | None = None

    def pooled(self, name: str) -> np.ndarray:
        """All samples of feature ``name``, shape (n,)."""
        if name not in self.values:
            raise KeyError(f"no feature {name!r}; have {sorted(self.values)}")
        parts = self.values[name]
        return np.concatenate(parts) if parts else np.zeros(0)

    @staticmethod
    def combine(parts: Sequence["TrackFeatures"]) -> "TrackFeatures":
        """The features of several recordings together (their vehicles side by side)."""
        if not parts:
            raise ValueError("combine: no TrackFeatures given")
        names = set.intersection(*(set(p.values) for p in parts))
        overlaps = None
        if all(p.overlaps is not None for p in parts):  # the part each came from (track ids repeat across files)
            overlaps = pd.concat([p.overlaps.assign(part=k) for k, p in enumerate(parts)],  # type: ignore[union-attr]
                                 ignore_index=True)
        return TrackFeatures({n: [a for p in parts for a in p.values[n]] for n in sorted(names)},
                             sum(p.n_vehicles for p in parts), float(sum(p.duration_s for p in parts)), overlaps)


def track_features(tracks: pd.DataFrame, lmap=None, *, features: Sequence[FeatureSpec] = FEATURES) -> TrackFeatures:
    """Compute the realism features of a table of tracks.

    Parameters
    ----------
    tracks : pandas.DataFrame
        INTERACTION vehicle columns (`pirl_sim.io.interaction.read_tracks`): ``track_id``, ``frame_id``,
        ``timestamp_ms``, ``x``, ``y`` [m], ``vx``, ``vy`` [m/s], ``length``, ``width`` [m]; ``psi_rad`` [rad]
        if present (else the heading of the velocity).
    lmap : pirl_sim.io.lanelet2_map.LaneletMap, optional   the map, for the map features (``lane_offset``)
    features : sequence of FeatureSpec   which (default `FEATURES`); map features are left out without ``lmap``

    Returns
    -------
    TrackFeatures
    """
    if not isinstance(tracks, pd.DataFrame):
        raise TypeError(f"tracks must be a pandas.DataFrame of INTERACTION columns, got {type(tracks).__name__}")
    need = ("track_id", "frame_id", "timestamp_ms", "x", "y", "vx", "vy", "length", "width")
    if missing := [c for c in need if c not in tracks.columns]:
        raise ValueError(f"tracks lack the columns {missing}; need {list(need)}")
    names = [f.name for f in features if lmap is not None or not f.needs_map]
    unknown = [n for n in names if n not in {f.name for f in FEATURES}]
    if unknown:
        raise ValueError(f"unknown realism features {unknown}; known: {[f.name for f in FEATURES]}")
    df = tracks.sort_values(["track_id", "frame_id"], kind="stable").reset_index(drop=True)
    if len(df) == 0:
        raise ValueError("tracks: the table has no rows")
    for c in ("x", "y", "vx", "vy", "length", "width"):
        if not np.all(np.isfinite(df[c].to_numpy(dtype=float))):
            raise ValueError(f"tracks: column {c!r} has non-finite values")

    t = df["timestamp_ms"].to_numpy(dtype=float) / 1000.0
    xy, v_xy = df[["x", "y"]].to_numpy(dtype=float), df[["vx", "vy"]].to_numpy(dtype=float)
    speed = np.hypot(v_xy[:, 0], v_xy[:, 1])
    psi = df["psi_rad"].to_numpy(dtype=float) if "psi_rad" in df.columns else np.arctan2(v_xy[:, 1], v_xy[:, 0])
    ids = df["track_id"].to_numpy()
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    ends = np.r_[starts[1:], len(df)]

    per_row = {"speed": speed, **{n: np.full(len(df), np.nan) for n in ("acceleration", "jerk", "yaw_rate",
                                                                        "yaw_acceleration", "lateral_acceleration")}}
    stopped, duration = [], 0.0
    for a, b in zip(starts, ends):
        tt = t[a:b]
        if b - a >= 3 and np.all(np.diff(tt) > 0):
            acc, yaw = np.gradient(speed[a:b], tt), np.gradient(np.unwrap(psi[a:b]), tt)
            for name, col in (("acceleration", acc), ("jerk", np.gradient(acc, tt)), ("yaw_rate", yaw),
                              ("yaw_acceleration", np.gradient(yaw, tt)), ("lateral_acceleration", speed[a:b] * yaw)):
                per_row[name][a:b] = col
        dt = np.diff(tt, append=tt[-1] + (tt[-1] - tt[-2] if b - a > 1 else 0.1))
        stopped.append(np.array([np.sum(dt[speed[a:b] < _STOPPED])]))
        duration += float(tt[-1] - tt[0])

    interaction, overlaps = _interaction_rows(df, xy, psi, speed)
    per_row.update(interaction)
    if "lane_offset" in names:
        per_row["lane_offset"] = _lane_offsets(lmap, xy)
    vehicles = {n: np.split(col, starts[1:]) for n, col in per_row.items()}  # each column's rows per vehicle
    per_vehicle = {"stopped_time": stopped, "collision": [np.array([float(c.any())]) for c in vehicles["_collides"]]}
    if {"entry_wait", "accepted_gap"} & set(names):
        per_vehicle.update(_entries(df, t, xy, v_xy, speed, _on_ring(lmap, xy), starts, ends))
    out = {n: per_vehicle[n] if n in per_vehicle else [c[np.isfinite(c)] for c in vehicles[n]] for n in names}
    return TrackFeatures(out, len(starts), duration, overlaps)


def box_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance [m] between pairs of convex quadrilaterals (0 where they overlap).

    Parameters
    ----------
    a, b : numpy.ndarray, shape (P, 4, 2)
        Corners of each pair's boxes, in order around the box.

    Returns
    -------
    numpy.ndarray, shape (P,)
    """
    overlap = np.ones(len(a), dtype=bool)
    for box in (a, b):  # separating axis test: the edge normals of both boxes
        for k in range(2):
            edge = box[:, k + 1] - box[:, k]
            axis = np.stack([-edge[:, 1], edge[:, 0]], axis=-1)
            pa, pb = np.einsum("pkd,pd->pk", a, axis), np.einsum("pkd,pd->pk", b, axis)
            overlap &= (pa.max(1) >= pb.min(1)) & (pb.max(1) >= pa.min(1))
    return np.where(overlap, 0.0, np.minimum(_corner_edge_distance(a, b), _corner_edge_distance(b, a)))


def _corner_edge_distance(points: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Least distance from the corners of ``points`` to the edges of ``box``, both (P, 4, 2): shape (P,)."""
    p0 = box[:, None, :, :]                      # (P, 1, 4, 2) edge starts
    e = np.roll(box, -1, axis=1)[:, None] - p0   # (P, 1, 4, 2) edge vectors
    q = points[:, :, None, :] - p0               # (P, 4, 4, 2)
    u = np.clip(np.sum(q * e, -1) / np.maximum(np.sum(e * e, -1), 1e-12), 0.0, 1.0)
    return np.sqrt(np.sum((q - u[..., None] * e) ** 2, -1)).min(axis=(1, 2))


def _frame_pairs(frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All pairs (i, j), i < j, of rows with the same frame: two int arrays of equal length."""
    order = np.argsort(frames, kind="stable")
    fs, ii, jj = frames[order], [np.zeros(0, dtype=np.intp)], [np.zeros(0, dtype=np.intp)]
    for k in range(1, len(fs)):
        same = fs[k:] == fs[:-k]
        if not same.any():
            break
        ii.append(order[:-k][same])
        jj.append(order[k:][same])
    return np.concatenate(ii), np.concatenate(jj)


def _interaction_rows(df: pd.DataFrame, xy, psi, speed) -> tuple[dict[str, np.ndarray], pd.DataFrame]:
    """Per row: distance to the nearest other box, collision, gap, time headway and time to collision to the
    leader (the nearest vehicle ahead in the same direction within `_LEADER_RANGE`); and the pairs of vehicles whose
    boxes overlap (`OVERLAP_COLUMNS`)."""
    from pirl_sim.viz.vehicles import box_corners

    n, length, width = len(df), df["length"].to_numpy(dtype=float), df["width"].to_numpy(dtype=float)
    i, j = _frame_pairs(df["frame_id"].to_numpy())
    close = np.hypot(*(xy[i] - xy[j]).T) < _NEAR  # centres
    i, j = i[close], j[close]
    corners = np.roll(box_corners(xy[:, 0], xy[:, 1], psi, length, width, nose=False), -2, axis=1)  # front left 1st
    d = np.concatenate([box_distance(corners[i[s]], corners[j[s]])
                        for s in np.array_split(np.arange(len(i)), max(1, len(i) // 50_000))]) if len(i) else np.zeros(0)
    # each pair both ways round, (f, o); the leaders: the others ahead within a lane's width, heading the same way
    f, o, dd = np.concatenate([i, j]), np.concatenate([j, i]), np.concatenate([d, d])
    nearest = np.full(n, np.inf)
    np.minimum.at(nearest, f, dd)
    collides = np.zeros(n, dtype=bool)
    collides[f[dd == 0.0]] = True
    overlaps = _overlap_table(df, xy, psi, speed, i[d == 0.0], j[d == 0.0])
    h, rel = np.stack([np.cos(psi), np.sin(psi)], axis=-1), xy[o] - xy[f]
    lon, lat = np.sum(rel * h[f], -1), rel[:, 1] * h[f, 0] - rel[:, 0] * h[f, 1]
    ok = (lon > 0) & (lon < _LEADER_RANGE) & (np.abs(lat) < _LEADER_LATERAL) & (np.sum(h[f] * h[o], -1) > _LEADER_COS)
    f, o, lon = f[ok], o[ok], lon[ok]
    best = np.full(n, np.inf)
    np.minimum.at(best, f, lon)
    first, leader = lon == best[f], np.full(n, -1)
    leader[f[first]] = o[first]
    gap, headway, ttc = np.full(n, np.nan), np.full(n, np.nan), np.full(n, 5.0)
    fr = np.flatnonzero(leader >= 0)  # the followers and their leaders
    ld = leader[fr]
    g = np.maximum(best[fr] - (length[fr] + length[ld]) / 2.0, 0.0)
    gap[fr] = g
    fast = speed[fr] > _MIN_HEADWAY_SPEED
    headway[fr[fast]] = g[fast] / speed[fr[fast]]
    closing = speed[fr] - speed[ld] * np.sum(h[fr] * h[ld], -1)
    coming = closing > 0.1
    ttc[fr[coming]] = np.minimum(g[coming] / closing[coming], 5.0)
    return {"nearest_distance": np.where(np.isfinite(nearest), nearest, np.nan), "gap": gap,
            "time_headway": headway, "time_to_collision": ttc, "_collides": collides}, overlaps


#: The columns of `TrackFeatures.overlaps`: the two vehicles (``track_a`` < ``track_b``), the first frame their
#: boxes overlap and for how many frames, the midpoint of their centres [m] and their heading difference [deg, 0..180]
#: at that frame, and their speeds then [m/s].
OVERLAP_COLUMNS = ("track_a", "track_b", "frame_id", "frames", "x", "y", "heading_difference_deg", "speed_a",
                   "speed_b")


def _overlap_table(df: pd.DataFrame, xy, psi, speed, i: np.ndarray, j: np.ndarray) -> pd.DataFrame:
    """One row per pair of vehicles among the overlapping rows (i, j) of the same frames (`OVERLAP_COLUMNS`)."""
    ids, frames = df["track_id"].to_numpy(), df["frame_id"].to_numpy()
    swap = ids[i] > ids[j]
    a, b = np.where(swap, j, i), np.where(swap, i, j)
    turn = np.abs((psi[a] - psi[b] + np.pi) % (2.0 * np.pi) - np.pi)
    rows = pd.DataFrame({"track_a": ids[a], "track_b": ids[b], "frame_id": frames[a],
                         "x": 0.5 * (xy[a, 0] + xy[b, 0]), "y": 0.5 * (xy[a, 1] + xy[b, 1]),
                         "heading_difference_deg": np.degrees(turn), "speed_a": speed[a], "speed_b": speed[b]})
    rows = rows.sort_values(["track_a", "track_b", "frame_id"], kind="stable")
    pairs = rows.groupby(["track_a", "track_b"], sort=True)
    out = pairs.first().reset_index()
    out.insert(3, "frames", pairs.size().to_numpy())
    return out[list(OVERLAP_COLUMNS)].reset_index(drop=True)


def _on_ring(lmap, xy: np.ndarray) -> np.ndarray:
    """Bool (n,): each point is nearer to a centre line of the roundabout's ring (the lanelets on a cycle of the
    routing graph) than to any other lanelet's; all False on a map without a roundabout."""
    from pirl_sim.paths import polyline_distances
    from pirl_sim.scenarios.lanelet_graph import ring_lanelets

    ring = ring_lanelets(lmap)
    if not ring:
        return np.zeros(len(xy), dtype=bool)
    others = [c for lid, c in lmap.centerlines.items() if lid not in ring]
    d_ring = polyline_distances([lmap.centerlines[lid] for lid in ring], xy)
    return d_ring < polyline_distances(others, xy) if others else np.ones(len(xy), dtype=bool)


def _entries(df: pd.DataFrame, t, xy, v_xy, speed, on_ring, starts, ends) -> dict[str, list[np.ndarray]]:
    """Per vehicle that drives onto the ring from outside it: ``entry_wait``, its time [s] below the stopped speed
    before its first row on the ring, and ``accepted_gap``, the time [s] in which the nearest ring vehicle closing in
    on that entry position (within 50 m, at 0.5 m/s or faster) would reach it at that frame (`_NO_GAP` when none);
    other vehicles (starting on the ring, never on it) have no sample."""
    frames = df.groupby("frame_id").indices
    frame_ids, ids = df["frame_id"].to_numpy(), df["track_id"].to_numpy()
    wait, gap = [], []
    for a, b in zip(starts, ends):
        ring = on_ring[a:b]
        if ring[0] or not ring.any():
            wait.append(np.zeros(0))
            gap.append(np.zeros(0))
            continue
        k = a + int(np.argmax(ring))
        dt = np.diff(t[a : k + 1])
        wait.append(np.array([float(np.sum(dt[speed[a:k] < _STOPPED]))]))
        rows = frames[frame_ids[k]]
        rows = rows[on_ring[rows] & (ids[rows] != ids[k])]
        rel = xy[k] - xy[rows]  # from each ring vehicle to the entry position
        dist = np.hypot(rel[:, 0], rel[:, 1])
        closing = np.einsum("ij,ij->i", v_xy[rows], rel) / np.maximum(dist, 1e-9)
        near = (dist < _NEAR) & (closing >= _CLOSING)
        gap.append(np.array([min(float(np.min(dist[near] / closing[near])), _NO_GAP) if near.any() else _NO_GAP]))
    return {"entry_wait": wait, "accepted_gap": gap}


def _lane_offsets(lmap, xy: np.ndarray) -> np.ndarray:
    """Distance [m] from each point to the nearest lanelet centre line, shape (n,)."""
    from pirl_sim.paths import polyline_distances

    if not lmap.centerlines:
        raise ValueError(f"map {getattr(lmap, 'path', '')} has no lanelets: lane offsets need centre lines")
    return polyline_distances(lmap.centerlines.values(), xy)


@dataclass(frozen=True)
class RealismScore:
    """The realism of simulated features against recorded ones.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per feature: ``feature``, ``unit``, ``weight`` (normalised over the scored features),
        ``n_reference``, ``n_simulated`` (samples), ``log_likelihood`` (mean log-probability of the recorded
        samples under the simulated histogram), ``likelihood`` (mean over recorded vehicles of
        ``exp(mean log-probability)``, in (0, 1]), ``wasserstein`` (between the two samples, in the feature's
        unit). Features without samples on either side have NaN scores and weight 0.
    meta_metric : float
        Sum of ``weight * likelihood``, in (0, 1]; higher is more realistic.
    """

    table: pd.DataFrame
    meta_metric: float


def score_realism(reference: TrackFeatures, simulated: TrackFeatures, *, features: Sequence[FeatureSpec] = FEATURES,
                  pseudocount: float = 0.1, weights: Mapping[str, float] | None = None) -> RealismScore:
    """Score recorded features under the distribution of simulated ones.

    Parameters
    ----------
    reference, simulated : TrackFeatures   the recording (scored) and the rollouts (their histograms score it)
    features : sequence of FeatureSpec     histogram ranges and default weights (`FEATURES`)
    pseudocount : float                    added to every bin's count before normalising (additive smoothing; the
                                           challenge uses 0.1)
    weights : mapping, optional            feature name -> weight, replacing the defaults of the features named

    Returns
    -------
    RealismScore
    """
    if not isinstance(reference, TrackFeatures) or not isinstance(simulated, TrackFeatures):
        raise TypeError("reference and simulated must be TrackFeatures (see track_features)")
    number("pseudocount", pseudocount, low=0, allow_equal=False)
    specs, weights = {f.name: f for f in features}, dict(weights or {})
    if bad := [k for k in weights if k not in specs]:
        raise ValueError(f"weights name unknown features {bad}; known: {sorted(specs)}")
    for k, w in weights.items():
        number(f"weight of {k!r}", w, low=0)
    from scipy.stats import wasserstein_distance

    rows = []
    for name, spec in specs.items():
        if name not in reference.values or name not in simulated.values:
            continue
        ref_parts, sim = [a for a in reference.values[name] if len(a)], simulated.pooled(name)
        row = {"feature": name, "unit": spec.unit, "weight": float(weights.get(name, spec.weight)),
               "n_reference": int(sum(len(a) for a in ref_parts)), "n_simulated": int(len(sim)),
               "log_likelihood": math.nan, "likelihood": math.nan, "wasserstein": math.nan}
        if ref_parts and len(sim):
            counts = np.bincount(spec.bin_of(sim), minlength=spec.bins).astype(float) + pseudocount
            logp = np.log(counts / counts.sum())
            per_vehicle = [logp[spec.bin_of(a)] for a in ref_parts]
            row.update(log_likelihood=float(np.mean(np.concatenate(per_vehicle))),
                       likelihood=float(np.mean([math.exp(lp.mean()) for lp in per_vehicle])),
                       wasserstein=float(wasserstein_distance(np.clip(np.concatenate(ref_parts), spec.low, spec.high),
                                                              np.clip(sim, spec.low, spec.high))))
        rows.append(row)
    table = pd.DataFrame(rows, columns=["feature", "unit", "weight", "n_reference", "n_simulated",
                                        "log_likelihood", "likelihood", "wasserstein"])
    scored = table["likelihood"].notna()
    table.loc[~scored, "weight"] = 0.0
    total = table["weight"].sum()
    if not scored.any() or total <= 0:
        raise ValueError("no feature has samples on both sides with a positive weight: nothing to score "
                         f"(reference: {reference.n_vehicles} vehicles, simulated: {simulated.n_vehicles})")
    table["weight"] = table["weight"] / total
    return RealismScore(table, float((table["weight"] * table["likelihood"].fillna(0.0)).sum()))


def compare_sources(reference: TrackFeatures, sources: Mapping[str, Iterable[TrackFeatures]], **kwargs
                    ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Score several simulated sources, each over several rollouts (seeds), against one reference.

    Parameters
    ----------
    reference, sources : TrackFeatures, mapping   the recording; label -> its rollouts (one `TrackFeatures` each)
    **kwargs
        Passed to `score_realism`.

    Returns
    -------
    summary : pandas.DataFrame   one row per source: ``source``, ``rollouts``, ``meta_metric`` (mean over rollouts),
                                 ``ci95`` (half-width of its 95 % interval; NaN for one rollout), ``min``, ``max``
    features : pandas.DataFrame   one row per source, rollout and feature: the columns of `RealismScore.table` with
                                  ``source`` and ``rollout``
    """
    from .stats import ci95

    summary, parts = [], []
    for label, rollouts in sources.items():
        scores = [score_realism(reference, feats, **kwargs) for feats in rollouts]
        metas = [s.meta_metric for s in scores]
        parts += [s.table.assign(source=label, rollout=r) for r, s in enumerate(scores)]
        if not metas:
            raise ValueError(f"source {label!r} has no rollouts")
        summary.append({"source": label, "rollouts": len(metas), "meta_metric": float(np.mean(metas)),
                        "ci95": ci95(metas), "min": float(np.min(metas)), "max": float(np.max(metas))})
    if not summary:
        raise ValueError("compare_sources: no sources given")
    features = pd.concat(parts, ignore_index=True)
    cols = ["source", "rollout"] + [c for c in features.columns if c not in ("source", "rollout")]
    return pd.DataFrame(summary), features[cols]


def realism_figure(reference: TrackFeatures, sources: Mapping[str, Sequence[TrackFeatures]], path, *,
                   features: Sequence[FeatureSpec] = FEATURES, reference_label: str = "reference"):
    """Draw each feature's distribution, the reference's filled and each source's (rollouts pooled) as a line,
    on the histogram bins of the score; write it to ``path`` (PNG) and return the figure."""
    from .figures import pyplot, write_png

    specs = [f for f in features if f.name in reference.values]
    if not specs:
        raise ValueError("realism_figure: the reference has none of the features asked for")
    rows, cols = math.ceil(len(specs) / 4), 4
    fig, axes = pyplot().subplots(rows, cols, figsize=(3.2 * cols, 2.4 * rows), squeeze=False)
    pooled = {label: TrackFeatures.combine(list(r)) for label, r in sources.items()}
    for ax, spec in zip(axes.flat, specs):
        drawn = [(reference_label, reference.pooled(spec.name), {"fill": True, "color": "0.75"})]
        drawn += [(label, feats.pooled(spec.name), {"linewidth": 1.4}) for label, feats in pooled.items()
                  if spec.name in feats.values]
        for label, values, style in drawn:
            if len(values):
                ax.stairs(np.bincount(spec.bin_of(values), minlength=spec.bins) / len(values), spec.edges,
                          label=label, **style)
        ax.set_title(f"{spec.name} [{spec.unit}]", fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(specs):]:
        ax.set_visible(False)
    axes.flat[0].legend(fontsize=7)
    fig.tight_layout()
    write_png(path, fig, dpi=100)
    return fig


def overlap_map(overlaps: Mapping[str, pd.DataFrame], path, *, road=None, title: str | None = None):
    """Draw where vehicles overlap: one marker per overlapping pair (`TrackFeatures.overlaps`) at the midpoint of
    their centres when their boxes first overlap, a colour per source, over ``road`` (a `pirl_sim.viz.Road`, e.g.
    `pirl_sim.viz.road_from_lanelet2` of the map); write it to ``path`` (PNG) and return the figure.

    Parameters
    ----------
    overlaps : mapping label -> pandas.DataFrame     with columns ``x`` and ``y`` [m] at least; the legend gives
                                                     each source's number of pairs
    path : path-like                                 the PNG
    road, title : Road or None, str or None          drawn beneath; above the axes

    Raises
    ------
    ValueError
        With neither a road nor a single pair to draw.
    """
    from pirl_sim.viz import distinct_colors, draw_road, new_figure
    from pirl_sim.viz.raster import place_axes
    from pirl_sim.viz.road import road_axes
    from pirl_sim.viz.scene import fit_equal_aspect

    from .figures import write_png

    points = {label: table[["x", "y"]].to_numpy(dtype=float).reshape(-1, 2) for label, table in overlaps.items()}
    every = np.vstack([np.zeros((0, 2)), *points.values()])
    if road is None and not len(every):
        raise ValueError("overlap_map: no road and no overlapping pairs: nothing to draw")
    fig = new_figure()
    ax = road_axes(fig, title=title)
    place_axes(fig, title=bool(title))
    if road is not None:
        draw_road(ax, road)
        x0, y0, x1, y1 = road.bounds
    else:
        (x0, y0), (x1, y1) = every.min(axis=0) - 10.0, every.max(axis=0) + 10.0
    for (label, xy), color in zip(points.items(), distinct_colors(len(points))):
        ax.scatter(xy[:, 0], xy[:, 1], s=14, color=color, alpha=0.75, edgecolors="black", linewidths=0.3, zorder=5,
                   label=f"{label} ({len(xy)} pairs)")
    if points:
        ax.legend(fontsize="small", loc="upper right")
    fit_equal_aspect(ax, (x0, x1, y0, y1))
    write_png(path, fig)
    return fig
