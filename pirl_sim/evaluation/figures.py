"""Figures of the paper, drawn from tables and trajectories (matplotlib, Agg, PNG bytes without a timestamp)."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pandas as pd

from pirl_sim.io.atomic import atomic_write_bytes

__all__ = ["knn_vs_k", "knn_vs_k_figure", "label_log_axis", "legend_below", "nice_below", "nice_above",
           "feature_clusters", "s_t_predictions", "weight_tracking", "pyplot", "png_bytes", "panel_grid",
           "value_ticks", "log_yerr", "series_colors", "write_png"]


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig, **savefig) -> bytes:
    """``fig.savefig`` into PNG bytes (``savefig``: its keywords)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", **savefig)
    return buf.getvalue()


def png_bytes(fig) -> bytes:
    """The figure as PNG bytes without a time-stamped metadata field (same data, same bytes); closes it."""
    data = _png(fig, metadata={"Software": None})
    pyplot().close(fig)
    return data


def write_png(path, fig, **savefig) -> Path:
    """Write the figure ``fig`` (left open) as a PNG to ``path`` atomically (``savefig``: its ``savefig``
    keywords, e.g. ``dpi``); returns the path."""
    return atomic_write_bytes(path, _png(fig, **savefig))


def nice_below(x: float) -> float:
    """The largest number of the form {1, 2, 5} x 10^n that is <= ``x`` (> 0)."""
    e = math.floor(math.log10(x))
    return max((m * 10.0**e for m in (1.0, 2.0, 5.0) if m * 10.0**e <= x * (1 + 1e-12)), default=10.0**e)


def nice_above(x: float) -> float:
    """The smallest number of the form {1, 2, 5} x 10^n that is >= ``x`` (> 0)."""
    e = math.floor(math.log10(x))
    return min((m * 10.0**e for m in (1.0, 2.0, 5.0, 10.0) if m * 10.0**e >= x * (1 - 1e-12)), default=10.0 ** (e + 1))


def label_log_axis(ax, lo: float, hi: float) -> None:
    """Log y axis from a labelled tick at or below ``lo`` to one at or above ``hi`` (both > 0, data units).

    Spans of up to two decades get labelled ticks at 1, 2, 5 x 10^n written as plain numbers (matplotlib's
    default labels only some minor ticks there, and can leave the lowest data without a tick below it); wider
    spans keep decade ticks, with the limits widened to whole decades.
    """
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    if not (lo > 0 and hi >= lo and math.isfinite(hi)):
        raise ValueError(f"log axis limits must satisfy 0 < lo <= hi < inf, got lo={lo!r}, hi={hi!r}")
    narrow = hi / lo <= 100
    bottom = nice_below(lo) if narrow else 10.0 ** math.floor(math.log10(lo))
    top = nice_above(hi) if narrow else 10.0 ** math.ceil(math.log10(hi))
    if top <= bottom:
        top = nice_above(bottom * 1.01)
    ax.set(yscale="log", ylim=(bottom, top))
    if narrow:
        ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
        ax.yaxis.set_minor_formatter(NullFormatter())


def legend_below(fig, handles, labels, *, ncol: int | None = None, fontsize: float = 7, top: float = 0.93):
    """One legend for the whole figure, centred below the panels (outside every axes, so it covers no data).

    Lays the figure out (``tight_layout``) with room for the legend at the bottom and for a suptitle above
    ``top`` (figure fraction). Returns the legend.
    """
    ncol = ncol or min(len(labels), 4) or 1
    legend = fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=fontsize, frameon=False,
                        bbox_to_anchor=(0.5, 0.0))
    fig.canvas.draw()
    height = legend.get_window_extent().height / fig.bbox.height  # figure fraction
    fig.tight_layout(rect=(0.0, min(height + 0.01, 0.6), 1.0, top))
    return legend


def panel_grid(n: int, width: float = 4.6, height: float = 3.4):
    """A figure of ``n`` panels, at most three per row (``width`` x ``height`` inches each), and its ``n`` axes
    in reading order; the grid's unused axes are hidden."""
    ncols = min(3, n)
    nrows = math.ceil(n / ncols)
    fig, axes = pyplot().subplots(nrows, ncols, figsize=(width * ncols, height * nrows), dpi=100, squeeze=False)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    return fig, list(axes.flat[:n])


def value_ticks(ax, values) -> None:
    """A tick labelled with its value at each of ``values`` on a log x axis, and no minor labels."""
    from matplotlib.ticker import FuncFormatter, NullFormatter

    ax.set_xticks(values)
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())


def log_yerr(mean: np.ndarray, err: np.ndarray, floor: float | None) -> list:
    """Error bars [lower, upper] of mean ± err on a log axis, which cannot show mean - err <= 0: such a bar ends
    at ``floor``, the panel's lowest positive value (None: none)."""
    return [np.where(mean - err > 0, err, mean - floor) if floor is not None else err, err]


def series_colors(names) -> dict:
    """One matplotlib colour per series name, in first-seen order, shared by every panel of a figure."""
    return {name: f"C{i % 10}" for i, name in enumerate(dict.fromkeys(names))}


def knn_vs_k_figure(ktable: pd.DataFrame, title: str):
    """The figure of `knn_vs_k` (a matplotlib Figure; close it or pass it to `png_bytes`).

    The per-trajectory MED is skewed (its std often exceeds its mean), so a mean +- std bar would cross zero
    and be cut off on a log axis: the mean (solid, markers) and the std (dashed, same colour) are drawn as two
    positive curves instead, on log-log axes.
    """
    fig, ax = pyplot().subplots(figsize=(6, 3.9), dpi=100)
    handles, values = [], []
    for c, (name, g) in enumerate(ktable.groupby("protocol", sort=False)):
        handles += ax.plot(g["k"], g["med"], marker="o", color=f"C{c}", label=str(name))  # the mean: in the legend
        std = g["med_std"].to_numpy(dtype=float)
        ax.plot(g["k"], np.where(std > 0, std, np.nan), ls="--", color=f"C{c}", lw=1)
        values += [v for v in (*g["med"], *std) if v == v and v > 0]
    ax.set_xscale("log")
    if values:
        label_log_axis(ax, min(values), max(values))
    else:  # pragma: no cover - no positive value to show
        ax.set_yscale("log")
    ax.set(xlabel="k (neighbours of PIRL-kNN)", ylabel="MED [m] over test trajectories\n(solid: mean, dashed: std)",
           title=title)
    ax.grid(True, which="both", alpha=0.3)
    legend_below(fig, handles, [h.get_label() for h in handles], top=1.0)
    return fig


def knn_vs_k(ktable: pd.DataFrame, title: str) -> bytes:
    """MED of PIRL-kNN against k, one colour per protocol: mean (solid) and std (dashed) over test trajectories.

    ktable has columns ``protocol``, ``k``, ``med`` [m], ``med_std`` [m]. Returns PNG bytes.
    """
    return png_bytes(knn_vs_k_figure(ktable, title))


def feature_clusters(values: np.ndarray, names, labels: np.ndarray, true_styles=None, style_names=None) -> bytes:
    """The paper's Fig. "clustering results": demonstrations in (log) feature space, coloured by cluster.

    values (M, K) raw features; labels (M,) learned clusters; true_styles (M,) optional, drawn as markers.
    """
    plt, logv = pyplot(), np.log10(np.maximum(values, 1e-12))
    pairs = [(0, 1), (0, 2), (1, 2)] if values.shape[1] >= 3 else [(0, 1)]
    fig, axes = plt.subplots(1, len(pairs), figsize=(4.2 * len(pairs), 3.8), dpi=100, squeeze=False)
    markers = ["o", "s", "^", "D", "v", "P", "X"]
    for ax, (i, j) in zip(axes[0], pairs):
        for c in np.unique(labels):
            sel = labels == c
            if true_styles is None:
                ax.scatter(logv[sel, i], logv[sel, j], s=10, alpha=0.7, label=f"cluster {c}")
            else:
                for t in np.unique(true_styles[sel]):
                    both = sel & (true_styles == t)
                    ax.scatter(logv[both, i], logv[both, j], s=12, alpha=0.7, color=f"C{c}",
                               marker=markers[int(t) % len(markers)])
        ax.set(xlabel=f"log10 {names[i]}", ylabel=f"log10 {names[j]}")
        ax.grid(True, alpha=0.3)
    handles = [plt.Line2D([], [], color=f"C{c}", marker="o", ls="", label=f"cluster {c}") for c in np.unique(labels)]
    if true_styles is not None:
        handles += [plt.Line2D([], [], color="k", marker=markers[int(t) % len(markers)], ls="",
                               label=style_names[int(t)] if style_names is not None else f"style {t}")
                    for t in np.unique(true_styles)]
    axes[0][-1].legend(handles=handles, fontsize=7, loc="best")
    fig.suptitle("Clusters in feature space (colour: learned cluster"
                 + (", marker: true style)" if true_styles is not None else ")"))
    fig.tight_layout()
    return png_bytes(fig)


def s_t_predictions(t: np.ndarray, truth: np.ndarray, predictions: dict, history_steps: int) -> bytes:
    """S-T plot: true arc length vs time for a few tracks, and each learner's prediction after the history.

    t (T,) [s]; truth (n, T) [m]; predictions {learner: (n, T - history_steps) [m]}.
    """
    n = truth.shape[0]
    fig, axes = pyplot().subplots(1, n, figsize=(3.3 * n, 3.2), dpi=100, squeeze=False, sharey=False)
    for i, ax in enumerate(axes[0]):
        ax.plot(t, truth[i], "k-", lw=2, label="recorded")
        ax.axvline(t[history_steps], color="0.6", ls=":", lw=1)
        for c, (name, pred) in enumerate(predictions.items()):
            ax.plot(t[history_steps:], pred[i], color=f"C{c}", lw=1.2, label=name)
        ax.set_xlabel("T [s]")
        ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel("S [m]")
    axes[0][0].legend(fontsize=7)
    fig.suptitle("S-T: recorded vs predicted after the observed history (dotted line)")
    fig.tight_layout()
    return png_bytes(fig)


def weight_tracking(t: np.ndarray, inferred: np.ndarray, true: np.ndarray, label: str, switch_time: float) -> bytes:
    """Inferred vs true log weight ratio over time for drivers who switch style at ``switch_time`` [s].

    inferred (M, T) and true (T,) values of the plotted quantity.
    """
    fig, ax = pyplot().subplots(figsize=(6, 3.4), dpi=100)
    for m in range(inferred.shape[0]):
        ax.plot(t, inferred[m], color="C0", alpha=0.35, lw=1)
    ax.plot(t, np.median(inferred, axis=0), color="C0", lw=2, label="inferred (median over drivers)")
    ax.step(t, true, where="post", color="k", lw=2, label="true")
    ax.axvline(switch_time, color="0.5", ls=":")
    ax.set(xlabel="time [s]", ylabel=label, title="Online inference follows a style switch")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    return png_bytes(fig)
