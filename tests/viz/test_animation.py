"""pirl_sim.viz animations: frames asked for, vehicles moving in them, GIF/MP4 files, clear errors."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest
from PIL import Image
from viz_testdata import has_color_near, straight_tracks

from pirl_sim.viz import (
    PredictionWindow,
    SceneView,
    TrackFrames,
    animate_predictions,
    animate_scene,
    data_to_pixel,
    frame_schedule,
    iter_scene_frames,
    render_prediction_frames,
    render_scene_frames,
    writers,
)

SMALL = (240, 180)


@pytest.fixture
def tracks():
    return straight_tracks(2, 50)  # frames 1..50, 0.1..5.1 s


def test_schedule_has_the_frames_asked_for(tracks):
    frames = TrackFrames(tracks)
    assert frames.time_range_s == pytest.approx((0.1, 5.1))
    assert frame_schedule(frames).tolist() == list(range(1, 51))  # whole recording at 10 fps: every frame
    assert frame_schedule(frames, start_s=1.0, end_s=3.0, fps=5).tolist() == list(range(10, 30, 2))
    assert len(frame_schedule(frames, start_s=1.0, end_s=3.0, fps=5, speed=2.0)) == 5
    assert frame_schedule(frames, start_s=1.0, end_s=1.2, fps=20).tolist() == [10, 10, 11, 11]


def test_rendered_frames_show_the_vehicles_moving(tracks):
    frames = render_scene_frames(tracks, start_s=1.0, end_s=3.0, fps=5, size_px=SMALL, trail_s=0.0)
    assert frames.shape == (10, SMALL[1], SMALL[0], 3) and frames.dtype == np.uint8
    assert not np.array_equal(frames[0], frames[-1])
    view = SceneView(tracks, size_px=SMALL, trail_s=0.0)  # same layout as the frames' view
    colour = view.colors.rgba[view.frames.rows(10)][0]
    for i, frame in ((0, 10), (9, 28)):
        x = view.frames.x[view.frames.rows(frame)][0]
        assert has_color_near(frames[i], data_to_pixel(view.ax, (x, 0.0)), colour, radius=1, tol=10)


def test_progress_callback_sees_every_frame(tracks, capsys):
    seen = []
    list(iter_scene_frames(tracks, start_s=0.1, end_s=0.9, fps=10, size_px=SMALL,
                           progress=lambda done, total: seen.append((done, total))))
    assert seen == [(i, 8) for i in range(1, 9)]
    list(iter_scene_frames(tracks, start_s=0.1, end_s=0.4, size_px=SMALL, progress=True))  # a tqdm bar on stderr
    assert "3/3" in capsys.readouterr().err
    with pytest.raises(TypeError, match="progress must be"):
        iter_scene_frames(tracks, size_px=SMALL, progress="yes")


def test_gif_has_the_frames_asked_for(tracks, tmp_path):
    path = animate_scene(tracks, tmp_path / "scene.gif", start_s=0.5, end_s=2.0, fps=10, size_px=SMALL)
    with Image.open(path) as gif:
        assert gif.n_frames == 15 and gif.size == SMALL
        assert gif.info["duration"] == 100
    assert [p.name for p in tmp_path.iterdir()] == ["scene.gif"]  # no temporary file left


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg is not installed")
def test_mp4_written_with_ffmpeg(tracks, tmp_path):
    path = animate_scene(tracks, tmp_path / "scene.mp4", start_s=0.5, end_s=1.5, fps=10, size_px=(241, 181))
    assert path.stat().st_size > 1000
    assert path.read_bytes()[4:8] == b"ftyp"  # an MP4 container
    if shutil.which("ffprobe"):
        probe = subprocess.run(["ffprobe", "-v", "error", "-count_frames", "-select_streams", "v:0", "-show_entries",
                                "stream=nb_read_frames,width,height", "-of", "csv=p=0", str(path)],
                               capture_output=True, text=True, check=True)
        assert probe.stdout.strip() == "242,182,10"  # padded to even sizes for H.264
    assert [p.name for p in tmp_path.iterdir()] == ["scene.mp4"]


def test_mp4_without_ffmpeg_is_a_clear_error(tracks, tmp_path, monkeypatch):
    monkeypatch.setattr(writers.shutil, "which", lambda name: None)
    with pytest.raises(RuntimeError, match="MP4 needs the ffmpeg program on PATH.*write a .gif"):
        animate_scene(tracks, tmp_path / "scene.mp4", size_px=SMALL)
    assert not any(tmp_path.iterdir())


def test_bad_animation_requests_name_what_is_allowed(tracks, tmp_path):
    with pytest.raises(ValueError, match=r"suffix must be one of \['.gif', '.mp4'\]"):
        animate_scene(tracks, tmp_path / "scene.avi", size_px=SMALL)
    with pytest.raises(ValueError, match=r"time span 4\.5\.\.9 s is not a non-empty span of the recording, which "
                                         r"covers 0\.1\.\.5\.1 s \(frames 1\.\.50\)"):
        render_scene_frames(tracks, start_s=4.5, end_s=9.0, size_px=SMALL)
    with pytest.raises(ValueError, match="fps must be a positive number"):
        render_scene_frames(tracks, fps=0, size_px=SMALL)
    with pytest.raises(ValueError, match="speed must be a positive number"):
        render_scene_frames(tracks, speed=-1.0, size_px=SMALL)
    with pytest.raises(ValueError, match="shorter than one video frame"):
        render_scene_frames(tracks, start_s=1.0, end_s=1.01, fps=10, size_px=SMALL)
    with pytest.raises(ValueError, match="GiB.*iter_"):
        render_scene_frames(tracks, size_px=(4000, 4000))
    assert not any(tmp_path.iterdir())


def test_prediction_animation_redraws_each_window(tmp_path):
    track = np.column_stack([np.linspace(0.0, 30.0, 31), np.zeros(31)])
    windows = []
    for t in range(5, 10):
        ahead = track[t + 1:t + 11]
        preds = np.stack([ahead, ahead + [0.0, 2.0], ahead - [0.0, 2.0]])
        windows.append(PredictionWindow(track[:t + 1], preds, [0.6, 0.3, 0.1], future=ahead, time_s=t / 10))
    frames = render_prediction_frames(windows, repeat=2, size_px=SMALL)
    assert frames.shape[0] == 10
    assert np.array_equal(frames[0], frames[1]) and not np.array_equal(frames[1], frames[2])
    path = animate_predictions(windows, tmp_path / "pred.gif", fps=5, size_px=SMALL)
    with Image.open(path) as gif:
        assert gif.n_frames == 5 and gif.info["duration"] == 200
    with pytest.raises(ValueError, match="windows is empty"):
        render_prediction_frames([])
    with pytest.raises(ValueError, match="repeat must be a positive integer"):
        render_prediction_frames(windows, repeat=0)
