"""Figures of the paper, drawn from tables and trajectories (matplotlib, Agg, PNG bytes without a timestamp)."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd

__all__ = ["knn_vs_k", "feature_clusters", "s_t_predictions", "weight_tracking", "pyplot", "png_bytes"]


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def png_bytes(fig) -> bytes:
    """The figure as PNG bytes without a time-stamped metadata field (same data, same bytes); closes it."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    pyplot().close(fig)
    return buf.getvalue()


def knn_vs_k(ktable: pd.DataFrame, title: str) -> bytes:
    """MED of PIRL-kNN against k, one line per protocol (mean, bars: std over test trajectories)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=100)
    for name, g in ktable.groupby("protocol", sort=False):
        ax.errorbar(g["k"], g["med"], yerr=g["med_std"], marker="o", capsize=3, label=name)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("k (neighbours)")
    ax.set_ylabel("MED [m] (mean ± std over test trajectories)")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    return png_bytes(fig)


def feature_clusters(values: np.ndarray, names, labels: np.ndarray, true_styles=None, style_names=None) -> bytes:
    """The paper's Fig. "clustering results": demonstrations in (log) feature space, coloured by cluster.

    values (M, K) raw features; labels (M,) learned clusters; true_styles (M,) optional, drawn as markers.
    """
    plt = pyplot()
    logv = np.log10(np.maximum(values, 1e-12))
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
        ax.set_xlabel(f"log10 {names[i]}")
        ax.set_ylabel(f"log10 {names[j]}")
        ax.grid(True, alpha=0.3)
    handles = [plt.Line2D([], [], color=f"C{c}", marker="o", ls="", label=f"cluster {c}") for c in np.unique(labels)]
    if true_styles is not None:
        for t in np.unique(true_styles):
            label = style_names[int(t)] if style_names is not None else f"style {t}"
            handles.append(plt.Line2D([], [], color="k", marker=markers[int(t) % len(markers)], ls="", label=label))
    axes[0][-1].legend(handles=handles, fontsize=7, loc="best")
    fig.suptitle("Clusters in feature space (colour: learned cluster"
                 + (", marker: true style)" if true_styles is not None else ")"))
    fig.tight_layout()
    return png_bytes(fig)


def s_t_predictions(t: np.ndarray, truth: np.ndarray, predictions: dict, history_steps: int) -> bytes:
    """S-T plot: true arc length vs time for a few tracks, and each learner's prediction after the history.

    t (T,) [s]; truth (n, T) [m]; predictions {learner: (n, T - history_steps) [m]}.
    """
    plt = pyplot()
    n = truth.shape[0]
    fig, axes = plt.subplots(1, n, figsize=(3.3 * n, 3.2), dpi=100, squeeze=False, sharey=False)
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
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 3.4), dpi=100)
    for m in range(inferred.shape[0]):
        ax.plot(t, inferred[m], color="C0", alpha=0.35, lw=1)
    ax.plot(t, np.median(inferred, axis=0), color="C0", lw=2, label="inferred (median over drivers)")
    ax.step(t, true, where="post", color="k", lw=2, label="true")
    ax.axvline(switch_time, color="0.5", ls=":")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(label)
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    ax.set_title("Online inference follows a style switch")
    fig.tight_layout()
    return png_bytes(fig)
