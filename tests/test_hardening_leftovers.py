"""Regression tests for the leftovers of issue 15 ("Hardening"): items 6, 13 and 16."""

import os
import signal
import subprocess
import sys
import time

import pytest

# A sweep whose cells take long enough that the workers are busy when the main process is killed.
_ORPHAN_CONFIG = """
name = "orphans"
seeds = [0, 1, 2, 3]

[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 600, n_train = 500 }
protocols = ["paper"]
learners = ["tirl", "pirl-dpgmm", { name = "pirl-gmm", grid = { n_components = [2, 3] } }]
"""


def _group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes of process group ``pgid`` (Linux /proc)."""
    members = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) "
        state, group = fields[0], int(fields[2])
        if group == pgid and state != "Z":
            members.append(int(entry))
    return members


# -- item 6: SIGKILL of the sweep's main process only ---------------------------------------------------------------

@pytest.mark.skipif(not os.path.isdir("/proc") or not hasattr(os, "killpg"), reason="needs Linux /proc")
@pytest.mark.parametrize("busy", [False, True], ids=["idle-workers", "busy-workers"])
def test_sigkill_of_sweep_main_process_leaves_no_worker(tmp_path, busy):
    """Killing only the main process (not its group) ends its spawn workers and the resource tracker too."""
    cfg = tmp_path / "orphans.toml"
    cfg.write_text(_ORPHAN_CONFIG)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "pirl_sim", "sweep", str(cfg), "--out", str(out), "--workers", "2", "--quiet"],
        start_new_session=True,  # its own process group, so that the test can find (and at the end clean up) children
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            children = [p for p in _group_members(proc.pid) if p != proc.pid]
            started = (out / "cells").is_dir() and any((out / "cells").glob("*.json"))
            if len(children) >= 3 and (started or not busy):  # two workers and the resource tracker
                break
            time.sleep(0.05)
        assert proc.poll() is None, f"the sweep ended before it could be killed: {proc.stderr.read().decode()}"
        children = [p for p in _group_members(proc.pid) if p != proc.pid]
        assert len(children) >= 3, children
        os.kill(proc.pid, signal.SIGKILL)  # the main process only
        proc.wait(timeout=30)
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline and _group_members(proc.pid):
            time.sleep(0.05)
        survivors = _group_members(proc.pid)
        assert not survivors, f"processes left running after the sweep's main process died: {survivors}"
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        if proc.poll() is None:
            proc.wait(timeout=30)


def test_watch_parent_rejects_bad_arguments():
    from pirl_sim.engine.executors import watch_parent

    with pytest.raises(ValueError, match="parent_pid"):
        watch_parent(0)
    with pytest.raises(ValueError, match="parent_pid"):
        watch_parent(True)
    with pytest.raises(ValueError, match="interval"):
        watch_parent(os.getppid(), interval=0.0)


# -- item 13: figures --------------------------------------------------------------------------------------------

from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

SWEEP_TABLE = Path(__file__).resolve().parents[1] / "results" / "sweep" / "table.csv"


def _data_boxes(ax):
    """Display-space boxes of every data mark in ``ax``: bars, and each segment of lines and error bars."""
    from matplotlib.transforms import Bbox

    boxes = [p.get_window_extent() for p in ax.patches if p.get_visible() and p.get_height() > 0]
    paths = [(ln.get_transform(), ln.get_path()) for ln in ax.get_lines()]
    for coll in ax.collections:
        paths += [(coll.get_transform(), p) for p in coll.get_paths()]
    for transform, path in paths:
        xy = transform.transform(path.vertices)
        xy = xy[np.isfinite(xy).all(axis=1)]
        boxes += [Bbox([np.minimum(a, b), np.maximum(a, b)]) for a, b in zip(xy[:-1], xy[1:])] or \
            [Bbox([p, p]) for p in xy]
    return boxes


def _legends(fig):
    return list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None]


def _assert_legends_clear(fig):
    from matplotlib.transforms import Bbox

    fig.canvas.draw()
    legends = _legends(fig)
    assert legends, "the figure has a legend"
    for legend in legends:
        box = legend.get_window_extent()
        for ax in fig.axes:
            if not ax.get_visible():
                continue
            clipped = [Bbox.intersection(b, ax.bbox) for b in _data_boxes(ax)]  # marks are drawn inside the axes
            hits = [b for b in clipped if b is not None and box.overlaps(b)]
            assert not hits, f"legend {[t.get_text() for t in legend.get_texts()]} covers data of {ax.get_title()!r}"


def _sweep_summary():
    from pirl_sim.experiments.sweep_report import best_variants, summary_table

    summary = summary_table(pd.read_csv(SWEEP_TABLE))
    return summary, best_variants(summary)


def _series_colors(ax):
    """{label: colour} of the labelled lines / bar containers of ``ax``."""
    from matplotlib.colors import to_hex

    out = {}
    for c in ax.containers:
        label = c.get_label()
        if label and not label.startswith("_"):
            artist = c.patches[0] if hasattr(c, "patches") else c.lines[0]
            out[label] = to_hex(artist.get_facecolor() if hasattr(c, "patches") else artist.get_color())
    for ln in ax.get_lines():
        if not ln.get_label().startswith("_"):
            out.setdefault(ln.get_label(), to_hex(ln.get_color()))
    return out


def _assert_one_colour_per_series(fig):
    seen = {}
    for ax in fig.axes:
        for label, color in _series_colors(ax).items():
            assert seen.setdefault(label, color) == color, f"{label!r} changes colour between panels"
    assert seen, "labelled series"


def _assert_tick_below_data(ax):
    """A labelled y tick at or below the lowest data point, inside the axis limits."""
    ax.figure.canvas.draw()
    lo, hi = ax.get_ylim()
    labelled = [t.get_loc() for t in ax.yaxis.get_major_ticks()
                if t.label1.get_visible() and t.label1.get_text() and lo * (1 - 1e-9) <= t.get_loc() <= hi]
    data_min = min(float(np.nanmin(ln.get_ydata())) for ln in ax.get_lines() if len(ln.get_ydata()))
    assert labelled and min(labelled) <= data_min, (ax.get_title(), labelled, data_min)


def test_learners_figure_legend_clear_and_colours_per_learner():
    from pirl_sim.evaluation.figures import pyplot
    from pirl_sim.experiments.sweep_report import learners_side_by_side_figure

    _, best = _sweep_summary()
    fig = learners_side_by_side_figure(best)
    try:
        _assert_legends_clear(fig)
        _assert_one_colour_per_series(fig)
        texts = [t.get_text() for ax in fig.axes for t in ax.texts]
        assert any(t.startswith("k=") for t in texts), "the best k is written at its bar"
    finally:
        pyplot().close(fig)


def test_med_vs_k_figure_legend_colours_and_what_k_counts():
    from pirl_sim.evaluation.figures import pyplot
    from pirl_sim.experiments.sweep_report import med_vs_k_figure

    summary, _ = _sweep_summary()
    fig = med_vs_k_figure(summary)
    try:
        _assert_legends_clear(fig)
        _assert_one_colour_per_series(fig)
        labels = {ax.get_title(): ax.get_xlabel() for ax in fig.axes if ax.get_visible()}
        assert any("PIRL-GMM" in t for t in labels) and any("PIRL-kNN" in t for t in labels)
        for title, xlabel in labels.items():
            if "PIRL-GMM" in title:
                assert "clusters" in xlabel and "neighbours" not in xlabel, xlabel
            if "PIRL-kNN" in title:
                assert "neighbours" in xlabel and "clusters" not in xlabel, xlabel
        passage = [ax for ax in fig.axes if ax.get_title().startswith("passage")]
        assert passage
        for ax in fig.axes:
            if ax.get_visible():
                _assert_tick_below_data(ax)  # the passage panel's lowest line (~0.12 m) was below every tick
    finally:
        pyplot().close(fig)


def test_recovery_figure_one_colour_per_feature():
    from matplotlib.colors import to_hex

    from pirl_sim.evaluation.figures import pyplot
    from pirl_sim.experiments.sweep_report import recovery_figure

    summary, best = _sweep_summary()
    recovery = pd.read_parquet(SWEEP_TABLE.with_name("recovery.parquet"))
    fig = recovery_figure(recovery, best)
    try:
        seen = {}
        for ax in fig.axes:
            for coll in ax.collections:
                label = coll.get_label()
                if label and not label.startswith("_"):
                    color = to_hex(coll.get_facecolor()[0], keep_alpha=False)
                    assert seen.setdefault(label, color) == color, f"{label!r} changes colour between panels"
        assert len(set(seen.values())) == len(seen) >= 2
        _assert_legends_clear(fig)
    finally:
        pyplot().close(fig)


def test_knn_vs_k_draws_no_band_through_zero_on_a_log_axis():
    from matplotlib.container import ErrorbarContainer

    from pirl_sim.evaluation.figures import knn_vs_k_figure, pyplot

    ktable = pd.DataFrame({"protocol": ["paper"] * 3 + ["online"] * 3, "k": [1, 3, 10] * 2,
                           "med": [6e-5, 4e-5, 9e-5, 1.4e-5, 9e-6, 2e-5],
                           "med_std": [1.7e-4, 8e-5, 3e-4, 4e-5, 2e-5, 7e-5]})  # std > mean, as measured
    fig = knn_vs_k_figure(ktable, "test")
    try:
        (ax,) = fig.axes
        assert ax.get_yscale() == "log"
        assert not [c for c in ax.containers if isinstance(c, ErrorbarContainer)], "no mean - std bar below 0"
        drawn = np.concatenate([np.asarray(ln.get_ydata(), float) for ln in ax.get_lines()])
        drawn = drawn[np.isfinite(drawn)]
        lo, hi = ax.get_ylim()
        assert (drawn > 0).all() and lo <= drawn.min() and drawn.max() <= hi  # everything is on the axis
        for std in ktable["med_std"]:
            assert np.isclose(drawn, std).any(), "the std is drawn as its own curve"
        assert "neighbours" in ax.get_xlabel()
        _assert_legends_clear(fig)
        _assert_tick_below_data(ax)
    finally:
        pyplot().close(fig)


def test_label_log_axis_rejects_bad_limits():
    from pirl_sim.evaluation.figures import label_log_axis, pyplot

    fig, ax = pyplot().subplots()
    try:
        with pytest.raises(ValueError, match="lo="):
            label_log_axis(ax, 0.0, 1.0)
        with pytest.raises(ValueError, match="hi="):
            label_log_axis(ax, 1.0, float("nan"))
    finally:
        pyplot().close(fig)


# -- item 16: --version, py.typed, diagnostics through logging --------------------------------------------------

REPO = Path(__file__).resolve().parents[1]


def test_version_flag_prints_the_package_metadata_version(capsys):
    from importlib.metadata import version

    from pirl_sim.cli import main

    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"pirl-sim {version('pirl_sim')}"


def test_package_is_marked_typed():
    import tomllib
    from importlib.resources import files

    assert files("pirl_sim").joinpath("py.typed").is_file()
    data = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    assert "py.typed" in data["tool"]["setuptools"]["package-data"]["pirl_sim"]  # shipped in wheels too


_TINY_SWEEP = """
name = "tiny-log"
seeds = [0]

[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 80, n_train = 60 }
protocols = ["paper"]
learners = ["tirl"]
"""


def test_failed_cells_are_reported_through_logging(tmp_path, monkeypatch, caplog, capsys):
    import logging

    import pirl_sim.engine.run as engine_run
    from pirl_sim.cli import main

    class FakeRun:
        table = pd.DataFrame({"key": ["abc"]})
        computed, cached, failed, wall_s = ["abc"], [], {"abc": "ValueError: boom"}, 0.1

    monkeypatch.setattr(engine_run, "run_sweep", lambda *a, **k: FakeRun())
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(_TINY_SWEEP)
    with caplog.at_level(logging.WARNING, logger="pirl_sim"):
        code = main(["sweep", str(cfg), "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 1
    messages = [r.getMessage() for r in caplog.records if r.name == "pirl_sim.cli.sweep"]
    assert any("cell abc failed: ValueError: boom" in m for m in messages), messages
    assert all(r.levelno == logging.WARNING for r in caplog.records if r.name == "pirl_sim.cli.sweep")
    err = capsys.readouterr().err
    assert "cell abc failed: ValueError: boom" in err  # and shown on stderr by the command's handler
    assert "1 cells failed" in err


def test_cli_logging_shows_library_warnings_and_leaves_no_handler(tmp_path, capsys):
    import logging

    from pirl_sim.cli import main
    from pirl_sim.engine.config import load_config
    from pirl_sim.engine.store import code_version

    cfg = tmp_path / "tiny.toml"
    cfg.write_text(_TINY_SWEEP)
    out = tmp_path / "out"
    (out / "cells").mkdir(parents=True)
    key = load_config(cfg).cells[0].key(code_version())
    (out / "cells" / f"{key}.json").write_text("{not json")  # a damaged cell: the store logs a warning
    handlers = list(logging.getLogger("pirl_sim").handlers)
    assert main(["sweep", str(cfg), "--out", str(out), "--dry-run"]) == 0
    captured = capsys.readouterr()
    assert "0 already in" in captured.out  # the result, on stdout as before
    assert "ignoring unreadable result" in captured.err or "ignoring malformed result" in captured.err
    assert logging.getLogger("pirl_sim").handlers == handlers  # the command's handler is gone


def test_verbose_flag_shows_info_messages(capsys):
    import logging

    from pirl_sim.cli import cli_logging

    log = logging.getLogger("pirl_sim.test_leftovers")
    with cli_logging(verbose=False):
        log.info("quiet detail")
        log.warning("a warning")
    with cli_logging(verbose=True):
        log.info("loud detail")
    err = capsys.readouterr().err
    assert "quiet detail" not in err and "a warning" in err and "loud detail" in err
