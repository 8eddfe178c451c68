"""Ports for ``dynamixel_sdk``: a real serial/pty port and an in-process port on an emulated chain.

``DxlPort`` is the SDK's ``PortHandler`` with three additions the driver needs:

- the USB latency timer as an instance value (``latency_ms``) in the status timeout
  ``tx_time * n + 2 * latency_ms + 2`` [ms], instead of the SDK's module-wide 16 ms constant;
- a trace of the bytes the SDK consumed (``rx_trace``), so the driver can tell a clean
  transaction from one that swallowed an extra (e.g. late) status packet;
- a clock (``now``/``sleep``) that the driver uses for timestamps and waits.

``EmulatedPort`` is a ``DxlPort`` whose serial object is answered by an ``EmulatedChain`` inside
``write()``: no thread, no pty, and every line of the SDK's packet handler and group classes runs
above it. With the chain's virtual clock the port's time is bus time: the SDK's own timeout loop
(``isPacketTimeout``) then runs on bus time, so a missing reply costs no wall time and every run
is deterministic.

The USB latency timer of a real adapter is read from
``/sys/bus/usb-serial/devices/<tty>/latency_timer`` (``usb_latency_timer``).
"""

from __future__ import annotations

import heapq
import os
import termios
import time
from pathlib import Path
from typing import TYPE_CHECKING

from dynamixel_sdk import PortHandler

from lowcostdex.hardware.bus import BusError
from lowcostdex.hardware.dynamixel.protocol import wire_time

if TYPE_CHECKING:
    from lowcostdex.hardware.dynamixel.protocol import Reply, WireDevice

SYSFS_USB_SERIAL = Path("/sys/bus/usb-serial/devices")
_POLL = 1e-4  # [s] virtual time one empty poll costs when nothing is pending
PORT_GONE = (OSError, termios.error)
"""What pyserial and termios raise when a port stops working under a read, write or flush
(``serial.SerialException`` is an ``OSError``)."""


class PortGone(BusError):
    """The port stopped working under the driver (unplugged, its server stopped)."""


class DxlPort(PortHandler):
    """``dynamixel_sdk.PortHandler`` with a per-port latency timer, an rx trace and a clock.

    Args:
      port_name: device path ("/dev/ttyUSB0", a pty slave path).
      latency_ms: USB latency timer the timeouts assume [ms] (the driver sets it from sysfs).
    """

    def __init__(self, port_name: str, latency_ms: float = 1.0):
        super().__init__(port_name)
        self.latency_ms = latency_ms
        self.rx_trace = bytearray()
        self.gone = False  # the port failed under a read, write or flush (``PortGone``)

    def setPacketTimeout(self, packet_length):  # noqa: N802 (SDK name)
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + 2.0 * self.latency_ms + 2.0

    def readPort(self, length):  # noqa: N802 (SDK name)
        try:
            data = self.ser.read(length)
        except PORT_GONE as exc:
            raise self._gone(exc) from None
        if data:
            self.rx_trace += data
        return data

    def writePort(self, packet):  # noqa: N802 (SDK name)
        try:
            return super().writePort(packet)
        except PORT_GONE as exc:
            raise self._gone(exc) from None

    def clearPort(self):  # noqa: N802 (SDK name)
        try:
            super().clearPort()
        except PORT_GONE as exc:
            raise self._gone(exc) from None

    def _gone(self, exc: BaseException) -> PortGone:
        """The error of a port that failed under the driver (a USB adapter unplugged, a pty
        whose server stopped): one line, no pyserial/termios traceback."""
        self.gone = True
        return PortGone(f"{self.getPortName()} stopped working ({exc}): was the adapter "
                        "unplugged or the emulator stopped? Nothing more was sent; plug it in "
                        "and run the command again")

    def deadline(self) -> float:
        """Bus time [s] at which the current SDK timeout expires."""
        return (self.packet_start_time + self.packet_timeout) / 1000.0

    def now(self) -> float:
        """Port clock [s] (monotonic)."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)

    @property
    def is_emulated(self) -> bool:
        return False


class EmulatedSerial:
    """The duck-typed pyserial object ``EmulatedPort`` installs; an ``EmulatedChain`` answers."""

    def __init__(self, chain: WireDevice, port: EmulatedPort, baudrate: int):
        self.chain, self.port, self.baudrate = chain, port, baudrate
        self._pending: list[Reply] = []
        self._ready = bytearray()
        self._line_free = 0.0
        self.is_open = True

    def _sync(self) -> None:
        clock = self.chain.clock
        self.chain.advance_to(clock.now())
        now = clock.now()
        while self._pending and self._pending[0].time <= now:
            self._ready += heapq.heappop(self._pending).data

    def write(self, data) -> int:
        data = bytes(data)
        clock = self.chain.clock
        wire = wire_time(len(data), self.baudrate) if self.chain.wire_time else 0.0
        t_in = max(clock.now(), self._line_free) + wire
        clock.advance_to(t_in)  # virtual: the host's bytes take their wire time
        self._sync()
        replies = self.chain.handle(data, t_in, self.baudrate)
        for r in replies:
            heapq.heappush(self._pending, r)
        self._line_free = max([t_in] + [r.time for r in replies if not r.late])
        return len(data)

    def read(self, size: int = 1) -> bytes:
        self._sync()
        clock = self.chain.clock
        if not self._ready and clock.virtual:
            now = clock.now()
            nxt = self._pending[0].time if self._pending else float("inf")
            deadline = self.port.deadline()
            t = min(nxt, deadline + 1e-6 if deadline > now else now + _POLL)
            clock.advance_to(max(t, now + 1e-9))
            self._sync()
        out = bytes(self._ready[:size])
        del self._ready[:size]
        return out

    @property
    def in_waiting(self) -> int:
        self._sync()
        return len(self._ready)

    def reset_input_buffer(self) -> None:
        self._sync()
        self._ready.clear()

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.is_open = False


class EmulatedPort(DxlPort):
    """An in-process ``PortHandler`` whose serial object is an ``EmulatedChain``.

    Args:
      chain: the emulated devices.
      latency_ms: latency timer the SDK timeouts assume [ms].
    """

    def __init__(self, chain: WireDevice, latency_ms: float = 1.0):
        super().__init__(f"emulated:{chain.hand.name}", latency_ms)
        self.chain = chain

    def setupPort(self, cflag_baud):  # noqa: N802 (SDK name)
        if self.is_open:
            self.closePort()
        self.ser = EmulatedSerial(self.chain, self, self.baudrate)
        self.is_open = True
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True

    def getCurrentTime(self):  # noqa: N802 (SDK name)
        return self.chain.clock.now() * 1000.0

    def now(self) -> float:
        return self.chain.clock.now()

    def sleep(self, seconds: float) -> None:
        if seconds <= 0:
            return
        clock = self.chain.clock
        if clock.virtual:
            clock.advance_to(clock.now() + seconds)
        else:
            time.sleep(seconds)
        self.chain.advance_to(clock.now())

    @property
    def is_emulated(self) -> bool:
        return True


def usb_latency_timer(port_name: str, sysfs: Path = SYSFS_USB_SERIAL) -> int | None:
    """The USB-serial latency timer [ms] of a tty (e.g. /dev/ttyUSB0), or None if not USB serial."""
    try:
        tty = Path(os.path.realpath(port_name)).name
        return int((sysfs / tty / "latency_timer").read_text().strip())
    except (OSError, ValueError):
        return None


LATENCY_ADVICE = (
    "set it to 1 ms: `echo 1 | sudo tee {path}`, or permanently with a udev rule "
    '`ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", ATTR{{latency_timer}}="1"`; '
    "with the default 16 ms every read waits for the timer and a 500 Hz loop runs at ~50 Hz")
