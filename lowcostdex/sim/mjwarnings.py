"""MuJoCo's run-time warnings, counted instead of printed.

MuJoCo's C library reports a warning (``Nan, Inf or huge value in QACC``, ``Inertia matrix is
too close to singular``, ``Linesearch objective is not convex`` ...) by printing it and appending
it to ``MUJOCO_LOG.TXT`` in the current directory, once per simulation and warning kind until the
simulation is reset. An analysis that simulates thousands of candidate models, many at the edges
of their ranges, resets millions of times: on a user's one-joint MJCF with a ``position``
actuator and Coulomb friction, a 4-log gap analysis printed 22 million warning lines (1 GB of
stderr) and wrote a 1.7 GB ``MUJOCO_LOG.TXT`` into the folder holding the user's logs
(2026-11-26, mujoco 4.0.0).

``collect_mujoco_warnings`` installs a handler (``mujoco.set_mju_user_warning``) that counts each
message kind instead (thread-safe: ``mujoco.batch`` worker threads call it), and puts back the
handler it found when the block ends. The counts go into the report, where a person can see that
some candidate models were unstable without scrolling through them.
"""

from __future__ import annotations

import re
import threading
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import mujoco

_TIME = re.compile(r"\s*Time\s*=\s*[-+0-9.eE]+\.?\s*$")


def warning_kind(message: str) -> str:
    """The message without its simulation time (``... Time = 0.0120.``), so that the same
    warning at different times is one kind."""
    return _TIME.sub("", message.strip())


@dataclass
class MujocoWarnings:
    """Counts of MuJoCo warnings by kind (message without its time stamp)."""

    counts: Counter[str] = field(default_factory=Counter)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def add(self, message: str) -> None:
        kind = warning_kind(message)
        with self._lock:
            self.counts[kind] += 1

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def as_dict(self) -> dict[str, int]:
        """Kinds and counts, most frequent first (JSON-ready)."""
        return dict(self.counts.most_common())

    def summary(self, top: int = 3) -> str:
        """One line for a person, e.g. ``MuJoCo warned 1,200 times: 'Nan, Inf ...' x1,200``;
        empty when there were none."""
        if not self.counts:
            return ""
        parts = [f"'{k}' x{n:,}" for k, n in self.counts.most_common(top)]
        more = len(self.counts) - top
        return (f"MuJoCo warned {self.total:,} times: " + "; ".join(parts)
                + (f"; and {more} other kinds" if more > 0 else ""))


@contextmanager
def collect_mujoco_warnings() -> Iterator[MujocoWarnings]:
    """Count MuJoCo's warnings during the block instead of printing them and writing
    ``MUJOCO_LOG.TXT``; yields the counts. Blocks may nest (the inner one counts its own)."""
    seen = MujocoWarnings()
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(seen.add)
    try:
        yield seen
    finally:
        mujoco.set_mju_user_warning(previous)
