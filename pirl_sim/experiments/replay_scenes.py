"""Scenes of a replay: the windows where the best learner beats constant acceleration most and loses to it most.

`write_replay_scenes` draws them (``scene_gain.png``, ``scene_loss.png``: history, recorded future and both
predictions on the matched routes' centre lines) and keeps them in ``scenes.json`` so that ``pirl-sim show
OUT --window gain|loss`` can draw them again (`read_replay_scenes`). The windows' positions are the replay
cells' (`pirl_sim.experiments.recorded`: ``examples["scene_*"]``), so drawing costs no prediction.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pirl_sim.evaluation.figures import write_png
from pirl_sim.io.atomic import atomic_write_text

__all__ = ["SCENE_KINDS", "SCENES_FILE", "scene_learner", "replay_scene_windows", "write_replay_scenes",
           "read_replay_scenes", "draw_replay_scene"]

SCENE_KINDS: tuple[str, ...] = ("gain", "loss")  #: scene_<kind>.png: where the best learner beats CA most, loses most
SCENES_FILE = "scenes.json"  #: the drawn windows of a replay's output folder
_CA = "CA (path)"
_FORMAT = "pirl_sim replay scenes"


def scene_learner(result: dict) -> str | None:
    """The learner of the scenes: the lowest mean MED on the first split seed among the learners (not baselines);
    None without one."""
    rows = result["rows"]
    first = rows[(rows["seed"] == result["seeds"][0]) & rows["method"].isin(set(result.get("learners", ())))]
    return None if first.empty else str(first.loc[first["med"].idxmin(), "method"])


def replay_scene_windows(result: dict, scene) -> tuple[list, list]:
    """The scenes of a replay's result dict (`pirl_sim.experiments.replay_report.collect_replay`) on its ``scene``:
    (centre lines [(n, 2) arrays, m], [(kind, title, `pirl_sim.viz.PredictionWindow`)]); both empty when the
    result has no best learner or no CA (path) predictions of the windows."""
    ex, best = result["examples"], scene_learner(result)
    preds = ex.get("scenes", {})
    if best is None or best not in preds or _CA not in preds or "scene_history" not in ex:
        return [], []
    from pirl_sim.viz import PredictionWindow

    lines = [np.column_stack([p.x, p.y]) for p in getattr(scene.model.path, "segments", (scene.model.path,))]
    errors, seed = result["errors"], result["seeds"][0]
    names, windows = [best, _CA], []
    for k, kind in enumerate(SCENE_KINDS):
        w = int(ex["scene_windows"][k])
        window = PredictionWindow(history=ex["scene_history"][k], predictions=np.stack([preds[n][k] for n in names]),
                                  probabilities=np.array([0.5, 0.5]), future=ex["scene_future"][k],
                                  labels=tuple(f"{n}: {errors[(seed, n)][w]:.2f} m" for n in names))
        windows.append((kind, f"{best} {'beats' if kind == 'gain' else 'loses to'} CA (path) most", window))
    return lines, windows


def _draw(lines, title: str, window, size_px=None):
    from pirl_sim.viz import Road, draw_prediction

    road = Road((), (), tuple(lines), source="matched routes")
    return draw_prediction(window, road=road, title=title, **({} if size_px is None else {"size_px": size_px}))


def write_replay_scenes(result: dict, scene, out) -> list[str]:
    """Write ``scene_gain.png``, ``scene_loss.png`` and ``scenes.json`` into ``out`` (nothing when
    `replay_scene_windows` has none); return the names of the pictures."""
    lines, windows = replay_scene_windows(result, scene)
    if not windows:
        return []
    out = Path(out)
    for kind, title, window in windows:
        write_png(out / f"scene_{kind}.png", _draw(lines, title, window))
    record = {"format": _FORMAT, "learner": scene_learner(result), "seed": int(result["seeds"][0]),
              "centerlines": [np.asarray(c, float).tolist() for c in lines],
              "windows": [{"kind": kind, "title": title, "history": w.history.tolist(),
                           "future": None if w.future is None else w.future.tolist(),
                           "predictions": w.predictions.tolist(), "probabilities": w.probabilities.tolist(),
                           "labels": list(w.labels or ())} for kind, title, w in windows]}
    atomic_write_text(out / SCENES_FILE, json.dumps(record) + "\n")
    return [f"scene_{kind}.png" for kind, _, _ in windows]


def read_replay_scenes(folder) -> tuple[list, list]:
    """The centre lines and windows that `write_replay_scenes` kept in ``folder/scenes.json`` (ValueError when the
    file is not one)."""
    from pirl_sim.viz import PredictionWindow

    path = Path(folder) / SCENES_FILE
    try:
        record = json.loads(path.read_text("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a replay's scenes file ({exc})") from None
    if not isinstance(record, dict) or record.get("format") != _FORMAT:
        raise ValueError(f"{path}: not a replay's scenes file (its 'format' is not {_FORMAT!r})")
    try:
        lines = [np.asarray(c, dtype=float).reshape(-1, 2) for c in record["centerlines"]]
        windows = [(str(w["kind"]), str(w["title"]),
                    PredictionWindow(history=w["history"], predictions=w["predictions"],
                                     probabilities=w["probabilities"], future=w["future"],
                                     labels=tuple(w["labels"]) or None)) for w in record["windows"]]
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: a scene is malformed ({type(exc).__name__}: {exc})") from None
    return lines, windows


def draw_replay_scene(folder, kind: str, size_px=None):
    """The figure of the scene ``kind`` of a replay's output ``folder`` (ValueError for a kind it does not have)."""
    lines, windows = read_replay_scenes(folder)
    found = {k: (title, w) for k, title, w in windows}
    if kind not in found:
        raise ValueError(f"--window {kind!r}: the replay's scenes are {sorted(found)}")
    return _draw(lines, *found[kind], size_px)
