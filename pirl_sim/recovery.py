"""Weight recovery as an API: how close fitted weights come to known ones, per feature, per style and per track.

A :class:`RecoveryReport` holds the true and fitted normalised weights of the free features of ``n`` tracks and
summarises the errors |log(theta_hat / theta)| per feature, over all tracks and per style (median, 90th
percentile and mean with confidence intervals, Spearman's rank correlation). It is built from arrays
(:meth:`RecoveryReport.from_weights`), from trajectories with known weights
(:meth:`RecoveryReport.from_trajectories`) or from a recorded simulator run (:meth:`RecoveryReport.from_run`).
:func:`pirl_sim.testing.assert_recovered` asserts a report within stated tolerances. The same statistics serve
the sweep (:func:`weight_scores`) and ``pirl-sim recover`` (:func:`spearman`).

See the documentation's "Recovery tests" page.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from .trajectory import Trajectory

__all__ = ["RecoveryReport", "TrackFits", "ALL", "NO_STYLE", "INTERVALS", "STATISTICS", "LIKELIHOODS", "abs_log_errors",
           "spearman",
           "statistic", "interval", "weight_scores", "fit_track_weights", "run_demonstrations"]

#: confidence-interval methods: percentile bootstrap, or analytic (order statistics / Student t)
INTERVALS: tuple[str, ...] = ("bootstrap", "analytic")
#: summary statistics of the |log| errors of a group of tracks
STATISTICS: tuple[str, ...] = ("median", "p90", "mean")
#: likelihoods of the per-track fits: the drivers re-plan every step, or one open-loop optimum per track
LIKELIHOODS: tuple[str, ...] = ("receding", "trajectory")
_QUANTILE = {"median": 0.5, "p90": 0.9}
ALL = "all"  #: the group of every track in summaries (not a style name)
NO_STYLE = "(none)"  #: the style of tracks whose style is not known


# ---------------------------------------------------------------------------------------------- statistics
def abs_log_errors(estimated, true) -> np.ndarray:
    """|log(estimated / true)| elementwise, shapes equal, every weight finite and > 0.

    Raises
    ------
    ValueError
        Shapes differ, or a weight is not finite and > 0 (naming how many and the first one).
    """
    est, tru = np.asarray(estimated, dtype=float), np.asarray(true, dtype=float)
    if est.shape != tru.shape:
        raise ValueError(f"estimated weights of shape {est.shape} do not match true weights of shape {tru.shape}")
    for label, a in (("estimated", est), ("true", tru)):
        bad = ~(np.isfinite(a) & (a > 0))
        if bad.any():
            raise ValueError(f"{label} weights must be finite and > 0; {int(bad.sum())} are not "
                             f"(first: {a[bad].flat[0]!r})")
    return np.abs(np.log(est / tru))


def spearman(a, b) -> float:
    """Spearman's rank correlation of ``a`` and ``b`` (1-D, equal length); NaN when fewer than 3 values or
    either is constant."""
    from scipy.stats import spearmanr

    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"spearman needs two 1-D arrays of one length, got shapes {a.shape} and {b.shape}")
    if len(a) < 3 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return math.nan
    return float(spearmanr(a, b).statistic)


def _check_statistic(name: str) -> None:
    if name not in STATISTICS:
        raise ValueError(f"statistic must be one of {STATISTICS}, got {name!r}")


def statistic(values, name: str) -> float:
    """``name`` (:data:`STATISTICS`) of 1-D ``values``; NaN for no values."""
    _check_statistic(name)
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return math.nan
    if name == "mean":
        return float(np.mean(v))
    return float(np.quantile(v, _QUANTILE[name]))


def _check_confidence(confidence) -> float:
    if isinstance(confidence, bool) or not isinstance(confidence, (int, float, np.floating)) \
            or not 0 < confidence < 1:
        raise ValueError(f"confidence must be a number in (0, 1), e.g. 0.95; got {confidence!r}")
    return float(confidence)


def interval(values, name: str, *, method: str = "bootstrap", confidence: float = 0.95, n_boot: int = 2000,
             rng: np.random.Generator | None = None) -> tuple[float, float]:
    """Confidence interval of a statistic of 1-D ``values``.

    Parameters
    ----------
    values : array (n,)
    name : {"median", "p90", "mean"}
    method : {"bootstrap", "analytic"}   percentile bootstrap, or order statistics (quantiles) / t interval (mean)
    confidence : float in (0, 1)
    n_boot : int >= 100                  bootstrap resamples
    rng : numpy.random.Generator         the bootstrap's resampling (required with it)

    Returns
    -------
    (low, high) : floats, NaN with fewer than 2 values
    """
    from scipy import stats

    _check_statistic(name)
    if method not in INTERVALS:
        raise ValueError(f"method must be one of {INTERVALS}, got {method!r}")
    confidence = _check_confidence(confidence)
    v = np.sort(np.asarray(values, dtype=float))
    n = v.size
    alpha = 1.0 - confidence
    if method == "bootstrap":
        if isinstance(n_boot, bool) or not isinstance(n_boot, (int, np.integer)) or n_boot < 100:
            raise ValueError(f"n_boot must be an integer >= 100, got {n_boot!r}")
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"the bootstrap needs rng, a numpy.random.Generator; got {type(rng).__name__}")
    if n < 2:
        return math.nan, math.nan
    if method == "bootstrap":
        samples = v[rng.integers(0, n, size=(int(n_boot), n))]  # type: ignore[union-attr]
        if name == "mean":
            stat = samples.mean(axis=1)
        else:
            stat = np.quantile(samples, _QUANTILE[name], axis=1)
        lo, hi = np.quantile(stat, [alpha / 2, 1 - alpha / 2])
        return float(lo), float(hi)
    if name == "mean":
        half = stats.t.ppf(1 - alpha / 2, n - 1) * np.std(v, ddof=1) / math.sqrt(n)
        m = float(np.mean(v))
        return m - float(half), m + float(half)
    q = _QUANTILE[name]
    lo_rank = int(stats.binom.ppf(alpha / 2, n, q))  # 1-based rank of the lower order statistic
    hi_rank = int(stats.binom.ppf(1 - alpha / 2, n, q)) + 1
    return float(v[min(max(lo_rank, 1), n) - 1]), float(v[min(max(hi_rank, 1), n) - 1])


# ---------------------------------------------------------------------------------------------- sweep scores
def weight_scores(inferred: np.ndarray, true: np.ndarray, styles, model, style_names) -> list[dict]:
    """Weight recovery per free feature, over all rows and per true style (the sweep's ``weights``).

    Parameters
    ----------
    inferred, true : arrays (n, K)     normalised weights (the reference feature's is 1), all features
    styles : int array (n,) or None    style index of each row
    model : DriverModel                names the features and the reference
    style_names : sequence of str      names of the style indices (an index without a name: its number)

    Returns
    -------
    rows : list of dict                one per (feature, style): ``n``, ``median_abs_log_err``, ``p90_abs_log_err``
                                       of |log(inferred / true)|, ``spearman`` (None if constant or n < 3)
    """
    names = list(model.features.names)
    ref = model.features.reference_index
    groups = [("all", np.ones(len(true), dtype=bool))]
    if styles is not None:
        for k in np.unique(styles):
            label = style_names[int(k)] if 0 <= int(k) < len(style_names) else str(int(k))
            groups.append((label, styles == k))
    rows = []
    for j, name in enumerate(names):
        if j == ref:
            continue
        for label, mask in groups:
            est, tru = inferred[mask, j], true[mask, j]
            err = np.abs(np.log(est / tru))
            rho = spearman(tru, est)
            rows.append({"feature": name, "style": label, "n": int(mask.sum()),
                         "median_abs_log_err": _finite(np.median(err)),
                         "p90_abs_log_err": _finite(np.percentile(err, 90)),
                         "spearman": _finite(rho)})
    return rows


def _finite(x):
    x = float(x)
    return x if math.isfinite(x) else None


# ---------------------------------------------------------------------------------------------- per-track fits
@dataclass(frozen=True)
class TrackFits:
    """One weight vector fitted per trajectory (:func:`fit_track_weights`).

    Attributes
    ----------
    normalized : array (n, K)       fitted normalised weights (reference feature = 1)
    converged : bool array (n,)
    at_bound : bool array (n,)      a log weight at its bound
    fitted_steps : int array (n,)   steps scored (receding) or steps of the trajectory (trajectory)
    sigma : array (n,)              [control units] fitted residual scale (receding); NaN (trajectory)
    log_se : array (n, K)           standard errors of the fitted log weights (receding,
                                    `pirl_sim.receding.log_standard_errors`); NaN (trajectory)
    """

    normalized: np.ndarray
    converged: np.ndarray
    at_bound: np.ndarray
    fitted_steps: np.ndarray
    sigma: np.ndarray
    log_se: np.ndarray


def run_demonstrations(run, min_steps: int = 10) -> list:
    """The PIRL tracks of a recorded run with at least ``min_steps`` steps whose control is the driver's own
    (``selection="steps"``, interacting tracks included); ValueError for a bad ``min_steps`` or when none has."""
    from .validation import is_positive_int

    if not is_positive_int(min_steps):
        raise ValueError(f"min_steps must be a positive integer, got {min_steps!r}")
    demos = run.demonstrations(selection="steps", non_interacting=False, min_steps=min_steps)
    if not demos:
        raise ValueError(f"no PIRL track of the run has {min_steps} usable steps")
    return demos


def fit_track_weights(model, trajectories: Sequence[Trajectory], *, likelihood: str = "receding",
                      horizon: int | None = None, stride: int = 1,
                      log_bounds: tuple[float, float] = (-20.0, 20.0)) -> TrackFits:
    """Fit one weight vector to each trajectory.

    Parameters
    ----------
    model : DriverModel
    trajectories : sequence of Trajectory (n)
    likelihood : {"receding", "trajectory"}   `pirl_sim.receding.fit_receding` (``step_mask`` honoured), or
                                   the paper's `pirl_sim.irl.fit_weights` (Gauss-Newton refits where indefinite)
    horizon : int                  [steps], required with ``"receding"``
    stride : int                   ``"receding"``: score every ``stride``-th step
    log_bounds : (low, high)       box on the log normalised weights
    """
    from .irl import attach_gauss_newton, fit_weights
    from .receding import fit_receding
    from .validation import is_positive_int

    if likelihood not in LIKELIHOODS:
        raise ValueError(f"likelihood must be one of {LIKELIHOODS}, got {likelihood!r}")
    if not is_positive_int(stride):
        raise ValueError(f"stride must be a positive integer, got {stride!r}")
    trajectories = model.check(trajectories)
    if not trajectories:
        raise ValueError("no trajectories to fit")
    n = len(trajectories)
    if likelihood == "receding":
        if not is_positive_int(horizon):
            raise ValueError(f"likelihood='receding' needs horizon, a positive number of steps; got {horizon!r}")
        res = fit_receding(model, trajectories, horizon=int(horizon), stride=stride,  # type: ignore[arg-type]
                           log_bounds=log_bounds)
        log_se = res.log_se if res.log_se is not None else np.full(res.normalized.shape, math.nan)
        return TrackFits(res.normalized, res.converged.astype(bool), res.at_bound.any(axis=1),  # type: ignore[arg-type]
                         res.n_steps.astype(np.int64), np.asarray(res.sigma, dtype=float), log_se)
    blocks = attach_gauss_newton(model.laplace_blocks(trajectories), model.features, model.dynamics, trajectories)
    labels = np.arange(n)
    res = fit_weights([b for b, _ in blocks], [labels[idx] for _, idx in blocks],  # type: ignore[assignment]
                      model.features, n_groups=n,
                      log_bounds=log_bounds)
    return TrackFits(res.normalized, res.converged.astype(bool), res.at_bound.any(axis=1),  # type: ignore[arg-type]
                     np.array([t.n_steps for t in trajectories], dtype=np.int64), np.full(n, math.nan),
                     np.full(res.normalized.shape, math.nan))


# ---------------------------------------------------------------------------------------------- the report
def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class RecoveryReport:
    """Fitted vs true weights of n tracks, per feature, over all tracks and per style (arrays: read-only copies).

    Attributes
    ----------
    features : tuple of str (F,)    the free features (the reference feature, weight 1, is left out)
    true, estimated : array (n, F)  true and fitted normalised weights, finite and > 0; errors ``log(estimated / true)``
    track_ids : int array (n,)      unique
    styles : tuple of str (n,)      each track's true style name (`NO_STYLE` when unknown; not "all")
    converged : bool array (n,)     whether each track's fit converged (all True when not known)
    fitted_steps : int array (n,)   steps each fit scored (0 when not known)
    reference, source : str         the reference feature; what the tracks are (e.g. "sumo seed 0")
    method : {"bootstrap", "analytic"}   interval method (`interval`)
    confidence : float              of the intervals, in (0, 1)
    n_boot, seed : int              bootstrap resamples and their seed (same report, same intervals)
    """

    features: tuple[str, ...]
    true: np.ndarray
    estimated: np.ndarray
    track_ids: np.ndarray
    styles: tuple[str, ...]
    converged: np.ndarray | None = None
    fitted_steps: np.ndarray | None = None
    reference: str = "jerk_sq"
    source: str = ""
    method: str = "bootstrap"
    confidence: float = 0.95
    n_boot: int = 2000
    seed: int = 0
    _summary: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if isinstance(self.features, str) or not isinstance(self.features, Sequence) or not self.features \
                or not all(isinstance(f, str) and f for f in self.features):
            raise TypeError(f"features must be a non-empty sequence of feature names, got {self.features!r}")
        if len(set(self.features)) != len(self.features):
            raise ValueError(f"features must be distinct, got {list(self.features)}")
        if self.reference in self.features:
            raise ValueError(f"the reference feature {self.reference!r} (weight 1) cannot be a free feature")
        set_(self, "features", tuple(self.features))
        F = len(self.features)
        true = np.asarray(self.true, dtype=float)
        est = np.asarray(self.estimated, dtype=float)
        if true.ndim != 2 or true.shape[1] != F:
            raise ValueError(f"true must have shape (n, {F}) for features {list(self.features)}, got {true.shape}")
        if true.shape[0] == 0:
            raise ValueError("a recovery report needs at least one track")
        abs_log_errors(est, true)  # shapes and positivity, naming the problem
        n = true.shape[0]
        ids = np.asarray(self.track_ids)
        if ids.shape != (n,) or ids.dtype.kind not in "iu":
            raise ValueError(f"track_ids must be {n} integers, got {self.track_ids!r}")
        if len(np.unique(ids)) != n:
            raise ValueError("track_ids must be unique")
        if isinstance(self.styles, str) or len(self.styles) != n or not all(isinstance(s, str) for s in self.styles):
            raise ValueError(f"styles must be {n} style names (str), one per track")
        if ALL in self.styles:
            raise ValueError(f"the style name {ALL!r} is reserved for the group of all tracks; rename that style")
        conv = np.ones(n, dtype=bool) if self.converged is None else np.asarray(self.converged)
        if conv.shape != (n,) or conv.dtype != bool:
            raise ValueError(f"converged must be {n} booleans, got {self.converged!r}")
        steps = np.zeros(n, dtype=np.int64) if self.fitted_steps is None else np.asarray(self.fitted_steps)
        if steps.shape != (n,) or steps.dtype.kind not in "iu" or (steps < 0).any():
            raise ValueError(f"fitted_steps must be {n} integers >= 0, got {self.fitted_steps!r}")
        if self.method not in INTERVALS:
            raise ValueError(f"method must be one of {INTERVALS}, got {self.method!r}")
        _check_confidence(self.confidence)
        if isinstance(self.n_boot, bool) or not isinstance(self.n_boot, (int, np.integer)) or self.n_boot < 100:
            raise ValueError(f"n_boot must be an integer >= 100, got {self.n_boot!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        set_(self, "true", _readonly(true))
        set_(self, "estimated", _readonly(est))
        set_(self, "track_ids", _readonly(ids.astype(np.int64)))
        set_(self, "styles", tuple(self.styles))
        set_(self, "converged", _readonly(conv))
        set_(self, "fitted_steps", _readonly(steps.astype(np.int64)))

    # -------------------------------------------------------------------------------- constructors
    @classmethod
    def from_weights(cls, true, estimated, *, features: Sequence[str], reference: str = "jerk_sq",
                     styles: Sequence[str] | None = None, track_ids=None, **kwargs) -> "RecoveryReport":
        """A report of given weights: ``true`` and ``estimated`` (n, F) normalised weights of the free
        ``features``; ``styles`` default :data:`NO_STYLE` for every track, ``track_ids`` default 0..n-1; other keywords
        as the dataclass (``source``, ``method``, ...)."""
        true = np.asarray(true, dtype=float)
        n = true.shape[0] if true.ndim == 2 else 0
        return cls(tuple(features), true, estimated, np.arange(n) if track_ids is None else track_ids,
                   tuple([NO_STYLE] * n) if styles is None else tuple(styles), reference=reference, **kwargs)

    @classmethod
    def from_trajectories(cls, model, trajectories: Sequence[Trajectory], *, likelihood: str = "receding",
                          horizon: int | None = None, stride: int = 1, theta=None,
                          log_bounds: tuple[float, float] = (-20.0, 20.0), **kwargs) -> "RecoveryReport":
        """Fit one weight vector per trajectory (:func:`fit_track_weights`) and compare with the truth.

        Parameters
        ----------
        model : DriverModel
        trajectories : sequence of Trajectory (n)
            The truth is ``metadata["theta"]`` (K weights over ``model.features``, normalised here) unless
            ``theta`` is given; styles are ``metadata["style_name"]`` (default :data:`NO_STYLE`), track ids
            ``metadata["track_id"]`` (default the index).
        likelihood, horizon, stride, log_bounds : as :func:`fit_track_weights`
        theta : array (K,) or (n, K), optional
            The true weights (absolute or normalised) of every trajectory, or of each: for a policy whose
            weights are known outside the trajectories.
        **kwargs : ``source``, ``method``, ``confidence``, ``n_boot``, ``seed``
        """
        trajectories = model.check(trajectories)
        if not trajectories:
            raise ValueError("no trajectories to compare")
        names = list(model.features.names)
        ref = model.features.reference_index
        K = len(names)
        if theta is None:
            missing = [i for i, t in enumerate(trajectories) if "theta" not in t.metadata]
            if missing:
                raise ValueError(f"trajectories {missing[:5]} carry no metadata['theta'] (true weights); pass theta")
            truth = np.array([np.asarray(t.metadata["theta"], dtype=float) for t in trajectories])
        else:
            truth = np.broadcast_to(np.asarray(theta, dtype=float), (len(trajectories), K)) \
                if np.ndim(theta) == 1 else np.asarray(theta, dtype=float)
        if truth.shape != (len(trajectories), K):
            raise ValueError(f"true weights must have {K} entries ({', '.join(names)}) per trajectory, got shape "
                             f"{truth.shape}")
        if not np.all(np.isfinite(truth) & (truth > 0)):
            raise ValueError("true weights must be finite and > 0 (background drivers' weights are unknown: leave "
                             "them out)")
        truth = truth / truth[:, [ref]]
        fits = fit_track_weights(model, trajectories, likelihood=likelihood, horizon=horizon, stride=stride,
                                 log_bounds=log_bounds)
        free = [k for k in range(K) if k != ref]
        ids = [t.metadata.get("track_id", i) for i, t in enumerate(trajectories)]
        styles = [str(t.metadata.get("style_name", NO_STYLE)) for t in trajectories]
        return cls(tuple(names[k] for k in free), truth[:, free], fits.normalized[:, free], np.asarray(ids),
                   tuple(styles), fits.converged, fits.fitted_steps, reference=names[ref], **kwargs)

    @classmethod
    def from_run(cls, run, *, min_steps: int = 10, stride: int = 1, horizon: int | None = None,
                 **kwargs) -> "RecoveryReport":
        """The PIRL tracks of a recorded simulator run (:class:`~pirl_sim.scenarios.demonstrations.RecordedRun`,
        e.g. ``load_sumo_run(dir)``): every PIRL track with at least ``min_steps`` steps whose control is the
        driver's own (``selection="steps"``), fitted by the receding-horizon likelihood with the drivers'
        horizon (``horizon`` overrides it: a learner that assumes another one). ``source`` defaults to
        "<simulator> seed <seed>"."""
        demos = run_demonstrations(run, min_steps)
        info = run.recording.info
        kwargs.setdefault("source", f"{info.get('simulator', 'run')} seed {info.get('seed', '?')}")
        return cls.from_trajectories(run.model, demos, likelihood="receding",
                                     horizon=run.horizon if horizon is None else horizon, stride=stride, **kwargs)

    # -------------------------------------------------------------------------------- views
    @property
    def n_tracks(self) -> int:
        return int(self.true.shape[0])

    @property
    def log_errors(self) -> np.ndarray:
        """Signed errors log(estimated / true), (n, F)."""
        return np.log(self.estimated / self.true)

    @property
    def style_names(self) -> tuple[str, ...]:
        """The styles present, sorted."""
        return tuple(sorted(set(self.styles)))

    def groups(self) -> list[tuple[str, np.ndarray]]:
        """("all", every track) then (style, its tracks) per style: (label, bool mask (n,))."""
        styles = np.array(self.styles, dtype=object)
        return [(ALL, np.ones(self.n_tracks, dtype=bool))] + [(s, styles == s) for s in self.style_names]

    def per_track(self) -> pd.DataFrame:
        """One row per track: ``track_id``, ``style``, ``converged``, ``fitted_steps`` and per feature f
        ``theta_f``, ``theta_hat_f``, ``log_err_f``."""
        out = {"track_id": self.track_ids, "style": list(self.styles), "converged": self.converged,
               "fitted_steps": self.fitted_steps}
        err = self.log_errors
        for j, f in enumerate(self.features):
            out[f"theta_{f}"] = self.true[:, j]
            out[f"theta_hat_{f}"] = self.estimated[:, j]
            out[f"log_err_{f}"] = err[:, j]
        return pd.DataFrame(out)

    def summary(self) -> pd.DataFrame:
        """One row per (feature, group), groups "all" then each style: ``feature``, ``style``, ``n``, for each
        statistic s of :data:`STATISTICS` ``s``, ``s_low``, ``s_high`` (its interval) of |log error|, and
        ``spearman`` (true vs fitted). Bootstrap resamples come from ``seed``, one stream per (feature,
        group), so the same report always gives the same table."""
        key = "summary"
        if key not in self._summary:
            abs_err = np.abs(self.log_errors)
            rows = []
            for j, f in enumerate(self.features):
                for g, (label, mask) in enumerate(self.groups()):
                    e = abs_err[mask, j]
                    row: dict[str, Any] = {"feature": f, "style": label, "n": int(mask.sum())}
                    for s, name in enumerate(STATISTICS):
                        rng = np.random.default_rng([int(self.seed), j, g, s])
                        lo, hi = interval(e, name, method=self.method, confidence=self.confidence,
                                          n_boot=int(self.n_boot), rng=rng)
                        row[name], row[f"{name}_low"], row[f"{name}_high"] = statistic(e, name), lo, hi
                    row["spearman"] = spearman(self.true[mask, j], self.estimated[mask, j])
                    rows.append(row)
            self._summary[key] = pd.DataFrame(rows)
        return self._summary[key].copy()

    def value(self, feature: str, statistic_name: str = "median", *, style: str = "all",
              bound: str = "estimate") -> float:
        """One figure of :meth:`summary`: ``bound`` "estimate", "low" or "high" (interval) of a statistic."""
        if feature not in self.features:
            raise ValueError(f"feature must be one of {self.features}, got {feature!r}")
        _check_statistic(statistic_name)
        if style != "all" and style not in self.style_names:
            raise ValueError(f"style must be 'all' or one of {self.style_names}, got {style!r}")
        bounds = {"estimate": "", "low": "_low", "high": "_high"}
        if bound not in bounds:
            raise ValueError(f"bound must be one of {tuple(bounds)}, got {bound!r}")
        s = self.summary()
        row = s[(s["feature"] == feature) & (s["style"] == style)].iloc[0]
        return float(row[statistic_name + bounds[bound]])

    def to_markdown(self, digits: int = 3) -> str:
        """The summary as a Markdown table (statistic with its interval per column)."""
        s = self.summary()
        pct = f"{self.confidence * 100:g} %"

        def fmt(x):
            return "nan" if not math.isfinite(x) else f"{x:.{digits}g}"

        head = ["feature", "style", "n", *[f"{name} [{pct}]" for name in STATISTICS], "spearman"]
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for _, r in s.iterrows():
            cells = [r["feature"], r["style"], str(r["n"])]
            cells += [f"{fmt(r[n])} [{fmt(r[n + '_low'])}, {fmt(r[n + '_high'])}]" for n in STATISTICS]
            cells.append(fmt(r["spearman"]))
            lines.append("| " + " | ".join(cells) + " |")
        return "\n".join(lines) + "\n"

    def __repr__(self) -> str:
        return (f"RecoveryReport({self.source or 'tracks'}: {self.n_tracks} tracks, styles {list(self.style_names)}, "
                f"features {list(self.features)}, {self.method} {self.confidence:g} intervals)")
