"""The learner cell: fit a learner on a kind's training data and score it on its test data by a protocol.

`run_learner_cells` is what the engine's worker (`pirl_sim.engine.worker`) runs for the kinds without a cell
runner of their own (synthetic, passage, SUMO, highway-env). Under the ``online`` protocol every learner that
predicts several futures is also scored on `ONLINE_FUTURES` futures per test history (min ADE/FDE, miss rate,
NLL), and every learner with a style posterior by the accuracy and ARI of its most probable style.
"""

from __future__ import annotations

import json
import os
import socket
import time
import warnings

import numpy as np

from pirl_sim.evaluation.baselines import BASELINES
from pirl_sim.evaluation.protocols import cases, evaluate, style_agreement
from pirl_sim.metrics import adjusted_rand_index, match_styles
from pirl_sim.recovery import weight_scores

__all__ = ["run_learner_cells", "knn_group", "messages", "ONLINE_FUTURES", "ONLINE_SCORES"]

ONLINE_FUTURES = 6  #: K futures per test history under the online protocol (the INTERACTION challenge's number)
#: scores of the online protocol only (module doc); None in the cells of other protocols and learners
ONLINE_SCORES = ("style_accuracy", "style_ari", "k_futures", "min_ade", "min_fde", "miss_rate", "nll")
MAX_RECOVERY_POINTS = 200  #: test histories whose inferred weights are kept for the recovery scatter
MAX_WARNING_MESSAGES = 10


def _recovery(learner, test, protocol, model, style_names=()) -> tuple[dict | None, list | None]:
    """True vs inferred normalised weights of up to `MAX_RECOVERY_POINTS` test histories, and
    `pirl_sim.recovery.weight_scores` over all of them (truth permitting; learners without weights, the baselines,
    give neither)."""
    if not all("theta" in t.metadata for t in test) or isinstance(learner, tuple(BASELINES.values())):
        return None, None
    hist, _, owner = cases(test, protocol)
    inferred = learner.infer_weights(hist)
    true = np.stack([np.asarray(test[i].metadata["theta"], dtype=float) for i in owner])
    styles = (np.array([int(test[i].metadata["style"]) for i in owner])
              if all("style" in t.metadata for t in test) else None)
    scores = weight_scores(inferred, true, styles, model, style_names)
    if len(hist) > MAX_RECOVERY_POINTS:
        pick = np.unique(np.linspace(0, len(hist) - 1, MAX_RECOVERY_POINTS).astype(int))
        inferred, true = inferred[pick], true[pick]
    names = list(model.features.names)
    ref = model.features.reference_index
    keep = [j for j in range(len(names)) if j != ref]
    return {
        "features": [names[j] for j in keep],
        "reference": names[ref],
        "true": true[:, keep].tolist(),
        "inferred": inferred[:, keep].tolist(),
    }, scores


def _style_scores(learner, train, test, protocol) -> dict:
    """Style posterior of the online test histories: ``style_accuracy``, the share of test histories whose most
    probable style (``learner.predict_proba``, p(style | first ``history_steps`` steps)) is their true style,
    learned styles paired with true ones by the training labels (`pirl_sim.metrics.match_styles`: a learned
    style left unpaired is always wrong), and ``style_ari``, the adjusted Rand index of those most probable
    styles against the true styles (no pairing needed). Both None for learners without ``predict_proba`` or
    ``labels_`` and for data without true styles. A feature-space mixture predicts with its feature look-up
    (`pirl_sim.learners.gmm.PIRLGMM.predict_style`), not with this posterior: these scores rate the styles it
    learned, judged by their likelihoods."""
    none = {"style_accuracy": None, "style_ari": None}
    if (protocol.kind != "online" or not hasattr(learner, "predict_proba") or not hasattr(learner, "labels_")
            or not all("style" in t.metadata for t in (*train, *test))):
        return none
    to_true = match_styles(np.array([int(t.metadata["style"]) for t in train]), learner.labels_)
    truth = np.array([int(t.metadata["style"]) for t in test])
    guess = learner.predict_proba([t.window(0, protocol.history_steps) for t in test]).argmax(axis=1)
    paired = np.array([to_true.get(int(j), -1) for j in guess])
    return {"style_accuracy": _float(np.mean(paired == truth)), "style_ari": _float(adjusted_rand_index(truth, guess))}


def messages(caught) -> list[str]:
    """The distinct messages of caught warnings, in order (at most `MAX_WARNING_MESSAGES`)."""
    return list(dict.fromkeys(f"{w.category.__name__}: {w.message}" for w in caught))[:MAX_WARNING_MESSAGES]


def _float(x):
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


def knn_group(spec: dict) -> str | None:
    """What PIRL-kNN cells must share to run together in `run_cells` (their spec without ``n_neighbors``, as
    JSON), or None for a cell of another learner."""
    if spec["learner"] != "pirl-knn" or "n_neighbors" not in spec["learner_params"]:
        return None
    params = {k: v for k, v in spec["learner_params"].items() if k != "n_neighbors"}
    return json.dumps({**spec, "learner_params": params}, sort_keys=True)


def run_learner_cells(specs: list[dict], data, test: list, protocol, generate_s: float, data_warnings: list,
                      t_cell: float, cpu_cell: float, raise_errors: bool = False) -> list[dict]:
    """Fit and score the learner of each cell on ``data`` (`pirl_sim.experiments.spec.ScenarioData`).

    Cells that differ only in PIRL-kNN's ``n_neighbors`` (`knn_group`) share one fit: each later cell takes the
    fitted learner with its own k (`pirl_sim.learners.knn.PIRLKNN.with_neighbors`), which predicts exactly as a
    refit would. ``test`` are the test trajectories long enough for ``protocol``; ``generate_s`` and
    ``data_warnings`` (the data's) are charged to the first cell that finishes; ``t_cell``/``cpu_cell`` are
    when the first cell's clock started.

    Returns
    -------
    list of dict, one per spec: ``scores``, ``timings``, ``recovery``, ``weights``, ``warnings``, ``worker``;
    or ``{"error": "Type: message"}`` (raised instead with ``raise_errors``).
    """
    from pirl_sim.learners import LEARNERS

    results = []
    fitted, fit_warnings = None, []
    charged = False  # the data's generation time and warnings go to the first cell that finishes
    for spec in specs:
        try:
            params = {k: tuple(v) if isinstance(v, list) else v for k, v in spec["learner_params"].items()}
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                t0 = time.perf_counter()
                if fitted is None:
                    learner = {**LEARNERS, **BASELINES}[spec["learner"]](
                        model=data.model, **params, **protocol.learner_params())
                    learner.fit(data.train)
                    shared = []  # type: ignore[var-annotated]
                else:  # the same fit with another k
                    learner = fitted.with_neighbors(params["n_neighbors"])
                    shared = fit_warnings
                fit_s = time.perf_counter() - t0
                if fitted is None and len(specs) > 1:
                    fitted, fit_warnings = learner, list(caught)
                t0 = time.perf_counter()
                futures = ({"n_futures": ONLINE_FUTURES, "random_state": spec["seed"]}
                           if protocol.kind == "online" and hasattr(learner, "predict_futures") else {})
                row = evaluate(learner, test, protocol, **futures)
                row.update(_style_scores(learner, data.train, test, protocol))
                evaluate_s = time.perf_counter() - t0
                ari = style_agreement(learner, data.train)
                recovery, weight_scores = _recovery(learner, test, protocol, data.model, data.style_names)
            caught = [*shared, *caught]
        except Exception as exc:
            if raise_errors:
                raise
            results.append({"error": f"{type(exc).__name__}: {exc}"})
            t_cell, cpu_cell = time.perf_counter(), time.process_time()
            continue
        n_styles = getattr(learner, "n_styles_", 1 if spec["learner"] == "tirl" else None)
        found = messages([*caught, *([] if charged else data_warnings)])
        scores = {
            "med": _float(row["med"]),
            "med_std": _float(row["med_std"]),
            "fde": _float(row["fde"]),
            "weight_error": _float(row.get("weight_error")),
            "ari": _float(ari),
            "n_styles": None if n_styles is None else int(n_styles),
            "n_train": len(data.train),
            "n_test": len(test),
            "n_predictions": int(row.get("n_predictions", len(test))),
            "n_warnings": len(caught),
            **{name: _float(row.get(name)) for name in ONLINE_SCORES},
        }
        if scores["k_futures"] is not None:
            scores["k_futures"] = int(scores["k_futures"])
        results.append({
            "scores": scores,  # type: ignore[dict-item]
            "timings": {"generate_s": 0.0 if charged else generate_s, "fit_s": fit_s,  # type: ignore[dict-item]
                        "evaluate_s": evaluate_s,
                        "cell_s": time.perf_counter() - t_cell, "cpu_s": time.process_time() - cpu_cell},
            "recovery": recovery,  # type: ignore[dict-item]
            "weights": weight_scores,  # type: ignore[dict-item]
            "warnings": found,  # type: ignore[dict-item]
            "worker": {"host": socket.gethostname(), "pid": os.getpid()},  # type: ignore[dict-item]
        })
        charged = True
        t_cell, cpu_cell = time.perf_counter(), time.process_time()  # the next cell's own time
    return results
