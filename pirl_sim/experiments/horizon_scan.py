"""Which MPC horizon H explains recorded driving best: held-out receding-horizon likelihood and MED per H.

For each split seed and each H (`scan_seed`), TIRL with the receding-horizon likelihood
(`pirl_sim.receding.fit_receding`) is fitted on the training tracks, the test tracks' residuals are scored under
the training fit's residual model (`pirl_sim.receding.cauchy_nll`) and the same weights predict every test window
closed-loop with that H (MED); per-track weights fitted on each test track's first half score its second half
(``own_nll``). `summarize_scan` and `write_scan` give the table per H. It runs as the engine kind
``horizon-scan`` (`SPEC`), ``pirl-sim replay --scan-horizon``.

The method and its results are explained in the documentation's "Replay of recorded driving" page (horizon
scan).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Sequence

import numpy as np
import pandas as pd

from pirl_sim.experiments.recorded import SPEC as RECORDED
from pirl_sim.experiments.recorded import (
    _errors,
    _replay_settings,
    _windows,
    desired_speed_model,
    load_scene,
    predict_path_states,
    split_by_track,
    start_histories,
    usable_tracks,
)
from pirl_sim.receding import cauchy_nll, cauchy_scale, fit_receding, receding_residuals
from pirl_sim.trajectory import Trajectory
from pirl_sim.validation import is_positive_int
from sklearn.base import BaseEstimator

__all__ = ["scan_seed", "scan_rows", "summarize_scan", "write_scan", "SPEC", "LEARNERS", "HorizonFit"]


def scan_seed(scene, seed: int, horizons: Sequence[int], proto, *, step_stride: int = 1,
              desired_speed=None) -> list[dict]:
    """Fit, score and predict on one split seed for each horizon (module doc).

    Parameters
    ----------
    scene : pirl_sim.scenarios.replay.ReplayScene
    seed : int                          the split seed (by track, as the replay)
    horizons : sequence of int          MPC horizons H [steps of the scene's dt]
    proto : pirl_sim.experiments.recorded.ReplayProtocol   test fraction and prediction windows
    step_stride : int                   score every ``step_stride``-th recorded step in the fit
    desired_speed : None, "fit" or (a_lat, v_max)   the scene's, one fitted on the training tracks, or given

    Returns
    -------
    rows : list of dict                 one per horizon (``horizon``, NLLs, ``sigma``, MEDs, weights, ``fit_s``)
    """
    horizons = [int(h) for h in horizons]
    if not horizons or any(h < 1 for h in horizons):
        raise ValueError(f"horizons must be positive numbers of steps, got {horizons!r}")
    model, speed, _ = desired_speed_model(scene, None if desired_speed == "fit" else desired_speed)
    names = model.features.names
    train, test, counts = split_by_track(usable_tracks(scene, proto), seed, proto.test_fraction)
    if desired_speed == "fit":
        model, speed, _ = desired_speed_model(scene, "fit", train)
    windows = _windows(test, proto)
    if not windows:
        raise ValueError("no test window: tracks are too short for the protocol")
    x0 = np.stack([h.states[-1] for h in start_histories(scene, test, windows, proto)])
    u_train = np.concatenate([t.controls for t in train])
    rows = []
    for H in horizons:
        t0 = time.perf_counter()
        res = fit_receding(model, train, np.zeros(len(train), dtype=int), horizon=H, stride=step_stride)
        fit_s = time.perf_counter() - t0
        theta = res.normalized[0]
        scale = float(cauchy_scale(float(res.sigma[0]), u_train))
        r_train, _ = receding_residuals(model, train, theta, H, stride=step_stride)
        r_test, _ = receding_residuals(model, test, theta, H)
        # per-track weights: each test track fitted on the first half of its steps, scored on the second
        first, second = zip(*(_halves(t) for t in test))
        own = fit_receding(model, list(first), horizon=H, stride=step_stride)
        r_own_fit, _ = receding_residuals(model, list(first), own.normalized, H, stride=step_stride)
        r_own, _ = receding_residuals(model, list(second), own.normalized, H)
        own_scale = float(cauchy_scale(1.4826 * float(np.median(np.abs(r_own_fit))), u_train))
        th = np.broadcast_to(theta, (len(windows), theta.size))
        med = {}
        for rollout in ("closed", "open"):
            s_pred = predict_path_states(model, x0, th, proto.horizon, rollout=rollout, mpc_horizon=H)[:, 1:, 0]
            med[rollout] = float(_errors(model, test, windows, s_pred, proto).mean())
        rows.append({"seed": seed, "horizon": H, "horizon_s": H * model.dynamics.dt,
                     "train_nll": cauchy_nll(r_train, scale), "test_nll": cauchy_nll(r_test, scale),
                     "test_rms": float(np.sqrt(np.mean(r_test**2))), "sigma": float(res.sigma[0]),
                     "own_nll": cauchy_nll(r_own, own_scale), "own_rms": float(np.sqrt(np.mean(r_own**2))),
                     "med": med["closed"], "med_open": med["open"], "converged": bool(res.converged[0]),
                     "n_train_steps": int(r_train.shape[0]), "n_test_steps": int(r_test.shape[0]),
                     "n_windows": len(windows), **counts, **speed, "fit_s": fit_s,
                     **{f"theta_{n}": float(v) for n, v in zip(names, theta)}})
    return rows


LEARNER = "mpc-horizon"  #: the kind's one learner: receding-horizon TIRL with MPC horizon ``horizon``


class HorizonFit(BaseEstimator):
    """The horizon-scan kind's learner (:func:`scan_seed`): TIRL with the receding-horizon likelihood and MPC
    horizon ``horizon`` [steps], every ``step_stride``-th recorded step scored in the fit."""

    name = LEARNER
    scenarios = ("horizon-scan",)

    def __init__(self, horizon: int = 10, step_stride: int = 1, model=None, window=None, windows="first"):
        self.horizon, self.step_stride = horizon, step_stride
        self.model, self.window, self.windows = model, window, windows  # the engine's learner keys, unused here

    def _check_common(self) -> None:
        for name in ("horizon", "step_stride"):
            if not is_positive_int(getattr(self, name)):
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")


#: the learners of this kind, by name (the engine's config reads them through the registry)
LEARNERS = {LEARNER: HorizonFit}


def run_scan_cells(specs: list[dict]) -> list[tuple[dict, dict]]:
    """The cells of one split seed of a recorded scene (`pirl_sim.engine.worker.run_cells` calls it): one
    `scan_seed` row per cell's horizon, stored as the cell's scores (``med``, and under ``scan`` the row's
    [column, value] pairs in order: stored JSON sorts a dict's keys)."""
    proto, desired_speed, _ = _replay_settings(specs[0])
    scene = load_scene(specs[0]["scenario_params"])
    # id(spec) -> its row; one scan per step stride (the command's cells share one)
    rows = {}  # type: ignore[var-annotated]
    for stride in {s["learner_params"]["step_stride"] for s in specs}:
        group = [s for s in specs if s["learner_params"]["step_stride"] == stride]
        horizons = [s["learner_params"]["horizon"] for s in group]
        found = scan_seed(scene, specs[0]["seed"], horizons, proto, step_stride=stride, desired_speed=desired_speed)
        rows.update(zip(map(id, group), found))
    return [({"med": rows[id(s)]["med"], "scan": list(rows[id(s)].items())},
             {"fit_s": rows[id(s)]["fit_s"], "evaluate_s": 0.0}) for s in specs]


def _check_protocol(params: dict, protocol: dict) -> None:
    """The recorded kind's check, without its rollout settings (the scan predicts both ways with each H)."""
    RECORDED.check_protocol(dict(params, replay={k: v for k, v in params["replay"].items()  # type: ignore[misc]
                                                 if k not in ("rollout", "mpc_horizon")}), protocol)


#: the recorded kind's scene and parameters, cells of its own
SPEC = replace(RECORDED, name="horizon-scan", summary="held-out receding-horizon likelihood and MED of recorded "
               "tracks per MPC horizon (module pirl_sim.experiments.horizon_scan)",
               run_cells=run_scan_cells, check_protocol=_check_protocol, learners=(LEARNER,),
               code=("pirl_sim.experiments.horizon_scan",))


def scan_rows(records: list[dict]) -> pd.DataFrame:
    """The scan's rows (`scan_seed`'s, by seed and horizon) from the cells' stored results."""
    rows = pd.DataFrame([dict(r["scan"]) for r in records])
    return rows.sort_values(["seed", "horizon"], kind="stable").reset_index(drop=True)


def _halves(t: Trajectory) -> tuple[Trajectory, Trajectory]:
    """The trajectory twice, its ``step_mask`` keeping the first / the second half of its steps."""
    mask = np.asarray(t.metadata.get("step_mask", np.ones(t.n_steps, dtype=bool)), dtype=bool)
    early = np.arange(t.n_steps) < t.n_steps // 2
    return t.with_metadata(step_mask=mask & early), t.with_metadata(step_mask=mask & ~early)


def summarize_scan(rows: pd.DataFrame) -> pd.DataFrame:
    """Per horizon: mean and standard error over seeds of the scores, and the held-out NLL minus that of the
    best horizon (paired by seed)."""
    seeds = rows["seed"].nunique()
    se = (lambda x: x.std(ddof=1) / np.sqrt(len(x))) if seeds > 1 else (lambda x: np.nan)
    cols = ["own_nll", "own_rms", "test_nll", "train_nll", "test_rms", "med", "med_open"]
    g = rows.groupby("horizon")
    out = g[["horizon_s"]].first()
    for c in cols:
        out[c] = g[c].mean()
        out[f"{c}_se"] = g[c].agg(se)
    for c in ("own_nll", "test_nll"):
        best = out[c].idxmin()
        base = rows[rows["horizon"] == best].set_index("seed")[c]
        diff = rows.assign(d=rows[c].to_numpy() - base.loc[rows["seed"]].to_numpy()).groupby("horizon")["d"]
        out[f"{c}_minus_best"] = diff.mean()
        out[f"{c}_minus_best_se"] = diff.agg(se)
    theta_cols = [c for c in rows.columns if c.startswith("theta_")]
    for c in theta_cols:
        out[c] = g[c].mean()
    out["fit_s"] = g["fit_s"].mean()
    out["n_seeds"] = seeds
    return out.reset_index()


def write_scan(rows: pd.DataFrame, out_dir, command: str) -> pd.DataFrame:
    """horizon_scan_rows.csv, horizon_scan.csv and horizon_scan.md in ``out_dir``; returns the summary."""
    from pathlib import Path

    from pirl_sim.evaluation.tables import markdown
    from pirl_sim.io.atomic import atomic_write_text

    out = Path(out_dir)
    table = summarize_scan(rows)
    atomic_write_text(out / "horizon_scan_rows.csv", rows.to_csv(index=False, float_format="%.6g"))
    atomic_write_text(out / "horizon_scan.csv", table.to_csv(index=False, float_format="%.6g"))
    best = int(table.loc[table["own_nll"].idxmin(), "horizon"])
    best_shared = int(table.loc[table["test_nll"].idxmin(), "horizon"])
    lines = ["# MPC horizon scan", "", f"Made by `{command}`.", "",
             "Per horizon H [steps]: own_nll: per-track weights, each test track's fitted on the first half of "
             "its steps, negative log-likelihood per scored control of the second half [nats] (Cauchy, scale from "
             "the first halves' residuals); test_nll: TIRL (one shared weight vector) with the receding-horizon "
             "likelihood fitted on the training tracks, scored on the test tracks under the training fit's "
             "Cauchy scale; med: MED [m] of closed-loop predictions with the shared weights and H (med_open: one "
             "open-loop plan); means and standard errors (_se) over the split seeds; *_minus_best: paired by "
             "seed against the best H.", "",
             f"Best held-out likelihood at H = {best} (per-track weights), H = {best_shared} (shared weights).",
             "", markdown(table), ""]
    atomic_write_text(out / "horizon_scan.md", "\n".join(lines))
    return table
