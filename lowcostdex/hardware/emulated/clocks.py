"""The emulated chain's clocks: virtual bus time (advanced by the bytes on the wire and by waits) and
wall time."""

from __future__ import annotations

import time

CLOCKS = ("virtual", "realtime")


class VirtualClock:
    """Bus time that advances only when told to [s]."""

    virtual = True

    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def advance_to(self, t: float) -> None:
        if t > self.t:
            self.t = t


class WallClock:
    """Monotonic wall time since construction [s]."""

    virtual = False

    def __init__(self) -> None:
        self._t0 = time.monotonic()

    def now(self) -> float:
        return time.monotonic() - self._t0

    def advance_to(self, t: float) -> None:
        """Wall time cannot be advanced; waiting is the caller's job."""

    def to_wall(self, t: float) -> float:
        """time.monotonic() value of bus time ``t``."""
        return self._t0 + t
