"""One evaluation: a fitted learner, test trajectories, a protocol -> a tidy row of scores.

A `Protocol` says what part of a test trajectory a learner sees and what it must predict: ``paper`` (weights from
the whole test trajectory, the whole trajectory predicted from its first state), ``online`` (weights from the
first ``history_steps`` steps, the rest predicted) or ``rolling`` (at every ``stride``-th step, weights from the
last ``history_steps`` steps and the next ``horizon`` steps predicted). `evaluate` scores a learner under one
protocol (MED, FDE and, where the truth is known, the weight error) and, with ``n_futures=K`` (online and
rolling only), K futures per history (`future_scores`: minADE, minFDE, miss rate and NLL of `pirl_sim.metrics`).

The protocols and scores are explained in the documentation's "Protocols and metrics" page.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from pirl_sim.metrics import (
    adjusted_rand_index,
    euclidean_errors,
    interaction_miss,
    min_ade,
    min_fde,
    mixture_nll,
    weight_recovery_error,
)
from pirl_sim.trajectory import Trajectory
from pirl_sim.validation import is_positive_int

__all__ = ["Protocol", "PAPER_PROTOCOL", "evaluate", "future_scores", "cases", "NLL_SIGMA"]

PROTOCOL_KINDS = ("paper", "online", "rolling")
NLL_SIGMA = 0.5  # [m] default standard deviation per step and coordinate of the NLL's Gaussian mixture


@dataclass(frozen=True)
class Protocol:
    """How test trajectories are split into what the learner sees and what it must predict.

    Parameters
    ----------
    kind : {"paper", "online", "rolling"}
    history_steps : int or None
        Steps observed before predicting (``online`` and ``rolling``).
    horizon : int or None
        Predicted steps (``rolling`` only).
    stride : int
        Steps between predictions (``rolling`` only).
    window_mode : {"first", "sliding"}
        Training windows for look-ups under ``online`` (see `pirl_sim.learners.base`): "first" when every
        history starts at the beginning of an episode.
    """

    kind: str = "paper"
    history_steps: int | None = None
    window_mode: str = "first"
    horizon: int | None = None
    stride: int = 1

    def __post_init__(self) -> None:
        if self.kind not in PROTOCOL_KINDS:
            raise ValueError(f"protocol kind must be one of {PROTOCOL_KINDS}, got {self.kind!r}")
        counts = {"online": ("history_steps",), "rolling": ("history_steps", "horizon", "stride")}  # [steps] >= 1
        for name in counts.get(self.kind, ()):
            if not is_positive_int(getattr(self, name)):
                raise ValueError(f"the {self.kind} protocol needs {name} >= 1, got {getattr(self, name)!r}")
        if self.kind == "rolling" and self.window_mode != "sliding":
            raise ValueError("the rolling protocol infers from windows anywhere in a trajectory: window_mode must be 'sliding'")
        if self.kind != "rolling" and self.horizon is not None:
            raise ValueError(f"horizon is only used by the rolling protocol, not {self.kind!r}")
        if self.kind == "paper" and self.history_steps is not None:
            raise ValueError("the paper protocol uses whole trajectories: history_steps must be None")
        if self.window_mode not in ("first", "sliding"):
            raise ValueError(f"window_mode must be 'first' or 'sliding', got {self.window_mode!r}")

    @property
    def name(self) -> str:
        if self.kind == "paper":
            return "paper"
        if self.kind == "online":
            return f"online (history {self.history_steps} steps)"
        return f"rolling (history {self.history_steps}, horizon {self.horizon} steps)"

    def learner_params(self) -> dict:
        """Parameters a learner needs to follow this protocol."""
        if self.kind == "paper":
            return {"window": None}
        return {"window": int(self.history_steps), "windows": self.window_mode}  # type: ignore[arg-type]

    def steps_needed(self) -> int:
        """The shortest test trajectory this protocol can score [steps]."""
        if self.kind == "paper":
            return 1
        if self.kind == "online":
            return self.history_steps + 1  # type: ignore[operator]
        return self.history_steps + self.horizon  # type: ignore[operator]


PAPER_PROTOCOL = Protocol()


def evaluate(learner, test: Sequence[Trajectory], protocol: Protocol, *, n_futures: int | None = None,
             random_state=None, nll_sigma: float = NLL_SIGMA) -> dict:
    """Score a fitted learner on test trajectories ("Protocols and metrics" page).

    Parameters
    ----------
    learner, test, protocol : a fitted learner, sequence of Trajectory, Protocol
    n_futures : int or None       K >= 1: also score K futures per history (online and rolling protocols)
    random_state : None, int or numpy.random.Generator   seed of the learners' draws of futures
    nll_sigma : float             standard deviation [m] per step and coordinate of the NLL's Gaussian mixture

    Returns
    -------
    scores : dict                 ``med``, ``med_std``, ``fde`` [m], ``weight_error``, ``infer_predict_s``, ``n_test``;
                                  with ``n_futures``: ``k_futures``, ``min_ade``, ``min_fde``, ``miss_rate``, ``nll``
    """
    test = list(test)
    if not test:
        raise ValueError("no test trajectories")
    if n_futures is not None:
        if not is_positive_int(n_futures):
            raise ValueError(f"n_futures (K, the number of predicted futures) must be an integer >= 1 or None, "
                             f"got {n_futures!r}")
        if protocol.kind == "paper":
            raise ValueError("multi-modal scores (n_futures) need the online or rolling protocol: the paper "
                             "protocol predicts from the first state after seeing the whole trajectory")
        if isinstance(nll_sigma, bool) or not isinstance(nll_sigma, (int, float, np.integer, np.floating)) \
                or not np.isfinite(nll_sigma) or nll_sigma <= 0:
            raise ValueError(f"nll_sigma must be a finite number of metres > 0, got {nll_sigma!r}")
    histories, futures, owners = cases(test, protocol)
    if not histories:
        raise ValueError(f"no test trajectory is long enough for {protocol.history_steps} history + "
                         f"{protocol.horizon} predicted steps")
    model = learner.model_
    per_case, final = np.empty(len(histories)), np.empty(len(histories))
    inferred = np.empty((len(histories), model.features.n_features))
    lengths = np.array([len(f) for f in futures])
    t0 = time.perf_counter()
    for n in np.unique(lengths):  # one prediction horizon at a time
        idx = np.flatnonzero(lengths == n)
        theta = learner.infer_weights([histories[i] for i in idx])
        truth = np.stack([futures[i] for i in idx])
        pred = model.predict_states(truth[:, 0].copy(), theta, int(n) - 1)
        err = euclidean_errors(model.positions(pred[:, 1:]), model.positions(truth[:, 1:]))
        per_case[idx], final[idx], inferred[idx] = err.mean(axis=1), err[:, -1], theta
    elapsed = time.perf_counter() - t0
    counts = np.bincount(owners)
    per_traj = (np.bincount(owners, per_case) / counts)[counts > 0]  # a trajectory's mean over its predictions
    row = {
        "protocol": protocol.name,
        "n_test": len(test),
        **({"n_predictions": len(histories)} if protocol.kind == "rolling" else {}),
        "med": float(per_traj.mean()),
        "med_std": float(per_traj.std()),
        "fde": float(final.mean()),
        "infer_predict_s": elapsed,
    }
    if all("theta" in t.metadata for t in test):
        true = np.stack([np.asarray(test[i].metadata["theta"], dtype=float) for i in owners])
        row["weight_error"] = float(np.median(weight_recovery_error(inferred, true, model.features.reference_index)))
    if n_futures is not None:
        rng = np.random.default_rng(random_state)
        parts = [future_scores(learner, [histories[i] for i in idx], np.stack([futures[i] for i in idx]), n_futures,
                               rng, nll_sigma) for idx in (np.flatnonzero(lengths == n) for n in np.unique(lengths))]
        row["k_futures"] = max(p["k_futures"] for p in parts)  # each case counts once, whatever its horizon
        row.update({name: float(np.concatenate([p[name] for p in parts]).mean())
                    for name in ("min_ade", "min_fde", "miss_rate", "nll")})
    return row


def future_scores(learner, histories: Sequence[Trajectory], truth_states: np.ndarray, n_futures: int,
                  rng: np.random.Generator, nll_sigma: float = NLL_SIGMA) -> dict:
    """Multi-modal scores of K futures after each history (module doc), per history.

    Parameters
    ----------
    learner : a fitted learner with ``predict_futures``
    histories : sequence of M Trajectory
    truth_states : array (M, H + 1, n_x)   the true states from the last observed one on (row 0)
    n_futures : int                         K asked for
    rng : numpy.random.Generator            the learner's draws
    nll_sigma : float [m]

    Returns
    -------
    scores : dict         ``k_futures`` and (M,) arrays ``min_ade``, ``min_fde`` [m], ``miss_rate``, ``nll`` [nats/step]
    """
    model = learner.model_
    H = truth_states.shape[1] - 1
    states, proba = learner.predict_futures(list(histories), H, n_futures=n_futures, random_state=rng)
    pred = model.positions(states[:, :, 1:])  # (M, K, H, P)
    true_pos = model.positions(truth_states)  # (M, H + 1, P)
    truth = true_pos[:, 1:]
    step = true_pos[:, -1] - true_pos[:, -2]  # the true motion over the last step
    speed = np.linalg.norm(step, axis=-1) / model.dynamics.dt
    heading = None
    if step.shape[-1] == 2:  # the true heading at the last step: the path's tangent there for a path model
        path = getattr(model, "path", None)
        heading = (np.arctan2(step[:, 1], step[:, 0]) if path is None
                   else path.heading_at(truth_states[:, -1, 0], extrapolate=True))
    return {
        "k_futures": int(proba.shape[1]),
        "min_ade": min_ade(pred, truth),
        "min_fde": min_fde(pred, truth),
        "miss_rate": interaction_miss(pred, truth, speed, heading).astype(float),
        "nll": mixture_nll(pred, proba, truth, float(nll_sigma)) / H,
    }


def cases(test: Sequence[Trajectory], protocol: Protocol):
    """Every prediction of the protocol (module doc): its history (paper: the whole test trajectory), its true
    future (the states from the last observed one on; paper: from the first) and the index of its test
    trajectory (an int array). Online and paper: one per test trajectory; rolling: every window."""
    if protocol.kind != "rolling":
        start = 0 if protocol.kind == "paper" else protocol.history_steps
        n = min(t.n_steps for t in test)
        if start >= n:  # type: ignore[operator]
            raise ValueError(f"history of {start} steps leaves nothing to predict in trajectories of {n} steps")
        return ([t if start == 0 else t.window(0, start) for t in test], [t.states[start:] for t in test],
                np.arange(len(test)))
    T, H = protocol.history_steps, protocol.horizon
    histories, futures, owners = [], [], []
    for i, t in enumerate(test):
        for step in range(T, t.n_steps - H + 1, protocol.stride):  # type: ignore[arg-type, operator]
            histories.append(t.window(step - T, step))  # type: ignore[operator]
            futures.append(t.states[step : step + H + 1])  # type: ignore[operator]
            owners.append(i)
    return histories, futures, np.asarray(owners, dtype=int)


def style_agreement(learner, train: Sequence[Trajectory]) -> float | None:
    """ARI of a clustering learner's training labels against the true styles in the metadata, or None."""
    if not hasattr(learner, "labels_") or not all("style" in t.metadata for t in train):
        return None
    return adjusted_rand_index(np.array([t.metadata["style"] for t in train]), learner.labels_)
