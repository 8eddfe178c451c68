"""Process-wide torque-off hooks: every connected ``DynamixelBus`` is turned off on SIGINT/SIGTERM
(then the previous handler runs) and at interpreter exit."""

from __future__ import annotations

import atexit
import logging
import os
import signal
import threading
import weakref
from typing import Protocol


class DynamixelBus(Protocol):
    """What the hooks need of a ``driver.DynamixelBus`` (this module does not import the driver)."""

    def emergency_torque_off(self) -> None: ...

    def disconnect(self) -> None: ...


log = logging.getLogger(__name__)
_OPEN: weakref.WeakSet[DynamixelBus] = weakref.WeakSet()
_PREVIOUS: dict[int, object] = {}
_INSTALL_LOCK = threading.Lock()
_ATEXIT = False


def register(bus: DynamixelBus) -> None:
    global _ATEXIT
    _OPEN.add(bus)
    with _INSTALL_LOCK:
        if not _ATEXIT:
            atexit.register(_at_exit)
            _ATEXIT = True
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            current = signal.getsignal(sig)
            if current is not _on_signal:
                _PREVIOUS[sig] = current
                signal.signal(sig, _on_signal)


def unregister(bus: DynamixelBus) -> None:
    """Forget ``bus`` (disconnected: nothing to turn off any more)."""
    _OPEN.discard(bus)


def _on_signal(signum: int, frame: object) -> None:
    for bus in list(_OPEN):
        bus.emergency_torque_off()
    prev = _PREVIOUS.get(signum, signal.SIG_DFL)
    if callable(prev):
        prev(signum, frame)
    elif prev == signal.SIG_DFL:
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)


def _at_exit() -> None:
    for bus in list(_OPEN):
        try:
            bus.disconnect()
        except Exception as exc:  # exiting anyway; report and go on
            log.warning("torque off at exit failed: %s", exc)
