"""Scenes of a weight-recovery study: a simulated run's tracks on its road, coloured by the fitted weights.

`recovery_scene` draws one run's tracks coloured by each track's fitted ``speed_dev`` weight (log10) or by the
|log error| of that fit; `write_recovery_scenes` writes both for the first seed of each simulator of a study
(``scene_<simulator>_weights.png``, ``scene_<simulator>_errors.png``) and adds a "Scenes" section to its README.
The simulated runs are read from the study's ``simulations/`` folder, so the scenes cost no simulation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from pirl_sim.evaluation.figures import write_png
from pirl_sim.io.atomic import atomic_write_text

__all__ = ["SCENE_VALUES", "recovery_scene", "scene_values", "write_recovery_scenes"]

#: what a scene's tracks are coloured by: the fitted weight, or the fit's error against the true weight
SCENE_VALUES: tuple[str, ...] = ("weights", "errors")
_FEATURE = "speed_dev"  # the free weight that tells the styles apart (acc_sq moves with it)
_ERROR_FLOOR = 1e-6  # |log error| below this is drawn as this (log10 of 0 is not a colour)
_LABELS = {"weights": f"log10 fitted {_FEATURE} weight", "errors": f"log10 |log error| of {_FEATURE}"}


def scene_values(fits: pd.DataFrame, value: str) -> dict:
    """{track_id: number} to colour a run's tracks by: log10 of the fitted ``speed_dev`` weight (``"weights"``)
    or log10 of its |log error| against the true weight (``"errors"``, floored at 1e-6).

    Parameters
    ----------
    fits : pandas.DataFrame    per-track fits of one run (`pirl_sim.experiments.recovery.RunRecovery.tracks`:
                               ``track_id``, ``theta_hat_speed_dev``, ``log_err_speed_dev``)
    value : {"weights", "errors"}
    """
    if value not in SCENE_VALUES:
        raise ValueError(f"value must be one of {SCENE_VALUES}, got {value!r}")
    need = {"track_id", f"theta_hat_{_FEATURE}", f"log_err_{_FEATURE}"}
    if not need <= set(fits.columns):
        raise ValueError(f"fits need the columns {sorted(need)}, got {list(fits.columns)}")
    numbers = (np.log10(fits[f"theta_hat_{_FEATURE}"].to_numpy(float)) if value == "weights" else
               np.log10(np.maximum(np.abs(fits[f"log_err_{_FEATURE}"].to_numpy(float)), _ERROR_FLOOR)))
    ok = np.isfinite(numbers)
    return dict(zip(fits["track_id"].to_numpy()[ok].tolist(), numbers[ok].tolist()))


def recovery_scene(tracks: pd.DataFrame, fits: pd.DataFrame, value: str, *, road=None, title: str | None = None):
    """Every track of a run on its road, coloured by `scene_values` (tracks without a fit are grey).

    Parameters
    ----------
    tracks : pandas.DataFrame    the run's INTERACTION-format rows (`pirl_sim.io.interaction.read_tracks`)
    fits : pandas.DataFrame      its per-track fits (see `scene_values`)
    value : {"weights", "errors"}
    road : pirl_sim.viz.Road, optional
    title : str, optional

    Returns
    -------
    figure : matplotlib.figure.Figure
    """
    from pirl_sim.viz import draw_recording

    colours = scene_values(fits, value)
    if not colours:
        raise ValueError("no fitted track to colour: the fits have no finite weight")
    cmap = "viridis" if value == "weights" else "magma"
    return draw_recording(tracks, road=road, color_by=colours, categorical=False, cmap=cmap, label=_LABELS[value],
                          title=title)


def write_recovery_scenes(study, run_dirs: Sequence[Path], out) -> dict[str, Path]:
    """Draw the scenes of the first main-table run (population's own noise) of each simulator of ``study`` into
    ``out`` and add a "Scenes" section to ``out/README.md`` (written before by
    `pirl_sim.experiments.recovery.write_recovery`); return the files written by name.

    Parameters
    ----------
    study : pirl_sim.experiments.recovery.RecoveryResult
    run_dirs : sequence of Path    the simulated run of each of ``study.jobs``, in order (each with its track file
                                   and ``map.osm``)
    out : path-like                the study's output folder
    """
    from pirl_sim.io.interaction import read_tracks
    from pirl_sim.scenarios.recording import MAP_FILE, TRACKS_FILE
    from pirl_sim.viz import road_from_lanelet2

    out = Path(out)
    if len(run_dirs) != len(study.jobs):
        raise ValueError(f"one run folder per job is needed: {len(study.jobs)} jobs, {len(run_dirs)} folders")
    written: dict[str, Path] = {}
    lines, drawn = [], set()  # drawn: the simulators whose scenes are written
    for job, report, run_dir in zip(study.jobs, study.reports, run_dirs):
        tracks_file, map_file = Path(run_dir) / TRACKS_FILE, Path(run_dir) / MAP_FILE
        if job.control_noise is not None or job.simulator in drawn or not tracks_file.is_file() or report.tracks.empty:
            continue
        drawn.add(job.simulator)
        tracks, road = read_tracks(tracks_file), road_from_lanelet2(map_file) if map_file.is_file() else None
        for value in SCENE_VALUES:
            name, title = f"scene_{job.simulator}_{value}.png", f"{job.simulator} seed {job.seed}: {_LABELS[value]}"
            written[name] = write_png(out / name, recovery_scene(tracks, report.tracks, value, road=road, title=title))
        lines.append(" ".join(f"![{job.simulator} {v}](scene_{job.simulator}_{v}.png)" for v in SCENE_VALUES))
    if lines:
        readme = out / "README.md"
        text = readme.read_text("utf-8") if readme.is_file() else ""
        section = ("## Scenes\n\nThe first seed of each simulator on its road: every track coloured by its fitted "
                   f"`{_FEATURE}` weight (log10, `scene_<simulator>_weights.png`; the styles show as colours) and by "
                   "the |log error| of that fit (log10, `scene_<simulator>_errors.png`); grey tracks were not fitted "
                   "(not PIRL drivers, or too few usable steps).\n\n" + "\n\n".join(lines) + "\n")
        written["README.md"] = atomic_write_text(readme, text.rstrip("\n") + "\n\n" + section)
    return written
