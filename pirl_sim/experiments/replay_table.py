"""One table over several recorded roundabouts (``pirl-sim replay --table ROOT``): aggregate figures only.

Per roundabout (`table_row`): each method's MED and displacement error at the last horizon (FDE) as mean and
standard error over the split seeds; the best PIRL learner (lowest mean MED) paired by window against
``CA (path)`` (mean difference and standard error over seeds) and the ratio MED_best / MED_CA; the IRL
convergence of every learner's fit per seed ("converged groups / groups", seeds in order); the share of matched
car tracks usable under each selection rule (`pirl_sim.scenarios.replay.selection_counts`); the paper's
ordering TIRL > PIRL-GMM > PIRL-kNN in MED as measured; the desired-speed parameters per seed; the wall time.
Where the rows have them (`pirl_sim.experiments.replay_report`): the ratio along the path (``med_path``: predictions at
the recorded lateral offsets) and the lateral floor relative to CA (recorded arc lengths under the protocol's
lateral model: the best ratio any prediction along the path could reach); with ``--direct`` the direct
regression's MED relative to CA (`pirl_sim.evaluation.direct`: no cost, what the history and the map tell);
each method's MED on the entry windows (the car has a conflict point to yield at,
`pirl_sim.experiments.recorded.entry_windows`) and on the others.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from pirl_sim.experiments.replay_report import DIRECT, selection_table
from pirl_sim.io.atomic import atomic_write_text

__all__ = ["table_row", "write_table", "table_markdown"]

CA = "CA (path)"  #: the reference of the ratios


def _se(x: pd.Series) -> float:
    return float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")


def table_row(name: str, files: list[str], result: dict, scene, proto, elapsed: float) -> dict:
    """Aggregate figures of one roundabout's replay (module doc)."""
    rows = result["rows"]
    fde = max((c for c in rows.columns if c.startswith("de@")), key=lambda c: float(c[3:-1]))  # the last horizon
    methods: dict[str, dict[str, Any]] = {}
    for m, g in rows.groupby("method", sort=False):
        entry = methods[m] = {"med": float(g["med"].mean()), "med_se": _se(g["med"]),
                              "fde": float(g[fde].mean()), "fde_se": _se(g[fde])}
        if "med_path" in g and g["med_path"].notna().all():
            entry["med_path"] = float(g["med_path"].mean())
        for col in ("med_entry", "med_not_entry"):
            if col in g and g[col].notna().all():
                entry[col], entry[f"{col}_se"] = float(g[col].mean()), _se(g[col])
        if "irl_groups" in g and g["irl_groups"].notna().all():
            entry["converged"] = ", ".join(f"{int(c)}/{int(n)}" for c, n in zip(g["irl_converged"], g["irl_groups"]))
        if "ahead_weight" in g and g["ahead_weight"].notna().all():
            entry["ahead_weight"] = ", ".join(f"{w:g}" for w in g["ahead_weight"])
    pirl = [m for m in methods if m.startswith("PIRL")]
    best = min(pirl, key=lambda m: methods[m]["med"]) if pirl else None
    paired = result["paired_ca"].set_index("method")
    out = {"roundabout": name, "files": files, "seeds": len(proto.seeds), "fde_column": fde, "methods": methods,
           "best": best, "elapsed_s": elapsed, "n_windows": int(rows.groupby("seed")["n_windows"].first().sum())}
    if "n_entry_windows" in rows:
        out["n_entry_windows"] = int(rows.groupby("seed")["n_entry_windows"].first().sum())
    if best is not None and best in paired.index:
        ca, per_seed = methods[CA], rows.pivot(index="seed", columns="method", values="med")
        out.update(best_minus_ca=float(paired.loc[best, "mean_difference"]),
                   best_minus_ca_se=float(paired.loc[best, "standard_error"]),
                   ratio=methods[best]["med"] / ca["med"], ratio_se=_se(per_seed[best] / per_seed[CA]))
        if "med_path" in methods[best] and "med_path" in ca:
            path = rows.pivot(index="seed", columns="method", values="med_path")
            out.update(ratio_path=methods[best]["med_path"] / ca["med_path"], ratio_path_se=_se(path[best] / path[CA]))
        if DIRECT in methods:  # the reference without a cost, on the same scale
            out.update(direct_ratio=methods[DIRECT]["med"] / ca["med"],
                       direct_ratio_se=_se(per_seed[DIRECT] / per_seed[CA]))
        if "lateral_floor" in rows:
            floor = rows.groupby("seed")["lateral_floor"].first()
            out.update(floor_ratio=float(floor.mean()) / ca["med"], floor_ratio_se=_se(floor / per_seed[CA]))
    order = {key: min(v["med"] for m, v in methods.items() if m.startswith(prefix))  # the paper's learners
             for key, prefix in (("TIRL", "TIRL"), ("PIRL-GMM", "PIRL-GMM"), ("PIRL-kNN", "PIRL-kNN ("))
             if any(m.startswith(prefix) for m in methods)}
    out["ordering"] = " > ".join(f"{k} {v:.3f}" for k, v in sorted(order.items(), key=lambda kv: -kv[1]))
    out["paper_ordering_holds"] = (list(order) == ["TIRL", "PIRL-GMM", "PIRL-kNN"]
                                   and order["TIRL"] > order["PIRL-GMM"] > order["PIRL-kNN"])
    out["selection"] = selection_table(scene, proto.history, proto.horizon)
    if "a_lat" in rows:
        g = rows.groupby("seed")[["a_lat", "v_max"]].first()
        out["speed"] = ", ".join(f"{r.a_lat:.2f}/{r.v_max:.2f}" for _, r in g.iterrows())
    return out


def _pm(x: float, se: float) -> str:
    return f"{x:.3f} ± {se:.3f}" if np.isfinite(se) else f"{x:.3f}"


def table_markdown(rows: list[dict]) -> str:
    """The Markdown tables of `write_table`."""
    methods = list(dict.fromkeys(m for r in rows for m in r["methods"]))

    def by_method(names, text) -> list[str]:  # a row per roundabout, a column per method: text(its figures)
        return ["| roundabout | " + " | ".join(names) + " |", "|---|" + "---|" * len(names),
                *(f"| {r['roundabout']} | " + " | ".join(text(r["methods"].get(m, {})) for m in names) + " |"
                  for r in rows)]

    lines = ["MED at the 3 s horizon [m] (FDE at 3 s in brackets), mean ± standard error over split seeds:", "",
             *by_method(methods, lambda v: f"{_pm(v['med'], v['med_se'])} ({_pm(v['fde'], v['fde_se'])})"
                        if v else "")]
    lines += ["", "| roundabout | files | seeds | windows | best PIRL | best − CA (path) [m] | MED_best / MED_CA | "
              "along the path: best / CA | lateral floor / CA | direct regression (no cost) / CA | "
              "ordering (MED, high to low) | paper's TIRL > GMM > kNN | a_lat / v_max per seed | time [s] |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ratios = (_pm(r.get(k, np.nan), r.get(f"{k}_se", np.nan))
                  for k in ("best_minus_ca", "ratio", "ratio_path", "floor_ratio", "direct_ratio"))
        cells = [r["roundabout"], ", ".join(r["files"]), r["seeds"], r["n_windows"], r["best"], *ratios, r["ordering"],
                 "yes" if r["paper_ordering_holds"] else "no", r.get("speed", ""), f"{r['elapsed_s']:.0f}"]
        lines.append("| " + " | ".join(map(str, cells)) + " |")
    if any("n_entry_windows" in r for r in rows):
        lines += ["", "Entry windows (the car has a conflict point to yield at in the window's history or horizon) "
                  "and the other windows: MED [m], mean ± standard error over split seeds:", "",
                  "| roundabout | windows | " + " | ".join(methods) + " |", "|---|---|" + "---|" * len(methods)]
        for r in rows:
            if "n_entry_windows" not in r:
                continue
            for col, label, n in (("med_entry", "entry", r["n_entry_windows"]),
                                  ("med_not_entry", "other", r["n_windows"] - r["n_entry_windows"])):
                cells = [_pm(r["methods"][m][col], r["methods"][m][f"{col}_se"]) if col in r["methods"].get(m, {})
                         else "" for m in methods]
                lines.append(f"| {r['roundabout']} ({label}) | {n} | " + " | ".join(cells) + " |")
    conv_methods = [m for m in methods if any("converged" in r["methods"].get(m, {}) for r in rows)]
    lines += ["", "IRL groups converged / fitted per split seed:", "",
              *by_method(conv_methods, lambda v: v.get("converged", ""))]
    road = [m for m in methods if any("ahead_weight" in r["methods"].get(m, {}) for r in rows)]
    if road:
        lines += ["", "Weight of the road ahead in the look-up, chosen per split seed on held-out training windows:",
                  "", *by_method(road, lambda v: v.get("ahead_weight", ""))]
    lines += ["", "Matched car tracks usable per selection rule (min_steps: a training window = history; "
              "a test window = history + horizon):", "",
              "| roundabout | rule | selection | min_steps | usable / matched | share |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['roundabout']} | {c['rule']} | {c['selection']} | {c['min_steps']} | {c['usable']} / "
              f"{c['matched']} | {c['share']:.0%} |" for r in rows for _, c in r["selection"].iterrows()]
    return "\n".join(lines) + "\n"


def write_table(rows: list[dict], out_dir, command: str) -> str:
    """table.md and table.csv (one row per roundabout and method) in ``out_dir``; returns the Markdown."""
    out, text = Path(out_dir), f"# Replay on recorded roundabouts\n\nMade by `{command}`.\n\n" + table_markdown(rows)
    atomic_write_text(out / "table.md", text)
    flat = [{"roundabout": r["roundabout"], "method": m, **v, "best": m == r["best"], "elapsed_s": r["elapsed_s"]}
            for r in rows for m, v in r["methods"].items()]
    atomic_write_text(out / "table.csv", pd.DataFrame(flat).to_csv(index=False, float_format="%.6g"))
    return text
