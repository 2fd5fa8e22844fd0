"""Sweep progress (pirl_sim.engine.progress): the ETA from computed cells, a line every few seconds off a terminal,
redrawn in place on one."""

import io


class _Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


def test_sweep_progress_eta_from_computed_cells_with_cached_counted_as_done(monkeypatch):
    import tqdm.std

    from pirl_sim.engine.progress import Progress

    clock = _Clock()
    monkeypatch.setattr(tqdm.std, "time", clock)
    out = io.StringIO()
    p = Progress(10, 4, stream=out, every=5.0)
    p.start()
    assert p.done == 4 and "4/10 cells" in out.getvalue() and "0/6 run, 4 from the store" in out.getvalue()
    clock.t += 10.0
    p.update()  # 1 computed cell in 10 s, 5 to go: ETA 50 s (the 4 stored cells took no time)
    clock.t += 10.0
    p.update(failed=True)  # 2 in 20 s, 4 to go: 40 s
    line = p.line()
    assert "6/10" in line and "elapsed 00:20, ETA 00:40" in line and "2/6 run, 4 from the store, 1 failed" in line
    p.close()
    lines = out.getvalue().splitlines()
    assert all("\r" not in s and s.startswith("sweep [") for s in lines)  # not a terminal: whole lines
    assert any("5/10" in s and "elapsed 00:10, ETA 00:50" in s for s in lines)


def test_sweep_progress_not_a_terminal_writes_a_line_every_few_seconds_and_nothing_when_disabled(monkeypatch):
    import tqdm.std

    from pirl_sim.engine.progress import Progress

    clock = _Clock()
    monkeypatch.setattr(tqdm.std, "time", clock)
    out = io.StringIO()
    p = Progress(100, stream=out, every=5.0)
    p.start()
    for _ in range(99):
        clock.t += 0.5
        p.update()
    n_lines = len(out.getvalue().splitlines())
    assert 8 <= n_lines <= 12  # 49.5 s: about one line per 5 s, not one per cell
    clock.t += 0.5
    p.update()
    p.close()
    assert "100/100" in out.getvalue().splitlines()[-1]
    quiet = io.StringIO()
    q = Progress(3, stream=quiet, enabled=False)
    q.start()
    q.update()
    q.close()
    assert quiet.getvalue() == "" and q.line() == ""


def test_sweep_progress_redraws_in_place_on_a_terminal():
    from pirl_sim.engine.progress import Progress

    class Tty(io.StringIO):
        def isatty(self):
            return True

    out = Tty()
    p = Progress(3, 1, stream=out)
    p.start()
    p.update()
    p.update()
    p.close()
    text = out.getvalue()
    assert "\r" in text and "3/3" in text and text.endswith("\n")
