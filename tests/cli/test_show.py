"""``pirl-sim show``: a recording drawn on its map as a picture or an animation, and its bad inputs."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from pirl_sim.cli import main

pytest.importorskip("lanelet2")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A recorded scene with tracks, ground truth (styles) and a Lanelet2 map, as a simulated run has."""
    from pirl_sim.scenarios.passage import PassageConfig, generate, write_scene

    out = tmp_path_factory.mktemp("scene")
    write_scene(generate(PassageConfig(n_trajectories=12, n_train=9, n_steps=20, seed=1)), out)
    return out


def _pixels(path):
    return np.asarray(Image.open(path).convert("RGB"))


def test_every_track_coloured_by_style_and_one_frame(run_dir, tmp_path, capsys):
    every = tmp_path / "tracks.png"
    assert main(["show", str(run_dir), "--color-by", "style", "--out", str(every)]) == 0
    assert f"wrote {every}" in capsys.readouterr().out
    img = _pixels(every)
    assert img.shape == (600, 800, 3)
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 20  # road, tracks in style colours, legend: not blank
    frame = tmp_path / "frame.png"
    assert main(["show", str(run_dir), "--time", "1.0", "--size", "400x300", "--out", str(frame)]) == 0
    assert _pixels(frame).shape == (300, 400, 3)


def test_an_animation_has_the_frames_asked_for(run_dir, tmp_path):
    out = tmp_path / "clip.gif"
    assert main(["show", str(run_dir), "--span", "0.5", "1.5", "--fps", "10", "--quiet", "--out", str(out)]) == 0
    with Image.open(out) as gif:
        assert gif.n_frames <= 10 and gif.n_frames >= 2  # identical consecutive frames may merge


@pytest.mark.parametrize("argv, message", [
    (["--frame", "999999"], "outside the recording"),
    (["--color-by", "nope"], "unknown colour column 'nope'"),
    (["--span", "0", "1", "--out", "x.png"], "written as .gif or .mp4"),
    (["--out", "x.gif"], "written as .png"),
    (["--file", "3"], "--file 3"),
    (["--size", "10x10"], None),
])
def test_bad_input_is_a_clear_error(run_dir, tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    if message is None:  # an argparse type error: exit status 2 from the parser
        with pytest.raises(SystemExit) as info:
            main(["show", str(run_dir), *argv])
        assert info.value.code == 2
        return
    assert main(["show", str(run_dir), *argv]) == 2
    assert message in capsys.readouterr().err


def test_an_output_folder_or_a_missing_folder_is_refused(run_dir, tmp_path, capsys):
    (tmp_path / "taken.png").mkdir()
    assert main(["show", str(run_dir), "--out", str(tmp_path / "taken.png")]) == 2
    assert "is a folder" in capsys.readouterr().err
    assert main(["show", str(run_dir), "--out", str(tmp_path / "absent" / "x.png")]) == 2
    assert "does not exist" in capsys.readouterr().err
