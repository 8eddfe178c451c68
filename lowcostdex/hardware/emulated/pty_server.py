"""Serve an emulated chain on a Linux pty, so any program using dynamixel_sdk can connect.

The slave side (``PtyServer.path``, e.g. /dev/pts/5) is what a host opens with
``PortHandler(path)``; the server reads instruction packets from the master side and writes the
chain's status packets back. Pitfalls handled (05-dynamixel-protocol.md section 2.2): the slave is
put in raw mode right after ``openpty`` (a fresh pty echoes and translates newlines), the server
keeps its own slave fd open for its whole life (otherwise the master reads EIO while the SDK
re-opens the port in ``setBaudRate``), and nothing is written before the host sends a packet.

Baud rate: the server reads the rate the host set on the pty (termios, as pyserial sets it on a
real tty) and hands it to the chain, so motors set to another rate do not hear the host, as on a
real line; a rate termios cannot name is treated as unknown (every motor hears).

Time: with a real-time chain the loop keeps the physics up with the wall clock (so the Bus
Watchdog trips on a silent host) and, when the chain models wire time, holds each reply until its
bus time; with a virtual-clock chain bus time advances only by the bytes exchanged, and replies go
out at once.

Usage::

    server = PtyServer(chain); server.start()   # background thread
    ... PortHandler(server.path) ...
    server.stop()

or ``server.serve()`` in the foreground until interrupted (``lowcostdex emulate``).
"""

from __future__ import annotations

import errno
import heapq
import os
import select
import sys
import termios
import threading
import time
import tty
from typing import TYPE_CHECKING

from lowcostdex.hardware.dynamixel.protocol import BAUD_CODES, wire_time

if TYPE_CHECKING:
    from lowcostdex.hardware.dynamixel.protocol import Reply, WireDevice

_MAX_CATCHUP = 0.25  # [s] of physics a real-time loop may step in one go before skipping ahead
_SPIN = 0.002  # [s] replies due sooner than this are timed by spinning, not by select()
_SPEEDS = {getattr(termios, f"B{rate}"): rate for rate in BAUD_CODES.values()
           if hasattr(termios, f"B{rate}")}  # termios speed constant -> bit rate


class PtyServer:
    """A pty whose other end is ``chain``.

    Attributes:
      path: the slave device path a host opens.
      lock: held while the server touches the chain; hold it to inspect the chain from another
        thread.
    """

    def __init__(self, chain: WireDevice):
        self.chain = chain
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.path = os.ttyname(self._slave)
        self.lock = threading.Lock()
        self._pending: list[Reply] = []
        self._line_free = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.packets_in = 0

    # -- lifecycle -----------------------------------------------------------------------------
    def start(self) -> PtyServer:
        """Serve from a daemon thread of this process.

        dynamixel_sdk busy-polls the port while it waits for a status packet, holding the GIL
        between polls; with the default 5 ms GIL switch interval the server thread would answer
        milliseconds late. ``start`` therefore lowers ``sys.setswitchinterval`` to 0.1 ms while
        the thread runs (restored by ``stop``). A server in its own process (``lowcostdex
        emulate``) needs none of this.
        """
        self._switch = sys.getswitchinterval()
        sys.setswitchinterval(min(self._switch, 1e-4))
        self._thread = threading.Thread(target=self.serve, name="dxl-pty", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
            sys.setswitchinterval(self._switch)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
        self._master = self._slave = -1

    def __enter__(self) -> PtyServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def line_baudrate(self) -> int | None:
        """The bit rate the host set on the pty [bit/s], or None if termios does not name it."""
        try:
            return _SPEEDS.get(termios.tcgetattr(self._slave)[4])
        except (termios.error, OSError):
            return None

    # -- loop ------------------------------------------------------------------------------------
    def serve(self) -> None:
        """Serve until ``stop()`` (or KeyboardInterrupt in the foreground)."""
        clock = self.chain.clock
        dt = float(self.chain.plant.model.opt.timestep)
        max_steps = max(1, int(_MAX_CATCHUP / dt))
        while not self._stop.is_set():
            timeout = 0.05 if clock.virtual else dt
            if self._pending and not clock.virtual:
                timeout = max(0.0, min(timeout, self._pending[0].time - clock.now()))
            try:
                ready, _, _ = select.select([self._master], [], [], timeout)
            except (OSError, ValueError):
                return  # closed
            with self.lock:
                if ready:
                    self._receive()
                if not clock.virtual:
                    self.chain.advance_to(clock.now(), max_steps=max_steps)
                self._send_due()

    def _receive(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:  # no slave open right now (host re-opening the port)
                time.sleep(0.001)
                return
            if exc.errno == errno.EBADF and self._stop.is_set():
                return  # stop() closed the pty between select and read
            raise
        if not data:
            return
        self.packets_in += 1
        chain, clock = self.chain, self.chain.clock
        baud = self.line_baudrate()
        wire = wire_time(len(data), baud or chain.baudrate) if chain.wire_time else 0.0
        if clock.virtual:
            t_in = max(clock.now(), self._line_free) + wire
        else:
            t_in = clock.now() + wire
        replies = chain.handle(data, t_in, baud)
        if clock.virtual:
            ends = [r.time for r in replies if not r.late]
            self._line_free = max([t_in] + ends)
            clock.advance_to(self._line_free)
            self._write(b"".join(r.data for r in sorted(replies)))
        else:
            for r in replies:
                heapq.heappush(self._pending, r)
            # Replies due within a couple of ms are held here, not in select(): handing the GIL
            # back to a host that busy-polls (dynamixel_sdk does) can cost a 5 ms switch interval.
            while self._pending and self._pending[0].time - clock.now() < _SPIN:
                due = self._pending[0].time
                while clock.now() < due:
                    pass
                self._send_due()

    def _send_due(self) -> None:
        now = self.chain.clock.now()
        due = []
        while self._pending and self._pending[0].time <= now:
            due.append(heapq.heappop(self._pending).data)
        if due:
            self._write(b"".join(due))  # one write: one wake-up of the host, not one per motor

    def _write(self, data: bytes) -> None:
        if not data:
            return
        view = memoryview(data)
        while view:
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                time.sleep(0.0001)
                continue
            view = view[n:]
