"""`pirl-sim report RESULTS`: figures and a Markdown summary drawn from a sweep's tidy table.

`write_sweep_report` writes into the results directory (unless told otherwise) ``med_vs_k.png``
(`med_vs_k_figure`), ``learners.png`` (`learners_side_by_side_figure`), ``recovery.png`` (`recovery_figure`),
``recovery_curves.png`` (`pirl_sim.experiments.recovery_curves`) and ``README.md``: `summary_table` per
experiment, the weight recovery of the sweep's ``weights.csv`` (`weights_summary`) and the online protocol's
scores (`online_view`). The same table gives the same bytes.

The figures and the README's contents are explained in the documentation's "Sweeps" page (the report).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from pirl_sim.io.atomic import atomic_write_bytes, atomic_write_text

from pirl_sim.evaluation.figures import (label_log_axis, legend_below, log_yerr, panel_grid, png_bytes, pyplot,
                                         series_colors, value_ticks)
from pirl_sim.evaluation.stats import ci95
from pirl_sim.evaluation.tables import markdown
from pirl_sim.validation import check_output_dir

from .recovery_curves import _without, curves_markdown, curves_summary, curves_table, recovery_curves_figure

__all__ = ["write_sweep_report", "summary_table", "best_variants", "med_vs_k_figure", "learners_side_by_side_figure",
           "recovery_figure", "weights_summary", "online_view", "ONLINE_MEANS"]



def summary_table(table: pd.DataFrame) -> pd.DataFrame:
    """Mean (and std, 95 % interval half-widths ``*_ci``) over seeds per experiment, scenario variant, protocol
    and learner variant, table order."""
    t = table.assign(learner_base=[_without(x, "k") for x in table["learner_label"]],  # 'PIRL-kNN (k=10)': 'PIRL-kNN'
                     n_styles=table["n_styles"].astype(float), k=table["k"].astype(float))
    return t.groupby(["experiment", "scenario_label", "protocol", "learner_label"], sort=False).agg(
        learner=("learner", "first"), learner_base=("learner_base", "first"), k=("k", "first"),
        med=("med", "mean"), med_sd=("med", "std"), fde=("fde", "mean"), weight_error=("weight_error", "mean"),
        ari=("ari", "mean"), n_styles=("n_styles", "mean"), seeds=("seed", "nunique"), cell_s=("cell_s", "sum"),
        med_ci=("med", ci95), fde_ci=("fde", ci95), weight_error_ci=("weight_error", ci95), ari_ci=("ari", ci95),
        **{c: (c, "mean") for c in ONLINE_MEANS if c in t.columns},
        **{f"{c}_ci": (c, ci95) for c in ONLINE_MEANS if c in t.columns}).reset_index()


#: the online protocol's scores (`pirl_sim.engine.worker.ONLINE_SCORES`) averaged in `summary_table`, with the
#: README's column titles
ONLINE_MEANS = {"style_accuracy": "style accuracy", "style_ari": "style ARI", "min_ade": "minADE_6 [m]",
                "min_fde": "minFDE_6 [m]", "miss_rate": "miss rate", "nll": "NLL [nats/step]"}


def online_view(g: pd.DataFrame) -> pd.DataFrame | None:
    """The README's table of the online protocol's scores for the `summary_table` rows ``g`` of one experiment
    (the rows that have any), or None."""
    cols = [c for c in ONLINE_MEANS if c in g.columns]
    g = g[g[cols].notna().any(axis=1)]  # rows with an online score (none without the columns)
    return None if g.empty else _view(g, {c: ONLINE_MEANS[c] for c in cols})


def _view(g: pd.DataFrame, scores: dict, **extra) -> pd.DataFrame:
    """A README table of the summary rows ``g``: scenario (left out when there is one), protocol, learner, the
    columns ``extra`` and 'mean ± ci' of each of ``scores`` {column of g: title}."""
    view = pd.DataFrame({"scenario": g["scenario_label"], "protocol": g["protocol"], "learner": g["learner_label"],
                         **extra})
    for col, title in scores.items():
        view[title] = [_pm(m, c) for m, c in zip(g[col], g[f"{col}_ci"])]
    return view.drop(columns=["scenario"]) if view["scenario"].nunique() == 1 else view


def weights_summary(weights: pd.DataFrame) -> pd.DataFrame:
    """``weights.csv`` averaged over seeds per experiment, scenario variant, protocol, learner, feature and style:
    means and 95 % interval half-widths (``*_ci``) of the median and 90th-percentile |log error| and Spearman."""
    keys = ["experiment", "scenario_label", "protocol", "learner_label", "feature", "style"]
    return weights.groupby(keys, sort=False).agg(median=("median_abs_log_err", "mean"),
        median_ci=("median_abs_log_err", ci95), p90=("p90_abs_log_err", "mean"), p90_ci=("p90_abs_log_err", ci95),
        spearman=("spearman", "mean"), spearman_ci=("spearman", ci95), seeds=("seed", "nunique")).reset_index()


def _pm(mean, ci) -> str:
    """'mean ± ci' (just the mean without an interval)."""
    m = _fmt(mean)
    return f"{m} ± {ci:.2g}" if m and ci is not None and np.isfinite(ci) else m


def best_variants(summary: pd.DataFrame) -> pd.DataFrame:
    """Per experiment, scenario variant, protocol and learner (k removed): the variant with the lowest MED."""
    idx = summary.groupby(["experiment", "scenario_label", "protocol", "learner_base"], sort=False)["med"].idxmin()
    return summary.loc[idx.dropna().astype(int)].reset_index(drop=True)


# What k counts, per learner (the x axes of med_vs_k.png say it; the tables' column is just "k").
K_MEANING = {"pirl-gmm": "clusters", "pirl-knn": "neighbours"}


def med_vs_k_figure(summary: pd.DataFrame):
    """The figure of `med_vs_k`, or None when no learner ran with several k.

    One panel per scenario variant and learner (so each x axis counts one thing: clusters for PIRL-GMM,
    neighbours for PIRL-kNN), one colour per protocol in every panel, one legend below the panels.
    """
    s = summary[summary["k"].notna()]
    multi = s.groupby(["scenario_label", "learner_base", "protocol"], sort=False)["k"].nunique()
    multi = multi[multi > 1]
    if multi.empty:
        return None
    panels = list(dict.fromkeys((scen, base) for scen, base, _ in multi.index))
    colors = series_colors(proto for _, _, proto in multi.index)
    fig, axes = panel_grid(len(panels))
    for ax, (scen, base) in zip(axes, panels):
        values, panel = [], s[(s["scenario_label"] == scen) & (s["learner_base"] == base)]
        groups = [(proto, panel[panel["protocol"] == proto].sort_values("k"))
                  for sc, lb, proto in multi.index if (sc, lb) == (scen, base)]
        # a log axis cannot show mean - std <= 0: such bars end at the panel's lowest positive value
        floor = min((v for _, g in groups for v in (*g["med"], *(g["med"] - g["med_sd"].fillna(0.0)))
                     if v == v and v > 0), default=None)
        for proto, g in groups:
            several = g["seeds"].max() > 1
            yerr = log_yerr(g["med"].to_numpy(), g["med_sd"].fillna(0.0).to_numpy(), floor) if several else None
            ax.errorbar(g["k"], g["med"], yerr=yerr, marker="o", ms=4, capsize=3, color=colors[proto], label=proto)
            sd = g["med_sd"].fillna(0.0) if several else 0.0
            values += [v for v in (*g["med"], *(g["med"] + sd), *(g["med"] - sd)) if v == v and v > 0]
        ax.set_xscale("log")
        ks = sorted(set(panel["k"]))
        if len(ks) <= 6:  # few k: a labelled tick at each (matplotlib would write 2x10^0 ...)
            value_ticks(ax, ks)
        if values:
            label_log_axis(ax, min(values), max(values))
        what = K_MEANING.get(groups[-1][1]["learner"].iloc[0])
        ax.set(xlabel=f"k ({what} of {base})" if what else f"k ({base})", ylabel="MED [m]")
        ax.set_title(f"{scen}: {base}", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    handles = [pyplot().Line2D([], [], color=c, marker="o", ms=4, label=p) for p, c in colors.items()]
    fig.suptitle("MED vs k (mean over seeds; bars: std over seeds, cut at the panel's lowest value where the "
                 "std exceeds the mean)", fontsize=10)
    legend_below(fig, handles, list(colors))
    return fig


def _variant(scenario_label: str, experiment: str) -> str:
    """'passage population (rationality=20, mix=equal)' -> 'rationality=20, mix=equal'."""
    inside = scenario_label.startswith(experiment + " (") and scenario_label.endswith(")")
    return scenario_label[len(experiment) + 2 : -1] if inside else scenario_label


def _tick(scen: str, proto: str, experiment: str, variants: bool, protocols: bool) -> str:
    """The x tick label of a group of bars: its scenario variant and protocol where the panel has several of them."""
    parts = ([_variant(scen, experiment).replace(", ", "\n")] if variants else []) + ([proto] if protocols else [])
    return "\n".join(p.replace(" (", "\n(") for p in parts) or proto


def _log_floor(values) -> float:
    v = np.asarray([x for x in values if x == x and x > 0], dtype=float)
    return float(v.min() / 2.5) if v.size else 1e-6


def learners_side_by_side_figure(best: pd.DataFrame):
    """``learners.png``: bars of MED per learner (best k; one colour per learner in every panel), one panel per
    experiment, grouped by scenario variant and protocol, the best k written above each bar of a learner run
    with several k, one legend below the panels."""
    experiments = list(dict.fromkeys(best["experiment"]))
    fig, axes = panel_grid(len(experiments), width=5.6)
    colors = series_colors(best["learner_base"])
    for ax, exp in zip(axes, experiments):
        b = best[best["experiment"] == exp]
        groups = list(dict.fromkeys(zip(b["scenario_label"], b["protocol"])))
        several_variants, several_protocols = len({g[0] for g in groups}) > 1, len({g[1] for g in groups}) > 1
        names = list(dict.fromkeys(b["learner_base"]))
        width, at = 0.8 / max(1, len(names)), {g: i for i, g in enumerate(groups)}  # at: a group's place on the x axis
        b = b.assign(at=[at[g] for g in zip(b["scenario_label"], b["protocol"])]).sort_values("at", kind="stable")
        tops = []
        for j, name in enumerate(names):
            r = b[b["learner_base"] == name]  # its bars, in group order
            xs, ys = (r["at"] + (j - (len(names) - 1) / 2) * width).tolist(), r["med"].astype(float).tolist()
            errs = [float(sd) if n > 1 else 0.0 for sd, n in zip(r["med_sd"], r["seeds"])]
            ax.bar(xs, ys, width=width, yerr=errs if any(errs) else None, color=colors[name], label=name, capsize=2)
            for x, y, e, k in zip(xs, ys, errs, r["k"]):
                tops.append(y + e)
                if k == k and k is not None:
                    ax.annotate(f"k={int(k)}", (x, y + e), xytext=(0, 2), textcoords="offset points", ha="center",
                                va="bottom", rotation=90, fontsize=5.5)
        ticks = [_tick(scen, proto, exp, several_variants, several_protocols) for scen, proto in groups]
        ax.set_xticks(range(len(groups)), ticks, fontsize=6)
        floor, positive = _log_floor(b["med"]), [t for t in tops if t == t and t > 0]
        label_log_axis(ax, floor, max(positive) * 3 if positive else floor * 10)  # room for the k labels above
        ax.set_ylabel("MED [m]")
        ax.set_title(exp if several_protocols else f"{exp}, {groups[0][1]}", fontsize=9)
        ax.grid(True, axis="y", which="both", alpha=0.3)
    handles = [pyplot().Rectangle((0, 0), 1, 1, color=c) for c in colors.values()]
    fig.suptitle("Learners side by side (best k where several ran, written above its bar)", fontsize=10)
    legend_below(fig, handles, list(colors), ncol=len(colors))
    return fig


def recovery_figure(recovery: pd.DataFrame, best: pd.DataFrame):
    """True vs inferred normalised weights: one row per experiment (its first scenario variant and protocol),
    one column per learner (best k), one colour per feature in every panel, the legend below the panels.
    Inferred weights beyond a decade outside the true range are drawn at the edge (triangles). None when there
    is nothing to draw."""
    panels = []
    for _, r in recovery.groupby("experiment", sort=False) if recovery is not None else ():
        scen, proto = r["scenario_label"].iloc[0], r["protocol"].iloc[0]
        b = best[(best["scenario_label"] == scen) & (best["protocol"] == proto)]
        if labels := [lab for lab in b["learner_label"] if lab in set(r["learner_label"])]:
            panels.append((scen, proto, labels))
    if not panels:
        return None
    plt = pyplot()
    colors = series_colors(recovery[recovery["scenario_label"].isin({p[0] for p in panels})]["feature"])
    ncols = max(len(p[2]) for p in panels)
    fig, axes = plt.subplots(len(panels), ncols, figsize=(2.9 * ncols, 2.9 * len(panels)), dpi=100, squeeze=False)
    for row, (scen, proto, labels) in enumerate(panels):
        r = recovery[(recovery["scenario_label"] == scen) & (recovery["protocol"] == proto)]
        features = list(dict.fromkeys(r["feature"]))
        true_all = r["true"].to_numpy()
        true_all = true_all[np.isfinite(true_all) & (true_all > 0)]
        lo, hi = (true_all.min() / 10, true_all.max() * 10) if true_all.size else (1e-3, 1e3)
        for ax in axes[row][len(labels):]:
            ax.set_visible(False)
        for col, (ax, label) in enumerate(zip(axes[row], labels)):
            g = r[r["learner_label"] == label]
            for f in features:
                gf = g[g["feature"] == f]
                y = gf["inferred"].to_numpy()
                inside = (y >= lo) & (y <= hi)
                ax.scatter(gf["true"][inside], y[inside], s=6, alpha=0.5, color=colors[f], label=f)
                for sel, edge, marker in ((y < lo, lo, "v"), (y > hi, hi, "^")):
                    if sel.any():
                        ax.scatter(gf["true"][sel], np.full(sel.sum(), edge), s=14, color=colors[f], marker=marker)
            ax.plot([lo, hi], [lo, hi], "k:", lw=1)
            ax.set(xscale="log", yscale="log", xlim=(lo, hi), ylim=(lo / 1.3, hi * 1.3))
            ax.set_title(label, fontsize=8)
            ax.set_xlabel("true weight", fontsize=7)
            ax.set_ylabel(f"{scen}\n{proto}\ninferred weight" if col == 0 else "inferred weight", fontsize=7)
            ax.tick_params(labelsize=6)
            ax.grid(True, which="both", alpha=0.3)
    fig.suptitle("Weight recovery on test histories (normalised weights; dotted: inferred = true; triangles: "
                 "beyond the axes)", fontsize=9)
    handles = [plt.Line2D([], [], color=c, marker="o", ls="", ms=4) for c in colors.values()]
    legend_below(fig, handles, list(colors), ncol=min(len(colors), 6), top=0.95)
    return fig


def _fmt(x) -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return ""
    return f"{x:.3g}" if isinstance(x, (float, np.floating)) else str(x)


def _orderings(best: pd.DataFrame) -> list[str]:
    lines = []
    for (scen, proto), g in best.groupby(["scenario_label", "protocol"], sort=False):
        first = g.drop_duplicates("learner").set_index("learner")  # a learner's first variant
        med, lab = first["med"], first["learner_label"]
        if all(k in med for k in ("tirl", "pirl-gmm", "pirl-knn")):
            ok = med["tirl"] > med["pirl-gmm"] > med["pirl-knn"]
            lines.append(f"- {scen}, {proto}: MED(TIRL) > MED({lab['pirl-gmm']}) > MED({lab['pirl-knn']}) "
                         f"{'holds' if ok else 'does NOT hold'} ({med['tirl']:.3g} / {med['pirl-gmm']:.3g} / "
                         f"{med['pirl-knn']:.3g} m).")
    return lines


#: scenarios whose experiments report weight recovery per feature and style (drivers of known weights)
WEIGHT_SCENARIOS = ("sumo", "highway")
#: the README's caption of each figure, in the README's order
CAPTIONS = {"learners.png": "Learners side by side", "med_vs_k.png": "MED vs k", "recovery.png": "Weight recovery",
            "recovery_curves.png": "Recovery curves"}


def _read(path: Path, read, keys: set | None = None):
    """``read(path)``, None without the file; with ``keys``, only the rows of those cells (column ``key``)."""
    if not path.exists():
        return None
    data = read(path)
    return data if keys is None else data[data["key"].isin(keys)]


def write_sweep_report(table: pd.DataFrame, results, out_dir, *, template: bool = False) -> dict:
    """Draw the figures and write ``README.md`` for a sweep's tidy table (see module doc).

    Parameters
    ----------
    table : DataFrame    the sweep's tidy table (`pirl_sim.engine.run.read_table`)
    results : path       the results directory (or table file) it was read from: ``sweep.json``,
                         ``recovery.parquet`` and ``weights.csv`` beside it are read too
    out_dir : path       where to write
    template : bool      ``results`` is a report template's directory (its cells, no table files)

    Returns
    -------
    dict {name: path} of the files written.
    """
    results = Path(results)
    if table.empty:
        raise ValueError(f"{results}: the table has no finished cell")
    agents = table["scenario"] == "agents"  # episodes, not predictions: pirl_sim.experiments.agents_study reports them
    if agents.all():
        raise ValueError(f"{results}: every cell is of the 'agents' scenario, whose scores are episodes, not "
                         "predictions: `pirl-sim agents` writes their tables")
    n_agents, table = int(agents.sum()), table[~agents].reset_index(drop=True)
    res_dir = results if results.is_dir() else results.parent
    out = check_output_dir(out_dir, "the report's directory")
    manifest = _read(res_dir / "sweep.json", lambda f: json.loads(f.read_text(encoding="utf-8"))) or {}
    recovery = _read(res_dir / "recovery.parquet", pd.read_parquet, set(table["key"]))
    summary = summary_table(table)
    best = best_variants(summary)
    figures = {"med_vs_k.png": med_vs_k_figure(summary), "learners.png": learners_side_by_side_figure(best),
               "recovery.png": recovery_figure(recovery, best),
               "recovery_curves.png": recovery_curves_figure(curves_summary(curves_table(table)))}
    for name in [n for n, fig in figures.items() if fig is None]:  # nothing to draw: no figure left over
        (out / name).unlink(missing_ok=True)
    written = {name: atomic_write_bytes(out / name, png_bytes(fig)) for name, fig in figures.items() if fig is not None}
    lines = [
        f"# Sweep {manifest.get('name', res_dir.name)!r}", "",
        *([manifest["description"], ""] if manifest.get("description") else []),
        f"Made by `{manifest.get('command') or 'pirl-sim sweep'}`, then `pirl-sim report`; every number below is "
        "read from " + (f"the cells stored in {res_dir}/cells/." if template else
                        "`table.parquet` (also `table.csv`) in this directory."), "",
        f"- code version: `{manifest.get('code_version', table['code_version'].iloc[0])}`",
        f"- cells: {len(table)} finished of {manifest.get('n_cells', len(table))} ({table['key'].nunique()} "
        f"distinct computations); seeds: {sorted(int(s) for s in table['seed'].unique())}",
        f"- cell time: {table.drop_duplicates('key')['cell_s'].sum():.0f} s in all (sum over cells, any number "
        "of workers)",
        *([f"- not summarised here: {n_agents} cells of the 'agents' scenario (episodes, not predictions; "
           "`pirl-sim agents` writes their tables)"] if n_agents else []), "",
        "MED [m]: mean over test trajectories of the mean distance between predicted and true positions; FDE [m]: "
        "final displacement; weight error: median |log(inferred / true)| of the normalised weights; ARI: "
        "adjusted Rand index of the training clusters against the true styles. Means over seeds, with several "
        "seeds ± the half-width of the mean's 95 % confidence interval (Student t); every seed's numbers are in "
        + ("its cell's file." if template else "`table.csv`.")
        + " CV / CA: constant velocity / constant acceleration along the path (no weights).", ""]
    weight_experiments = set(table.loc[table["scenario"].isin(WEIGHT_SCENARIOS), "experiment"])
    weights = _read(res_dir / "weights.csv", pd.read_csv, set(table["key"]))
    weights = weights_summary(weights) if weights is not None and len(weights) else None
    for exp, g in summary.groupby("experiment", sort=False):
        lines += [f"## {exp}", ""]
        view = _view(g, {"med": "MED [m]", "fde": "FDE [m]", "weight_error": "weight error", "ari": "ARI"})
        view["styles"] = [_fmt(x) for x in g["n_styles"]]
        view["seeds"] = g["seeds"].to_numpy()
        lines += [markdown(view, _fmt), ""]
        if (online := online_view(g)) is not None:
            lines += ["Online protocol, style posterior and 6 futures per test history (`pirl_sim.engine.worker`): "
                      "style accuracy, the share of test histories whose most probable style given the observed steps "
                      "(p(style | history) from each learned style's likelihood) is their true one, and style ARI, the "
                      "adjusted Rand index of those styles (the ARI column above is of the training clusters); "
                      "minADE_6 / minFDE_6 [m], the smallest mean / final distance of the futures to the true one; "
                      "miss rate (the INTERACTION challenge's rule) and NLL [nats per predicted step] of the true "
                      "future under a Gaussian mixture (sigma 0.5 m) around the futures. TIRL has one future, a "
                      "feature-space mixture at most one per style.", "", markdown(online, _fmt), ""]
        w = None if weights is None else weights[weights["experiment"] == exp]
        if w is not None and len(w) and exp in weight_experiments:
            overall = w[w["style"] == "all"]
            wv = _view(overall, {"median": "median abs log error", "p90": "p90 abs log error", "spearman": "Spearman"},
                       feature=overall["feature"])
            per_style = w[w["style"] != "all"].pivot_table(
                index=["protocol", "learner_label", "feature"], columns="style", values="median", sort=False)
            lines += ["Weight recovery per feature over the test histories (normalised weights, jerk_sq = 1 for the "
                      "simulators): median and 90th percentile of |log(inferred / true)|, Spearman of true vs "
                      "inferred; means over seeds ± 95 % interval (`weights.csv`).", "", markdown(wv, _fmt), ""]
            if len(per_style):
                ps = per_style.reset_index().rename(columns={"learner_label": "learner"})
                lines += ["Median abs log error per true style (mean over seeds):", "", markdown(ps, _fmt), ""]
        if order := _orderings(best[best["experiment"] == exp]):
            lines += ["Orderings (best k of each learner):", "", *order, ""]
    if curves := curves_markdown(table, _fmt):
        lines += ["## Recovery curves", "", "Weight error (median |log(inferred / true)| of the normalised weights "
                  "over the test histories) against the parameter each curve varies; mean over seeds ± 95 % "
                  "interval (`pirl_sim.experiments.recovery_curves`, figure `recovery_curves.png`).", "", *curves]
    lines += ["## Figures", "", *(line for f, caption in CAPTIONS.items() if f in written
                                  for line in (f"![{caption}]({f})", ""))]
    timing = table.drop_duplicates("key").groupby("learner", sort=False)[["fit_s", "evaluate_s", "cell_s"]].sum()
    lines += ["## Time per learner [s] (sums over cells)", "", markdown(timing.reset_index(), _fmt), ""]
    if manifest.get("config"):
        lines += ["## Configuration", "", "```toml", manifest["config"].rstrip(), "```", ""]
    written["README.md"] = atomic_write_text(out / "README.md", "\n".join(lines))
    return written
