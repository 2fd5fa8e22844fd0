"""Recovery curves of a sweep: weight error against the one recovery parameter an experiment varies.

An experiment of a sweep is a recovery curve when its cells differ (beside the seed and the learner) in exactly
one of :data:`CURVE_AXES`: the scenario's number of training tracks (``n_train``; the x value is the cell's
actual training-set size, the table's ``n_train``), the drivers' control noise (``control_noise`` [m/s^3]), the
traffic density as the time between departures (``depart_interval`` [s]), or
the MPC horizon the learner assumes (learner parameter ``horizon`` [steps]; the drivers' own, the scenario's
``horizon``, is marked). :func:`curves_table` gathers the points, :func:`curves_summary` averages them over
seeds (mean and Student-t 95 % half-width), :func:`recovery_curves_figure` draws one panel per curve with one
line per learner, and :func:`curves_markdown` tabulates them; ``pirl-sim report`` writes
``recovery_curves.png`` and a "Recovery curves" section when a sweep has any (e.g.
``pirl_sim/experiments/configs/recovery_curves.toml`` and ``interacting_curves.toml``).
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pandas as pd

__all__ = ["CURVE_AXES", "curves_table", "curves_summary", "recovery_curves_figure", "curves_markdown"]

#: recovery parameters: (where the parameter is, axis label)
CURVE_AXES: dict[str, tuple[str, str]] = {
    "n_train": ("scenario", "training tracks"), "control_noise": ("scenario", "drivers' control noise [m/s^3]"),
    "depart_interval": ("scenario", "time between departures [s]"),
    "horizon": ("learner", "MPC horizon assumed by the learner [steps]")}


def _without(label: str, name: str) -> str:
    """A learner label without ``name=value``: 'TIRL (likelihood=receding, horizon=10)' ->
    'TIRL (likelihood=receding)'."""
    return re.sub(rf"{re.escape(name)}=[^,)]+(, )?", "", label).replace(" ()", "").replace(", )", ")")


def curves_table(table: pd.DataFrame) -> pd.DataFrame:
    """The points of every recovery curve of a sweep's table: one row per cell of an experiment that varies
    exactly one of :data:`CURVE_AXES`, with ``experiment``, ``axis``, ``x``, ``learner`` (label without the
    axis), ``seed``, ``weight_error`` and ``truth`` (the drivers' horizon on a horizon axis, else NaN).
    Cells without a weight error (baselines) are left out; empty when no experiment is a curve."""
    cols, rows = ["experiment", "axis", "x", "learner", "seed", "weight_error", "truth"], []
    for exp, g in table[table["weight_error"].notna()].groupby("experiment", sort=False):
        sp, lp = [json.loads(s) for s in g["scenario_params"]], [json.loads(s) for s in g["learner_params"]]
        axes = [(name, where, [(p if where == "scenario" else q).get(name) for p, q in zip(sp, lp)])
                for name, (where, _) in CURVE_AXES.items()]
        varied = [(name, where, values) for name, where, values in axes if len({json.dumps(v) for v in values}) > 1]
        if len(varied) != 1:
            continue
        name, where, values = varied[0]
        x = g["n_train"].to_numpy(dtype=float) if name == "n_train" else np.asarray(values, dtype=float)
        truth = [float(p.get("horizon", math.nan)) if name == "horizon" else math.nan for p in sp]
        labels = list(g["learner_label"])
        learners = [_without(lab, name) for lab in labels] if where == "learner" else labels
        rows.append(pd.DataFrame({"experiment": exp, "axis": name, "x": x, "learner": learners,
                                  "seed": g["seed"].to_numpy(), "weight_error": g["weight_error"].to_numpy(dtype=float),
                                  "truth": truth}))
    return pd.concat(rows, ignore_index=True)[cols] if rows else pd.DataFrame(columns=cols)


def curves_summary(points: pd.DataFrame) -> pd.DataFrame:
    """Mean weight error over seeds per (experiment, axis, learner, x), its 95 % half-width ``ci`` (Student t;
    NaN with one seed) and ``seeds``, in first-seen order of experiments and learners, x ascending."""
    from pirl_sim.evaluation.stats import ci95

    if points.empty:
        return pd.DataFrame(columns=["experiment", "axis", "learner", "x", "mean", "ci", "seeds", "truth"])
    out = points.groupby(["experiment", "axis", "learner", "x"], sort=False).agg(
        mean=("weight_error", "mean"), ci=("weight_error", ci95), seeds=("seed", "nunique"), truth=("truth", "first"))

    def first_seen(column):  # experiments and learners in first-seen order, x ascending
        return column if column.name == "x" else column.map({v: i for i, v in enumerate(dict.fromkeys(column))})

    return out.reset_index().sort_values(["experiment", "learner", "x"], key=first_seen).reset_index(drop=True)


def recovery_curves_figure(summary: pd.DataFrame):
    """One panel per curve (experiment): mean weight error (median |log(inferred / true)| over the test
    histories) against the axis, one colour per learner in every panel, bars the 95 % interval over seeds (cut
    at the panel's lowest value on the log axis), the drivers' horizon dashed on a horizon axis. None without
    curves."""
    from pirl_sim.evaluation.figures import (label_log_axis, legend_below, log_yerr, panel_grid, pyplot,
                                             series_colors, value_ticks)

    if summary.empty:
        return None
    panels, colors = list(dict.fromkeys(summary["experiment"])), series_colors(summary["learner"])
    fig, axes = panel_grid(len(panels))
    for ax, exp in zip(axes, panels):
        s = summary[summary["experiment"] == exp]
        axis, values = s["axis"].iloc[0], [v for v in s["mean"] if v > 0]
        floor = min(values, default=None)
        for learner, g in s.groupby("learner", sort=False):
            m, ci = g["mean"].to_numpy(), g["ci"].fillna(0.0).to_numpy()
            ax.errorbar(g["x"], m, yerr=np.maximum(log_yerr(m, ci, floor), 0.0), marker="o", ms=4, capsize=3,
                        color=colors[learner], label=learner)
            values += [v for v in m + ci if v > 0]
        if axis == "n_train":
            ax.set_xscale("log")
            value_ticks(ax, sorted(set(s["x"])))
        truth = s["truth"].dropna()
        if len(truth):
            ax.axvline(float(truth.iloc[0]), color="0.4", ls="--", lw=1)
            ax.text(float(truth.iloc[0]), 1.0, " drivers'", transform=ax.get_xaxis_transform(), fontsize=7,
                    va="top", color="0.3")
        if values:  # a margin below the lowest point: it does not sit on the axis
            label_log_axis(ax, 0.8 * min(values), max(values))
        ax.set(xlabel=CURVE_AXES[axis][1], ylabel="weight error (median |log ratio|)")
        ax.set_title(exp, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    handles = [pyplot().Line2D([], [], color=c, marker="o", ms=4) for c in colors.values()]
    fig.suptitle("Recovery curves (mean over seeds; bars: 95 % interval of the mean)", fontsize=10)
    legend_below(fig, handles, list(colors))
    return fig


def curves_markdown(table: pd.DataFrame, fmt) -> list[str]:
    """Markdown lines: per curve, a table of learners (rows) by axis values (columns), 'mean ± ci' each."""
    from pirl_sim.evaluation.tables import markdown

    summary, lines = curves_summary(curves_table(table)), []
    for exp, s in summary.groupby("experiment", sort=False):
        axis = s["axis"].iloc[0]
        cells: dict[str, dict[str, str]] = {}
        for _, r in s.iterrows():
            text = fmt(r["mean"]) + ("" if not np.isfinite(r["ci"]) else f" ± {r['ci']:.2g}")
            cells.setdefault(r["learner"], {})[f"{r['x']:g}"] = text
        view = pd.DataFrame.from_dict(cells, orient="index").reset_index().rename(columns={"index": "learner"})
        lines += [f"**{exp}**: weight error against {CURVE_AXES[axis][1]}"
                  + (f" (drivers' horizon {s['truth'].dropna().iloc[0]:g})" if s["truth"].notna().any() else ""),
                  "", markdown(view, fmt), ""]
    return lines
