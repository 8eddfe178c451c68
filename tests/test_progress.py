"""Progress lines when the output is not a terminal (issue 13, item 4)."""

from __future__ import annotations

import gc
import io
import os
import subprocess
import sys
import threading
import time

import pytest

from lowcostdex.progress import LineBar, LineProgress, bar, duration, line, tasks


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def test_duration_words():
    assert duration(4.4) == "4 s"
    assert duration(75.2) == "1 min 15 s"
    assert duration(3725) == "1 h 02 min"


def test_line_reports_elapsed_and_time_left_from_the_sessions_rate():
    # 10 of 40 done in 20 s -> 2 s each -> 30 left take 60 s
    text = line("npg", 10, 40, 20.0, "it")
    assert "10/40 it (25 %)" in text and "20 s elapsed" in text and "about 1 min 00 s left" in text
    # resumed at 30: 5 done this session in 10 s -> 2 s each; 5 left -> 10 s
    assert "about 10 s left" in line("npg", 35, 40, 10.0, "it", start=30)
    assert line("npg", 40, 40, 80.0).endswith("done")
    assert "left" not in line("npg", 0, 40, 3.0)


def test_line_bar_prints_at_start_every_interval_and_at_the_end():
    out, clock = io.StringIO(), Clock()
    b = LineBar(total=100, desc="dapg", unit="it", file=out, every=10.0, clock=clock)
    for _ in range(100):
        clock.t += 0.5           # 50 s in all -> a line at 10, 20, 30, 40 s; 50 s is the end
        b.update(1)
        b.set_postfix(success="0.50")
    b.close()
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("[progress] dapg: 0/100 it (0 %)")
    assert len(lines) == 1 + 4 + 1, lines
    assert sum("100/100" in x for x in lines) == 1     # the end is said once, by close()
    assert "20/100 it (20 %), 10 s elapsed, about 40 s left; success=0.50" in lines[1]
    assert lines[-1].endswith("done; success=0.50")


def test_disabled_bar_is_silent():
    out = io.StringIO()
    b = LineBar(total=3, file=out, disable=True, clock=Clock())
    b.update(3)
    b.close()
    assert out.getvalue() == ""


def test_line_progress_is_a_rich_like_display():
    out, clock = io.StringIO(), Clock()
    with LineProgress(file=out, every=10.0, clock=clock) as p:
        a = p.add_task("demos", total=4)
        for _ in range(4):
            clock.t += 6.0
            p.advance(a)
        g = p.add_task("gap analysis", total=1.0)
        p.update(g, completed=0.5, description="gap analysis: fit")
    text = out.getvalue()
    assert "[progress] demos: 0/4 (0 %)" in text
    assert "demos: 2/4 (50 %), 12 s elapsed, about 12 s left" in text
    assert "demos: 4/4 (100 %), 24 s elapsed, done" in text
    assert "gap analysis: fit: 0.5/1 (50 %)" in text


def test_not_a_terminal_gets_lines(monkeypatch):
    out = io.StringIO()   # StringIO.isatty() is False, like CI or nohup
    b = bar(total=2, desc="x", file=out)
    assert isinstance(b, LineBar)
    b.close()
    assert "[progress] x: 0/2" in out.getvalue()
    monkeypatch.setattr("sys.stderr", io.StringIO())
    assert isinstance(tasks(), LineProgress)


def _lines(out: io.StringIO) -> list[str]:
    return [x for x in out.getvalue().splitlines() if x.startswith("[progress]")]


def test_a_step_that_does_not_advance_still_prints_a_line_every_interval():
    # the lead's 16-joint gap analysis printed nothing for 14 min inside one long fit: lines came
    # only from update(); now a heartbeat prints the current line when none came for an interval
    out = io.StringIO()
    b = LineBar(total=5, desc="one long fit", file=out, every=0.05)
    time.sleep(0.4)                              # no update at all
    during = _lines(out)
    assert len(during) >= 1 + 4, during          # the start line + one per ~0.05 s
    assert all("one long fit: 0/5" in x for x in during)
    b.update(1)
    b.close()
    n_closed = len(_lines(out))
    time.sleep(0.2)
    assert len(_lines(out)) == n_closed           # closed: the heartbeat is quiet


def test_updates_reset_the_heartbeat():
    out = io.StringIO()
    b = LineBar(total=1000, desc="busy", file=out, every=0.2)
    t0 = time.monotonic()
    while time.monotonic() - t0 < 0.5:
        b.update(1)                               # updates print on their own schedule
        time.sleep(0.01)
    b.close()
    # start + about one line per 0.2 s + the end: never a burst from two sources
    assert 3 <= len(_lines(out)) <= 6, _lines(out)


def test_a_bar_dropped_without_close_stops_its_heartbeat():
    out = io.StringIO()
    before = set(threading.enumerate())
    b = LineBar(total=3, desc="dropped", file=out, every=0.02)
    (beat,) = [t for t in threading.enumerate() if t not in before]
    assert beat.name == "lowcostdex-progress" and beat.is_alive()
    del b
    gc.collect()
    beat.join(timeout=2.0)
    assert not beat.is_alive()


def test_exit_while_a_heartbeat_is_printing_is_clean():
    # a daemon thread caught writing to stderr at interpreter shutdown can abort the process
    code = ("from lowcostdex.progress import LineBar\n"
            "bars = [LineBar(total=9, desc=f'b{i}', every=0.001) for i in range(4)]\n"
            "import time; time.sleep(0.05)\n")
    for _ in range(3):
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                           timeout=60, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
        assert r.returncode == 0, r.stderr[-2000:]
        assert "Fatal Python error" not in r.stderr
        assert "[progress] b0: 0/9" in r.stderr


def test_ctrl_c_while_the_heartbeat_starts_leaves_a_clean_exit(monkeypatch):
    # CI: a SIGINT right after a bar's first line landed inside Thread.start(); at exit the
    # stop hook joined the never-started thread: "RuntimeError: cannot join thread before it
    # is started" became the last line instead of the one-line "interrupted (Ctrl-C)"
    from lowcostdex import progress

    kept = []   # threading keeps a starting thread referenced (its _limbo); so does this test

    def interrupted_start(self):
        kept.append(self)
        raise KeyboardInterrupt

    monkeypatch.setattr(threading.Thread, "start", interrupted_start)
    with pytest.raises(KeyboardInterrupt):
        LineBar(total=3, desc="x", file=io.StringIO(), every=0.05)
    monkeypatch.undo()
    assert kept and not kept[0].is_alive()
    progress._stop_heartbeats()     # the exit hook: no RuntimeError
