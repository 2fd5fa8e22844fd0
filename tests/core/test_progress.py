"""One way to report progress (pirl_sim.progress): status lines and bars through tqdm on
stderr, nothing on stdout, silent when disabled."""

import io

from pirl_sim.progress import bar, reporter


def test_reporter_writes_lines_to_its_stream_and_is_silent_when_disabled(capsys):
    out = io.StringIO()
    say = reporter(True, stream=out)
    say("seed 0: fitted")
    say(3)
    assert out.getvalue() == "seed 0: fitted\n3\n"
    reporter(False)("nothing")
    reporter(True)("to stderr")
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == "to stderr\n"


def test_bar_counts_and_writes_to_its_stream_only(capsys):
    out = io.StringIO()
    with bar(4, "cells", stream=out, every=0.0) as b:
        for _ in range(4):
            b.update(1)
        assert b.n == 4
    assert "cells" in out.getvalue() and "4/4" in out.getvalue()
    assert "\r" not in out.getvalue()  # not a terminal: whole lines (LineStream), no in-place redraws
    with bar(2, "quiet", enabled=False, stream=out) as b:
        b.update(2)
    assert "quiet" not in out.getvalue()
    assert capsys.readouterr().out == ""
