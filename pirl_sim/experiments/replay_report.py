"""The replay experiment's report template (``pirl-sim replay`` writes these files).

The experiment itself, what a split seed computes, is the sweep engine's ``recorded`` scenario
(`pirl_sim.experiments.recorded`: windows, baselines, learners, scores; its module doc). ``pirl-sim replay`` runs it
through the engine (`pirl_sim.cli.replay`: cells kept in the output directory, resumable) and gathers the stored
cells into the result dict (`collect_replay`) that the template writes (`write_replay_results`: ``rows.csv``,
``summary.csv/.md``, ``paired.csv``, ``paired_ca.csv``, ``README.md``, ``clusters.png``, ``s_t.png``,
``knn_k.png``, ``scene_gain.png``, ``scene_loss.png`` and ``scenes.json``: `pirl_sim.experiments.replay_scenes`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from pirl_sim.evaluation import figures
from pirl_sim.evaluation.tables import markdown
from pirl_sim.io.atomic import atomic_write_bytes, atomic_write_text
from pirl_sim.scenarios.replay import selection_counts, track_key
from pirl_sim.evaluation.direct import DIRECT
from pirl_sim.experiments.recorded import (  # noqa: F401  (ReplayProtocol, predict_path_states: the replay's names)
    _IRL_WARNINGS, HINDSIGHT, METHODS, ReplayProtocol, _track_keys, predict_path_states, usable_tracks)
from pirl_sim.experiments.replay_scenes import scene_learner, write_replay_scenes

__all__ = ["ReplayProtocol", "collect_replay", "paired_differences", "summarize", "selection_table",
           "write_replay_results", "predict_path_states", "HINDSIGHT", "DIRECT"]


def collect_replay(scene, proto: ReplayProtocol, per_seed: dict, learner_specs=()) -> dict:
    """The replay's result dict from the outputs of `pirl_sim.experiments.recorded.replay_seed` per split seed.

    ``per_seed``: {seed: output}, taken in the order of ``proto.seeds``, then of each output's methods (``pirl-sim
    replay`` rebuilds them from the stored cells); ``gmm_k`` of the cluster figure is the first PIRL-GMM learner's
    ``n_components`` in ``learner_specs`` [(name, key, params)], else 3.

    Returns
    -------
    result : dict
        ``rows`` (tidy DataFrame: seed, method, scores, counts, desired speed, times and, for learners, the IRL's
        diagnostics and, with ground truth, ``ari`` and weight errors), ``paired`` / ``paired_ca`` (differences
        against TIRL / CA (path)), ``errors`` {(seed, method): per-window MED (W,)}, ``selected`` and
        ``selected_pieces``, the S-T figure's ``examples``, ``history``, ``horizon`` and ``gmm_k``.
    """
    tracks = usable_tracks(scene, proto)
    outputs = [(seed, name, m) for seed in proto.seeds for name, m in per_seed[seed]["methods"].items()]
    rows, errors = [m["row"] for _, _, m in outputs], {(seed, name): m["errors"] for seed, name, m in outputs}
    first = per_seed[proto.seeds[0]]
    examples = {**first["examples"], "predictions": {name: m["shown"] for name, m in first["methods"].items()
                                                     if m["shown"] is not None},
                "scenes": {name: m["scene"] for name, m in first["methods"].items() if m.get("scene") is not None}}
    return {"rows": pd.DataFrame(rows), "paired": paired_differences(errors, "TIRL"),
            "paired_ca": paired_differences(errors, "CA (path)"), "errors": errors,
            "selected": len(_track_keys(tracks)[1]), "selected_pieces": len(tracks), "examples": examples,
            "history": proto.history, "horizon": proto.horizon, "seeds": tuple(proto.seeds),
            "learners": tuple(name for name, key, _ in learner_specs if key not in METHODS),
            "gmm_k": next((int(p.get("n_components", 3)) for _, key, p in learner_specs if key == "pirl-gmm"), 3)}


def paired_differences(errors: dict, reference: str) -> pd.DataFrame:
    """MED(method) - MED(reference) paired by window, mean per seed, then mean and standard error over seeds."""
    seeds, methods, rows = sorted({s for s, _ in errors}), sorted({m for _, m in errors if m != reference}), []
    for m in methods:
        if any((s, reference) not in errors for s in seeds):
            continue
        per_seed = np.array([np.mean(errors[(s, m)] - errors[(s, reference)]) for s in seeds])
        rows.append({"method": m, "reference": reference, "mean_difference": float(per_seed.mean()),
                     "standard_error": float(per_seed.std(ddof=1) / np.sqrt(len(seeds)) if len(seeds) > 1 else np.nan),
                     "n_seeds": len(seeds), "better_in_every_seed": bool(np.all(per_seed < 0))})
    return pd.DataFrame(rows)


def summarize(result: dict) -> pd.DataFrame:
    """Mean and standard deviation over seeds of every score, one row per method (sorted by MED); for
    learners also ``irl_converged`` ("converged groups / groups", summed over seeds) and the numbers of IRL
    warnings raised while fitting (summed over seeds)."""
    rows = result["rows"]
    scores = [c for c in rows.columns if c in ("med", "med_path", "med_entry", "med_not_entry", "ari", "weight_error",
                                                "irl_weight_error")
              or c.startswith(("de@", "min_ade@", "min_fde@", "miss_rate@", "nll_per_step@"))]
    agg = rows.groupby("method")[scores].agg(["mean", "std"])
    agg.columns = [f"{a}_{b}" for a, b in agg.columns]
    out = agg.sort_values("med_mean").reset_index()
    if "irl_groups" in rows:
        fits = rows[rows["irl_groups"].notna()].groupby("method")
        totals = fits[["irl_converged", "irl_groups", *_IRL_WARNINGS.values()]].sum().astype(int)
        conv = {m: f"{r.irl_converged} / {r.irl_groups}" for m, r in totals.iterrows()}
        out["irl_converged"] = out["method"].map(conv).fillna("")
        for col in _IRL_WARNINGS.values():
            out[col] = out["method"].map(totals[col]).astype(float)  # NaN (empty) for baselines
    return out


def write_replay_results(result: dict, scene, out_dir, command: str) -> None:
    """rows.csv, summary.csv/.md, paired.csv, paired_ca.csv and README.md (with the selection counts) and the
    figures in ``out_dir``."""
    out, summary = Path(out_dir), summarize(result)
    for name, frame in (("rows", result["rows"]), ("summary", summary), ("paired", result["paired"]),
                        ("paired_ca", result["paired_ca"])):
        atomic_write_text(out / f"{name}.csv", frame.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out / "summary.md", f"# Replay scores\n\nMade by `{command}`. Mean and standard deviation "
                      f"over split seeds; MED and de@ in metres.\n\n{markdown(summary)}\n")
    _write_figures(result, scene, out)
    n_inter = len({track_key(t) for t in scene.trajectories if t.metadata["interacted"]})
    selection = getattr(scene, "selection", "tracks")
    what, pieces = {  # the tracks each selection rule uses, and what it cuts them into
        "free": ("kept as free-flow runs (selection='free', steps with a leader left out, interacting tracks "
                 "included)", "runs"),
        "all": ("every matched track whole, leaders included (selection='all')", "pieces"),
        "steps": ("kept with per-step masks (selection='steps', interacting tracks included)", "pieces"),
    }.get(selection, ("used (not interacting, long enough)", "pieces"))
    used = f"{what}: {result['selected']} (in {result['selected_pieces']} {pieces})" + (
        f"; steps: {getattr(scene, 'steps', {})}" if selection in ("free", "steps") else "")
    knn_k = " ![MED vs k](knn_k.png)" if (out / "knn_k.png").exists() else ""
    lines = [
        "# Replay experiment", "", f"Made by `{command}`.", "",
        f"Tracks read: {scene.n_tracks}; converted: {scene.n_converted} (in {len(scene.trajectories)} pieces); "
        f"flagged as interacting: {n_inter}; {used}. Skipped: {scene.skipped or 'none'}. "
        f"Route-matching repairs: {getattr(scene, 'repairs', None) or 'none'}.", "",
        "Counts of train and test tracks per split are in rows.csv (n_train, n_test; their pieces in "
        "n_train_pieces, n_test_pieces). irl_converged: IRL groups whose Newton iteration converged / all groups, "
        "summed over the split seeds (PIRL-kNN learners that differ only in k share one fit per split).", "",
        *_speed_lines(result), *_selection_lines(scene, result),
        "## Scores (mean and std over split seeds)", "", markdown(summary), "",
        "## Paired differences against TIRL (MED, per window; mean and standard error over seeds)", "",
        markdown(result["paired"]), "", "## Paired differences against CA (path)", "", markdown(result["paired_ca"]),
        "", f"![clusters](clusters.png) ![S-T](s_t.png){knn_k}"]
    if (out / "scene_gain.png").exists():
        lines += ["", f"Where {scene_learner(result)} beats CA (path) most and loses to it most (split seed "
                  f"{result['seeds'][0]}; black: history, dashed: what was recorded):", "",
                  "![gain](scene_gain.png) ![loss](scene_loss.png)"]
    atomic_write_text(out / "README.md", "\n".join(lines) + "\n")


def _speed_lines(result: dict) -> list[str]:
    rows = result["rows"]
    if "a_lat" not in rows or rows["a_lat"].isna().all():
        return []
    per_seed = rows.groupby("seed")[["a_lat", "v_max"]].first()
    seeds = "; ".join(f"seed {s}: {r.a_lat:.2f}, {r.v_max:.2f}" for s, r in per_seed.iterrows())
    return [f"Desired speed (a_lat [m/s^2], v_max [m/s]) per split seed: {seeds}.", ""]


def selection_table(scene, history: int, horizon: int | None = None) -> pd.DataFrame:
    """`pirl_sim.scenarios.replay.selection_counts` for a training window (``min_steps`` = ``history``) and, with a
    ``horizon``, a test window (``history + horizon``)."""
    return pd.concat([selection_counts(scene, n).assign(min_steps=n)
                      for n in (history, history + horizon if horizon else None) if n], ignore_index=True)


def _selection_lines(scene, result: dict) -> list[str]:
    if getattr(scene, "track_table", None) is None:
        return []
    table = selection_table(scene, result["history"], result.get("horizon"))
    return ["## Matched car tracks usable per selection rule", "",
            "usable: tracks with at least one piece the rule keeps of >= min_steps steps (history: a training "
            "window; history + horizon: a test window).", "", markdown(table), ""]


def _write_figures(result: dict, scene, out) -> None:
    """clusters.png (PIRL-GMM with the replay's k, ``result["gmm_k"]``, default 3; the selected pieces; marker:
    true style where a sidecar gives one, background traffic as its own marker), s_t.png (a few predicted
    windows), knn_k.png (when several kNN learners ran)."""
    from pirl_sim.learners import PIRLGMM  # here: tests swap it for a recorder

    tracks, model = scene.selected, scene.model
    labels = PIRLGMM(model, n_components=min(int(result.get("gmm_k", 3)), len(tracks)),
                     random_state=0).cluster_labels(tracks)  # the clusters alone: no IRL for an illustration
    styles = np.array([int(t.metadata.get("style", -1)) for t in tracks])
    names = ({int(s): (f"style {s}" if s >= 0 else "background (no style)") for s in np.unique(styles)}
             if np.any(styles >= 0) else None)  # a sidecar gives styles: background traffic gets a marker too
    atomic_write_bytes(out / "clusters.png", figures.feature_clusters(
        model.feature_values(tracks), model.features.names, labels, styles if names else None, names))
    if ex := result["examples"]:
        h = result["history"]
        preds = {k: np.concatenate([ex["truth"][:, h : h + 1], v], axis=1) for k, v in ex["predictions"].items()}
        atomic_write_bytes(out / "s_t.png", figures.s_t_predictions(ex["t"], ex["truth"], preds, h))
    write_replay_scenes(result, scene, out)
    rows = result["rows"]
    knn = rows[rows["method"].str.startswith("PIRL-kNN (k=")]
    if knn["method"].nunique() > 1:
        per_seed = knn.groupby("method")["med"].agg(["mean", "std"]).reset_index()
        per_seed["k"] = per_seed["method"].str.extract(r"k=(\d+)", expand=False).astype(int)  # "PIRL-kNN (k=K)"
        table = pd.DataFrame({"protocol": "replay (std over seeds)", "k": per_seed["k"],
                              "med": per_seed["mean"], "med_std": per_seed["std"].fillna(0.0)}).sort_values("k")
        atomic_write_bytes(out / "knn_k.png", figures.knn_vs_k(table, "PIRL-kNN on replayed tracks: MED vs k"))

