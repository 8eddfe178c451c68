"""A log that keeps its newest entries: what an emulated device records of an hours-long run
(the Dynamixel chain's events and replies, the Allegro's applied torques) in bounded memory.
Below both devices (``hardware.emulated``, ``hardware.allegro``), beside the bus interface."""

from __future__ import annotations

from collections import deque
from itertools import islice
from typing import Any

from lowcostdex.errors import check_number


class RingLog(deque):
    """A log that keeps its newest ``maxlen`` entries (a ring buffer: appending to a full log
    drops the oldest), so an emulator serving an hours-long run holds bounded memory. ``total``
    counts every entry appended, ``dropped`` those pushed out by newer ones (``clear`` drops
    nothing: it empties the log and keeps both counts)."""

    def __init__(self, maxlen: int, name: str = "RingLog maxlen"):
        check_number(name, maxlen, 1, integer=True)  # (name: the option that sets it)
        super().__init__(maxlen=int(maxlen))
        self.total = 0
        self.dropped = 0

    def append(self, entry: Any) -> None:
        self.dropped += len(self) == self.maxlen
        self.total += 1
        super().append(entry)

    def since(self, total: int) -> list[Any]:
        """The entries appended after the log's ``total`` was ``total``, oldest first; an
        IndexError if some of them are no longer kept."""
        n = self.total - int(total)
        if not 0 <= n <= len(self):
            raise IndexError(f"{n} entries since total {total}, {len(self)} kept")
        return list(islice(self, len(self) - n, None))
