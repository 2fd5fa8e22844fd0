"""A replay's scenes (pirl_sim.experiments.replay_scenes): written as pictures and scenes.json, drawn again by
``pirl-sim show OUT --window``. (That a replay stores the right windows: tests/experiments/test_replay_report.py.)"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from pirl_sim.cli import main
from pirl_sim.experiments.replay_scenes import (SCENES_FILE, draw_replay_scene, read_replay_scenes,
                                                replay_scene_windows, scene_learner, write_replay_scenes)
from pirl_sim.viz import data_to_pixel

H = 8  # future steps


def _result():
    t = np.arange(H + 1)[1:, None] * 1.0
    truth = [np.column_stack([t[:, 0], 0.0 * t[:, 0]]), np.column_stack([t[:, 0], 2.0 + 0.0 * t[:, 0]])]
    learner = [truth[0] + [0.0, 0.1], truth[1] + [0.0, 1.5]]  # beats CA on window 0, loses on window 1
    ca = [truth[0] + [0.0, 1.0], truth[1] + [0.0, 0.2]]
    rows = pd.DataFrame({"seed": [0, 0, 0], "method": ["TIRL", "PIRL-GMM (k=2)", "CA (path)"],
                         "med": [0.5, 0.7, 0.6]})
    errors = {(0, "TIRL"): np.array([0.1, 9.0, 1.5]), (0, "CA (path)"): np.array([1.0, 9.0, 0.2])}
    examples = {"scenes": {"TIRL": np.stack(learner), "CA (path)": np.stack(ca)}, "scene_windows": [0, 2],
                "scene_history": np.stack([np.column_stack([np.arange(-4.0, 1.0), np.zeros(5)])] * 2),
                "scene_future": np.stack(truth)}
    path = SimpleNamespace(x=np.linspace(-5.0, 10.0, 16), y=np.zeros(16))
    scene = SimpleNamespace(model=SimpleNamespace(path=path))
    return {"rows": rows, "seeds": [0], "learners": ["TIRL", "PIRL-GMM (k=2)"], "examples": examples,
            "errors": errors}, scene


def test_the_best_learner_is_the_lowest_mean_med_of_the_first_seed():
    result, _ = _result()
    assert scene_learner(result) == "TIRL"
    assert scene_learner({**result, "learners": []}) is None


def test_written_scenes_read_back_the_same(tmp_path):
    result, scene = _result()
    assert write_replay_scenes(result, scene, tmp_path) == ["scene_gain.png", "scene_loss.png"]
    lines, windows = replay_scene_windows(result, scene)
    lines_back, windows_back = read_replay_scenes(tmp_path)
    assert [k for k, _, _ in windows_back] == ["gain", "loss"]
    np.testing.assert_array_equal(lines_back[0], lines[0])
    for (_, title, w), (_, title_back, wb) in zip(windows, windows_back):
        assert title == title_back and w.labels == wb.labels == (w.labels[0], w.labels[1])
        for name in ("history", "future", "predictions", "probabilities"):
            np.testing.assert_array_equal(getattr(wb, name), getattr(w, name))
    assert windows[0][2].labels == ("TIRL: 0.10 m", "CA (path): 1.00 m")


def test_nothing_is_written_without_ca_predictions(tmp_path):
    result, scene = _result()
    del result["examples"]["scenes"]["CA (path)"]
    assert write_replay_scenes(result, scene, tmp_path) == []
    assert not (tmp_path / SCENES_FILE).exists()


def test_show_draws_a_replays_scene_where_its_positions_are(tmp_path, capsys):
    from matplotlib.colors import to_rgb
    from matplotlib.image import imread

    from pirl_sim.viz.prediction import HISTORY_COLOR

    result, scene = _result()
    write_replay_scenes(result, scene, tmp_path)
    for kind in ("gain", "loss"):
        out = tmp_path / f"shown_{kind}.png"
        assert main(["show", str(tmp_path), "--window", kind, "--out", str(out), "--size", "400x300"]) == 0
        img = imread(out)[..., :3]
        assert img.shape == (300, 400, 3)
        assert np.all(np.abs(img - to_rgb(HISTORY_COLOR)) < 0.05, axis=-1).sum() > 10  # the history is drawn
    assert main(["show", str(tmp_path), "--out", str(tmp_path / "default.png"), "--size", "400x300"]) == 0
    assert (imread(tmp_path / "default.png") == imread(tmp_path / "shown_gain.png")).all()  # gain by default
    fig = draw_replay_scene(tmp_path, "gain", (400, 300))  # the figure show saved: where the history lands
    img = imread(tmp_path / "shown_gain.png")[..., :3]
    col, row = np.round(data_to_pixel(fig.axes[0], (-2.0, 0.0))).astype(int)
    patch = img[row - 1:row + 2, col - 1:col + 2]
    assert (np.abs(patch - to_rgb(HISTORY_COLOR)) < 0.05).all(axis=-1).any()


def test_bad_show_input_for_a_replay_is_a_clear_error(tmp_path, capsys):
    result, scene = _result()
    write_replay_scenes(result, scene, tmp_path)
    assert main(["show", str(tmp_path), "--window", "best", "--out", str(tmp_path / "x.png")]) == 2
    assert "the replay's scenes are ['gain', 'loss']" in capsys.readouterr().err
    assert main(["show", str(tmp_path), "--span", "0", "5", "--out", str(tmp_path / "x.gif")]) == 2
    assert "--span" in capsys.readouterr().err
    (tmp_path / SCENES_FILE).write_text('{"format": "something else"}')
    assert main(["show", str(tmp_path), "--out", str(tmp_path / "x.png")]) == 2
    assert "not a replay's scenes file" in capsys.readouterr().err
    empty = tmp_path / "run"
    empty.mkdir()
    assert main(["show", str(empty), "--window", "gain"]) == 2
    assert "has no scenes.json" in capsys.readouterr().err
