"""Scenes of a weight-recovery study (pirl_sim.experiments.recovery_scenes): tracks drawn where they are, in the
colour of their fitted weight; the study's README links them. (The command writes them: tests/experiments/
test_recovery.py, slow.)"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from pirl_sim.experiments.recovery import RecoveryJob
from pirl_sim.experiments.recovery_scenes import recovery_scene, scene_values, write_recovery_scenes
from pirl_sim.io.interaction import write_tracks
from pirl_sim.viz import color_rows, data_to_pixel, figure_to_array

from viz_testdata import has_color_near, straight_tracks

WEIGHTS = {1: 0.1, 2: 1.0, 3: 10.0}  # fitted speed_dev weights of tracks 1-3 (log10: -1, 0, 1)


def _fits(weights=WEIGHTS, errors=(1e-4, 0.0, 0.3)) -> pd.DataFrame:
    ids = list(weights)
    return pd.DataFrame({"track_id": ids, "theta_hat_speed_dev": [weights[i] for i in ids],
                         "log_err_speed_dev": list(errors)})


def test_values_are_log10_weights_and_floored_log10_errors():
    assert scene_values(_fits(), "weights") == pytest.approx({1: -1.0, 2: 0.0, 3: 1.0})
    assert scene_values(_fits(), "errors") == pytest.approx({1: -4.0, 2: -6.0, 3: np.log10(0.3)})


@pytest.mark.parametrize("value", ["weights", "errors"])
def test_each_track_is_drawn_where_it_is_in_the_colour_of_its_value(value):
    tracks = straight_tracks(4, 40)  # track 4 has no fit: grey
    fig = recovery_scene(tracks, _fits(), value, title="t")
    img = figure_to_array(fig)
    ax = fig.axes[0]
    numbers = scene_values(_fits(), value)
    cmap = "viridis" if value == "weights" else "magma"
    table = pd.DataFrame({"track_id": list(numbers)})
    colours = color_rows(table, numbers, categorical=False, cmap=cmap).rgba
    for (track_id, _), rgba in zip(numbers.items(), colours):
        mid = data_to_pixel(ax, (10.0, 10.0 * (track_id - 1)))
        assert has_color_near(img, mid, rgba, radius=1, tol=40), track_id  # lines are drawn a little translucent
        others = [c for t, c in zip(numbers, colours) if abs(numbers[t] - numbers[track_id]) > 0.5]
        assert not any(has_color_near(img, mid, c, radius=1, tol=40) for c in others), track_id


def test_bad_input_is_a_clear_error():
    with pytest.raises(ValueError, match="value must be one of"):
        scene_values(_fits(), "speed")
    with pytest.raises(ValueError, match="theta_hat_speed_dev"):
        scene_values(pd.DataFrame({"track_id": [1]}), "weights")
    with pytest.raises(ValueError, match="no fitted track"):
        recovery_scene(straight_tracks(1, 10), _fits({1: np.nan}, (np.nan,)), "weights")


def test_the_first_main_run_of_each_simulator_is_drawn_and_linked(tmp_path):
    runs = []
    for k in range(3):
        d = tmp_path / f"run{k}"
        d.mkdir()
        write_tracks(straight_tracks(3, 30), d / "vehicle_tracks_000.csv")
        runs.append(d)
    jobs = (RecoveryJob("sumo", 0, None), RecoveryJob("sumo", 0, 0.3), RecoveryJob("highway", 1, None))
    study = SimpleNamespace(jobs=jobs, reports=tuple(SimpleNamespace(tracks=_fits()) for _ in jobs))
    out = tmp_path / "out"
    out.mkdir()
    (out / "README.md").write_text("# Study\n\n## Files\n\nthe files\n")
    written = write_recovery_scenes(study, runs, out)
    assert set(written) == {"README.md", "scene_sumo_weights.png", "scene_sumo_errors.png",
                            "scene_highway_weights.png", "scene_highway_errors.png"}
    readme = (out / "README.md").read_text()
    assert readme.startswith("# Study\n\n## Files\n\nthe files\n\n## Scenes\n")
    for name in written:
        if name.endswith(".png"):
            assert f"]({name})" in readme
    with pytest.raises(ValueError, match="one run folder per job"):
        write_recovery_scenes(study, runs[:2], out)
