"""Lateral offsets of predictions along a reference path: hold the last offset, or follow the driven mean path.

The roundabout model predicts motion *along* a path (s, v, a); where a car is across the path, its lateral
offset d [m], is not modelled by the cost. On recorded roundabouts the lateral part dominates the error in the
plane: cars do not drive on the lane centreline (they cut the circle, swing wide at exits), so holding the last
offset (``"hold"``, the paper's choice) drifts off as the path curves. ``"mean-path"`` predicts the offset
that training tracks of the same route drove at the predicted arc length, keeping the car's own deviation from
it at the start:

    d(t) = dbar(s(t)) + (d_0 - dbar(s_0)),

where ``dbar`` is the median offset of the training tracks in bins of ``bin_width`` metres of arc length,
averaged over a window of ``2 * smooth + 1`` bins (`MeanOffsetProfile`). Where a route has too few training
tracks at s_0 or along the prediction, the offset is held. Both are shared by every path-based predictor
(baselines and learners alike), so that comparisons between them stay about the motion along the path.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["LATERAL_MODELS", "MeanOffsetProfile", "predict_offsets"]

LATERAL_MODELS = ("hold", "mean-path")


@dataclass(frozen=True)
class MeanOffsetProfile:
    """Median lateral offset [m] per route (segment) and arc-length bin, from training tracks.

    Parameters
    ----------
    bin_width : float [m]   arc-length bins
    min_count : int         a bin needs offsets of at least this many samples
    smooth : int            bins on each side averaged into each bin's value (bins without data skipped)
    """

    bin_width: float = 1.0
    min_count: int = 3
    smooth: int = 2
    _table: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not np.isfinite(self.bin_width) or self.bin_width <= 0:
            raise ValueError(f"bin_width must be > 0 m, got {self.bin_width!r}")
        for name in ("min_count", "smooth"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < (1 if name == "min_count" else 0):
                raise ValueError(f"{name} must be a whole number >= {1 if name == 'min_count' else 0}, got {v!r}")

    def fit(self, segment: np.ndarray, s: np.ndarray, d: np.ndarray) -> "MeanOffsetProfile":
        """Fit on samples: route index (n,), composite arc length s (n,) [m], offset d (n,) [m].

        Returns a new fitted profile (this one is not changed)."""
        segment = np.asarray(segment)
        s, d = np.asarray(s, dtype=float), np.asarray(d, dtype=float)
        if not (segment.shape == s.shape == d.shape) or s.ndim != 1:
            raise ValueError(f"segment, s and d must be 1-D of one length, got {segment.shape}, {s.shape}, {d.shape}")
        ok = np.isfinite(s) & np.isfinite(d)
        if not ok.all():
            raise ValueError(f"s and d must be finite; {int((~ok).sum())} of {len(s)} samples are not")
        table: dict[int, dict[int, float]] = {}
        bins = np.floor(s / self.bin_width).astype(np.int64)
        for seg in np.unique(segment):
            on = segment == seg
            b, dd = bins[on], d[on]
            order = np.argsort(b, kind="stable")
            b, dd = b[order], dd[order]
            keys, starts = np.unique(b, return_index=True)
            medians = {int(k): float(np.median(part)) for k, part in zip(keys, np.split(dd, starts[1:]))
                       if len(part) >= self.min_count}
            table[int(seg)] = medians
        out = MeanOffsetProfile(self.bin_width, self.min_count, self.smooth)
        object.__setattr__(out, "_table", table)
        return out

    @property
    def fitted(self) -> bool:
        return bool(self._table)

    def __call__(self, segment: int, s: np.ndarray) -> np.ndarray:
        """dbar at arc lengths s (any shape) [m] on route ``segment``; NaN where no bin within ``smooth`` has
        data."""
        if not self.fitted:
            raise ValueError("MeanOffsetProfile is not fitted: call fit(segment, s, d) first")
        s = np.asarray(s, dtype=float)
        medians = self._table.get(int(segment), {})
        out = np.full(s.shape, np.nan)
        if not medians:
            return out
        b = np.floor(s / self.bin_width).astype(np.int64)
        for idx in np.ndindex(s.shape):
            vals = [medians[k] for k in range(b[idx] - self.smooth, b[idx] + self.smooth + 1) if k in medians]
            if vals:
                out[idx] = float(np.mean(vals))
        return out


def predict_offsets(kind: str, d0: float, segment: int, s0: float, s_pred: np.ndarray,
                    profile: MeanOffsetProfile | None = None) -> np.ndarray:
    """Lateral offsets [m] at the predicted arc lengths ``s_pred`` (H,) of one window (module doc).

    Parameters
    ----------
    kind : {"hold", "mean-path"}
    d0 : float [m]       last observed offset
    segment : int        the track's route
    s0 : float [m]       arc length at the start of the prediction
    s_pred : array (H,)  predicted arc lengths [m]
    profile : fitted MeanOffsetProfile (``"mean-path"``)
    """
    if kind not in LATERAL_MODELS:
        raise ValueError(f"lateral model must be one of {LATERAL_MODELS}, got {kind!r}")
    s_pred = np.asarray(s_pred, dtype=float)
    held = np.full(s_pred.shape, float(d0))
    if kind == "hold":
        return held
    if profile is None:
        raise ValueError("lateral model 'mean-path' needs a fitted MeanOffsetProfile")
    base = profile(segment, np.concatenate([[s0], s_pred.ravel()]))
    if not np.all(np.isfinite(base)):
        return held
    return base[1:].reshape(s_pred.shape) + (float(d0) - base[0])
