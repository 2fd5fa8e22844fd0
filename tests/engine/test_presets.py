"""The reproduce presets (pirl_sim.engine.presets): cells of the default sweep, the options mapped onto them, and
the output directory checked before any work."""

from pathlib import Path

import pytest

from pirl_sim.cli import main


def test_reproduce_presets_are_cells_of_the_default_sweep():
    """The presets run the default sweep's synthetic and passage cells (same keys: same numbers)."""
    from pirl_sim.engine.presets import preset_config
    from pirl_sim.engine.config import default_config

    default = {c.key("v") for c in default_config().cells}
    for name in ("synthetic", "passage"):
        cells = preset_config(name).cells
        assert {c.experiment for c in cells} == {"table", "knn_k"}
        assert {c.key("v") for c in cells} <= default, name


def test_reproduce_options_map_onto_the_preset(capsys):
    from pirl_sim.engine.presets import preset_config

    config = preset_config("synthetic", seed=3, params={"n_train": 30, "n_trajectories": 40}, history_steps=7)
    assert {c.seed for c in config.cells} == {3}
    assert {c.scenario_params["n_train"] for c in config.cells} == {30}
    assert {c.protocol["history_steps"] for c in config.cells if c.protocol["kind"] == "online"} == {7}
    assert sorted({c.k for c in config.cells if c.experiment == "knn_k"}) == [1, 2, 3, 5, 8, 13, 21]  # k <= n_train
    with pytest.raises(ValueError, match="unknown experiment 'highway'"):
        preset_config("highway")
    assert main(["reproduce", "passage", "--position-range", "2", "8", "--out", "/nonexistent/never"]) == 2
    assert "--position-range apply to the synthetic experiment only" in capsys.readouterr().err


def _bad_outputs(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("not a directory")
    return [(a_file, "is an existing file"), (a_file / "sub", "is not a writable directory"),
            (Path("/proc/pirl_sim_not_writable"), "is not a writable directory")]


def test_reproduce_api_checks_the_output_directory_first(tmp_path, monkeypatch):
    import pirl_sim.engine.presets as presets

    monkeypatch.setattr(presets, "run_sweep", lambda *a, **k: pytest.fail("ran the cells before the check"))
    for out, message in _bad_outputs(tmp_path):
        with pytest.raises(ValueError, match=f"out_dir .* {message}"):
            presets.run_preset("synthetic", out, progress=False)
