"""MuJoCo's run-time warnings, recorded instead of printed.

MuJoCo's C library reports a warning (``Nan, Inf or huge value in QACC``, ``Inertia matrix is
too close to singular``, ``Linesearch objective is not convex`` ...) by printing it and appending
it to ``MUJOCO_LOG.TXT`` in the current directory, once per simulation and warning kind until the
simulation is reset. An analysis that simulates thousands of candidate models, many at the edges
of their ranges, resets millions of times: on a user's one-joint MJCF with a ``position``
actuator and Coulomb friction, a 4-log gap analysis printed 22 million warning lines (1 GB of
stderr) and wrote a 1.7 GB ``MUJOCO_LOG.TXT`` into the folder holding the user's logs
(2026-11-26, mujoco 4.0.0).

``collect_mujoco_warnings`` installs a handler (``mujoco.set_mju_user_warning``) that records
each distinct message instead, and puts back the handler it found when the block ends. The
handler is a C method (``set.add``), never Python code: MuJoCo calls it from inside ``mj_step``,
and an exception escaping it (a Ctrl-C's KeyboardInterrupt, a test timeout) cannot unwind through
MuJoCo's C code: the process aborts (``libc++abi: terminating``, SIGABRT; measured with a Python
handler: 3 of 3 Ctrl-Cs aborted, 0 of 3 with ``set.add``). No Python code runs in it, so no
signal handler can raise there. It keeps distinct messages (kind + simulation time), so memory is
bounded by the kinds and time stamps, not by how often MuJoCo repeats them; the report gives, per
kind, at how many distinct simulation times it was raised.
"""

from __future__ import annotations

import re
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
    """The distinct warning messages MuJoCo raised (``messages``: kind + simulation time)."""

    messages: set[str] = field(default_factory=set)

    @property
    def kinds(self) -> Counter[str]:
        """Kind -> number of distinct simulation times it was raised at."""
        return Counter(warning_kind(m) for m in self.messages)

    def as_dict(self) -> dict[str, int]:
        """Kinds and their distinct times, most frequent first (JSON-ready)."""
        return dict(self.kinds.most_common())

    def summary(self, top: int = 3) -> str:
        """One line for a person; empty when MuJoCo raised nothing."""
        return describe_warnings(self.as_dict(), top)


def describe_warnings(kinds: dict[str, int], top: int | None = 3) -> str:
    """``kinds`` (kind -> distinct simulation times, most frequent first, as ``as_dict`` gives
    and report.json keeps) in one line; empty when there are none; ``top`` None: all kinds."""
    if not kinds:
        return ""
    shown = list(kinds.items())[:top]
    parts = [f"'{k}' (at {n:,} distinct simulation times)" for k, n in shown]
    more = len(kinds) - len(shown)
    return ("MuJoCo warned (recorded, not printed): " + "; ".join(parts)
            + (f"; and {more} other kinds" if more > 0 else ""))


@contextmanager
def collect_mujoco_warnings() -> Iterator[MujocoWarnings]:
    """Record MuJoCo's warnings during the block instead of printing them and writing
    ``MUJOCO_LOG.TXT``; yields the record. Blocks may nest (the inner one records its own)."""
    seen = MujocoWarnings()
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(seen.messages.add)  # C code only: see the module docstring
    try:
        yield seen
    finally:
        mujoco.set_mju_user_warning(previous)
