"""Progress on every long step, whether or not the output is a terminal.

On a terminal: tqdm bars (:func:`bar`) and rich progress displays (:func:`tasks`). Elsewhere (CI,
``nohup``, a notebook's captured stream, a pipe) those draw nothing useful, so the same calls print
plain lines instead: one when a step starts, one every ``LOWCOSTDEX_PROGRESS_INTERVAL`` seconds
(default 10) while it runs, and one when it ends, each with the count, the elapsed time and an
estimate of what remains. The interval lines come from a heartbeat thread too, so a step that
does not advance the count for minutes (one long fit) still prints a line every interval::

    [progress] dapg lowcostdex/DClawTurnValve-v0: 12/40 it (30 %), 1 min 02 s elapsed, about 2 min 24 s left; success=0.35

Both objects follow the subset of the tqdm / rich APIs the project uses, so a caller does not
branch on the terminal.
"""

from __future__ import annotations

import atexit
import os
import sys
import threading
import time
import weakref
from collections.abc import Callable
from typing import Any, TextIO

DEFAULT_INTERVAL = 10.0
"""Seconds between progress lines when the output is not a terminal."""


def interval() -> float:
    """Seconds between lines (``LOWCOSTDEX_PROGRESS_INTERVAL``, default 10; invalid: default)."""
    try:
        value = float(os.environ.get("LOWCOSTDEX_PROGRESS_INTERVAL", DEFAULT_INTERVAL))
    except ValueError:
        return DEFAULT_INTERVAL
    return value if value >= 0 and value == value else DEFAULT_INTERVAL


def is_terminal(stream: TextIO | None = None) -> bool:
    stream = sys.stderr if stream is None else stream
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):
        return False


def duration(seconds: float) -> str:
    """``75.2`` -> ``"1 min 15 s"``; ``3725`` -> ``"1 h 02 min"``."""
    s = max(0, int(round(seconds)))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {(s % 3600) // 60:02d} min"


def line(desc: str, n: float, total: float | None, elapsed: float, unit: str = "",
         postfix: str = "", start: float = 0, todo: float | None = None) -> str:
    """One progress line: count, percentage, elapsed time and (when known) time left.

    ``start`` is the count this session began at (a resumed run); the time left is estimated
    from this session's rate, ``elapsed / (n - start)`` per unit, times ``todo``: the units
    still to run (default ``total - n``; fewer when some of the rest will be found done).
    """
    unit = f" {unit}" if unit else ""
    if total:
        frac = min(max(n / total, 0.0), 1.0)
        text = f"{desc}: {n:g}/{total:g}{unit} ({100 * frac:.0f} %), {duration(elapsed)} elapsed"
        if n >= total:
            text += ", done"
        elif n > start:
            left = total - n if todo is None else todo
            text += f", about {duration(elapsed * left / (n - start))} left"
    else:
        text = f"{desc}: {n:g}{unit}, {duration(elapsed)} elapsed"
    return f"[progress] {text}" + (f"; {postfix}" if postfix else "")


class LineBar:
    """A tqdm-like bar that prints a line at start, every ``every`` seconds and at the end."""

    def __init__(self, total: float | None = None, initial: float = 0, desc: str = "",
                 unit: str = "", disable: bool = False, file: TextIO | None = None,
                 every: float | None = None, clock: Callable[[], float] = time.monotonic,
                 **_: Any) -> None:
        self.total, self.n, self.desc, self.unit = total, initial, desc, unit
        self.disable = disable
        self._file = file
        self._every = interval() if every is None else every
        self._clock = clock
        self._t0 = clock()
        self._start = initial
        self._last = self._t0
        self._postfix = ""
        self._closed = False
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._emit()
        if not disable and self._every > 0 and clock is time.monotonic:
            # the heartbeat holds only a weak reference: a bar dropped without close() stops it
            beat = threading.Thread(target=_heartbeat, args=(weakref.ref(self), self._stop),
                                    name="lowcostdex-progress", daemon=True)
            _HEARTBEATS[beat] = self._stop
            beat.start()

    @property
    def file(self) -> TextIO:
        return sys.stderr if self._file is None else self._file

    def _elapsed(self) -> float:
        return self._clock() - self._t0

    def _emit(self) -> None:
        if self.disable:
            return
        with self._lock:
            print(line(self.desc, self.n, self.total, self._elapsed(), self.unit, self._postfix,
                       self._start), file=self.file, flush=True)
            self._last = self._clock()

    def _beat(self) -> float:
        """The heartbeat's tick: a line when none was printed for an interval; returns the
        seconds until the next line is due."""
        due = self._every - (self._clock() - self._last)
        if due > 0 or self._closed:
            return due
        try:
            self._emit()
        except (OSError, ValueError):  # the stream went away (closed file, captured stream)
            self._stop.set()
        return self._every

    def update(self, n: float = 1) -> None:
        self.n += n
        finished = self.total is not None and self.n >= self.total
        if not finished and self._clock() - self._last >= self._every:
            self._emit()  # the final line comes from close(), with the final postfix

    def set_postfix(self, ordered_dict: dict[str, Any] | None = None, refresh: bool = True,
                    **kwargs: Any) -> None:
        items = {**(ordered_dict or {}), **kwargs}
        self._postfix = ", ".join(f"{k}={v}" for k, v in items.items())

    def set_description(self, desc: str) -> None:
        self.desc = desc

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._stop.set()
            self._emit()

    def __del__(self) -> None:
        stop = getattr(self, "_stop", None)
        if stop is not None:
            stop.set()

    def __enter__(self) -> LineBar:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


_HEARTBEATS: weakref.WeakKeyDictionary[threading.Thread, threading.Event] = (
    weakref.WeakKeyDictionary())


def _heartbeat(ref: weakref.ref[LineBar], stop: threading.Event) -> None:
    """Print the bar's line whenever none came for an interval, until it is closed or gone."""
    wait = 0.0
    while not stop.wait(max(wait, 0.01)):
        b = ref()
        if b is None:
            return
        wait = b._beat()
        del b


@atexit.register
def _stop_heartbeats() -> None:
    """Stop every heartbeat before the interpreter finalises (a daemon thread caught writing to
    stderr then can abort the process)."""
    beats = list(_HEARTBEATS.items())
    for _, stop in beats:
        stop.set()
    for beat, _ in beats:
        # a Ctrl-C inside Thread.start() leaves a registered thread that never started
        if beat.is_alive():
            beat.join(timeout=1.0)


def bar(total: float | None = None, initial: float = 0, desc: str = "", unit: str = "it",
        disable: bool = False, file: TextIO | None = None) -> Any:
    """A tqdm bar on a terminal, a :class:`LineBar` elsewhere."""
    if is_terminal(file):
        from tqdm.auto import tqdm

        return tqdm(total=total, initial=initial, desc=desc, unit=unit, disable=disable,
                    file=file, dynamic_ncols=True)
    return LineBar(total=total, initial=initial, desc=desc, unit=unit, disable=disable,
                   file=file)


class LineProgress:
    """A rich-``Progress``-like display printing lines; ``add_task`` / ``advance`` / ``update``."""

    def __init__(self, file: TextIO | None = None, every: float | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._file, self._every, self._clock = file, every, clock
        self._bars: dict[int, LineBar] = {}

    def add_task(self, description: str, total: float | None = None, **_: Any) -> int:
        key = len(self._bars)
        self._bars[key] = LineBar(total=total, desc=description, file=self._file,
                                  every=self._every, clock=self._clock)
        return key

    def advance(self, task: int, advance: float = 1) -> None:
        self._bars[task].update(advance)

    def update(self, task: int, completed: float | None = None, description: str | None = None,
               advance: float | None = None, **_: Any) -> None:
        b = self._bars[task]
        if description is not None:
            b.set_description(description)
        if advance is not None:
            b.update(advance)
        if completed is not None:
            b.update(completed - b.n)

    @property
    def console(self) -> Any:
        return _PrintConsole(self._file)

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: Any) -> None:
        for b in self._bars.values():
            b.close()


class _PrintConsole:
    def __init__(self, file: TextIO | None) -> None:
        self._file = file

    def print(self, *objects: Any, **_: Any) -> None:
        print(*objects, file=sys.stderr if self._file is None else self._file, flush=True)


def tasks(transient: bool = True, console: Any = None) -> Any:
    """A rich ``Progress`` (bar, count, elapsed, time left) on a terminal, a
    :class:`LineProgress` elsewhere."""
    if is_terminal():
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                        TimeElapsedColumn(), TimeRemainingColumn(),
                        console=console or Console(stderr=True), transient=transient)
    return LineProgress()
