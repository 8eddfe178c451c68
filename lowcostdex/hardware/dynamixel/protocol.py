"""Dynamixel Protocol 2.0 on the wire: CRC-16, byte stuffing, packet building and parsing.

This is the *device-side* codec used by the emulator (``lowcostdex.hardware.emulated.chain``) and by tests.
The driver (``lowcostdex.hardware.dynamixel.driver``) does not use it to talk to motors: it runs
``dynamixel_sdk``'s own packet handler. The two sides meet only on the wire, which is the point.

Packet layout (all multi-byte fields little-endian)::

    instruction  FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAM ... | CRC_L CRC_H
    status       FF FF FD 00 | ID | LEN_L LEN_H | 0x55 | ERR | PARAM ... | CRC_L CRC_H

LEN counts INST (or 0x55), ERR, the *stuffed* params and the two CRC bytes. Stuffing inserts an
extra FD after every FF FF FD inside INST..params, so a header can never appear inside a body. The
CRC is CRC-16/BUYPASS (polynomial 0x8005, init 0, no reflection, no final xor) over everything from
the first header byte to the last stuffed param.

Wire time at 8N1 is 10 bits per byte: ``wire_time(n, baud) = 10 n / baud`` [s].
"""

from __future__ import annotations

import enum
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol

# the packet sizes and the wire time live in core (the simulation's motion bound uses them too)
from lowcostdex.errors import ConfigError
from lowcostdex.motion import sync_read_bytes, sync_write_bytes, wire_time  # noqa: F401

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
STATUS = 0x55
MAX_LENGTH = 1024  # largest LEN a parser accepts (the SDK's RXPACKET_MAX_LEN)
ALERT = 0x80  # status error bit 7: a hardware error is latched (not an instruction failure)


class Instruction(enum.IntEnum):
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class ErrorNumber(enum.IntEnum):
    """Instruction error number: bits 0-6 of a status packet's error byte."""

    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


class HardwareError(enum.IntFlag):
    """Hardware Error Status (address 70) bits; the same layout selects Shutdown (63) causes."""

    INPUT_VOLTAGE = 0x01
    OVERHEATING = 0x04
    MOTOR_ENCODER = 0x08
    ELECTRICAL_SHOCK = 0x10
    OVERLOAD = 0x20


_HW_NAMES = {
    HardwareError.INPUT_VOLTAGE: "input voltage",
    HardwareError.OVERHEATING: "overheating",
    HardwareError.MOTOR_ENCODER: "motor encoder",
    HardwareError.ELECTRICAL_SHOCK: "electrical shock",
    HardwareError.OVERLOAD: "overload",
}


def hardware_error_names(bits: int) -> tuple[str, ...]:
    """Names of the hardware errors set in a Hardware Error Status value (unknown bits by number)."""
    names = [name for flag, name in _HW_NAMES.items() if bits & flag]
    known = sum(int(f) for f in _HW_NAMES)
    names += [f"bit {b}" for b in range(8) if bits & ~known & (1 << b)]
    return tuple(names)


def status_error_text(error: int) -> str:
    """Human-readable meaning of a status packet's error byte."""
    parts = []
    num = error & 0x7F
    if num:
        try:
            parts.append(ErrorNumber(num).name.lower().replace("_", " ") + " error")
        except ValueError:
            parts.append(f"unknown error {num}")
    if error & ALERT:
        parts.append("alert (hardware error latched)")
    return ", ".join(parts) or "ok"


# -- CRC-16 ---------------------------------------------------------------------------------------


def _crc_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ poly) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


CRC_TABLE = _crc_table(0x8005)
_CRC_TABLE16: list[int] = []  # CRC of every 16-bit word: two bytes per step (built on first use)


def _crc_table16() -> list[int]:
    t = CRC_TABLE
    _CRC_TABLE16.extend(((t[v >> 8] << 8) & 0xFFFF) ^ t[(t[v >> 8] >> 8) ^ (v & 0xFF)]
                        for v in range(65536))
    return _CRC_TABLE16


def crc16(data: bytes | bytearray | Iterable[int], crc: int = 0) -> int:
    """CRC-16/BUYPASS of ``data`` continuing from ``crc``.

    Bytes are taken two at a time: for a 16-bit register, one step over a big-endian word w is
    ``crc = T16[crc ^ w]``, about four times faster in Python than the byte-wise table.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        data = bytes(data)
    n = len(data)
    if n >= 2:
        t16 = _CRC_TABLE16 or _crc_table16()
        for w in struct.unpack_from(f">{n // 2}H", data):
            crc = t16[crc ^ w]
    if n & 1:
        crc = ((crc << 8) & 0xFFFF) ^ CRC_TABLE[(crc >> 8) ^ data[-1]]
    return crc


# -- stuffing -------------------------------------------------------------------------------------

_UNSTUFFED = b"\xff\xff\xfd"
_STUFFED = b"\xff\xff\xfd\xfd"


def stuff(body: bytes) -> bytes:
    """Insert FD after every FF FF FD of a packet body (INST/0x55 onwards, CRC excluded)."""
    return body.replace(_UNSTUFFED, _STUFFED) if _UNSTUFFED in body else bytes(body)


def unstuff(body: bytes) -> bytes:
    """Remove the FD inserted by ``stuff``."""
    return body.replace(_STUFFED, _UNSTUFFED) if _STUFFED in body else bytes(body)


# -- building -------------------------------------------------------------------------------------


def _frame(packet_id: int, body: bytes) -> bytes:
    body = stuff(body)
    n = len(body) + 2
    head = HEADER + bytes((packet_id, n & 0xFF, n >> 8))
    out = head + body
    crc = crc16(out)
    return out + bytes((crc & 0xFF, crc >> 8))


def instruction_packet(packet_id: int, instruction: int, params: bytes = b"") -> bytes:
    """A complete, stuffed instruction packet."""
    return _frame(packet_id, bytes((instruction,)) + bytes(params))


def status_packet(packet_id: int, error: int = 0, params: bytes = b"") -> bytes:
    """A complete, stuffed status packet."""
    return _frame(packet_id, bytes((STATUS, error)) + bytes(params))


def fast_status_packet(slots: list[tuple[int, int, bytes]], count: int | None = None) -> bytes:
    """The single reply to FAST_SYNC_READ / FAST_BULK_READ (ID 0xFE), not stuffed.

    Layout: ``FF FF FD 00 FE LEN 55 | err1 id1 data1 crc1 | ... | errN idN dataN CRC``. Each
    intermediate crc is the running CRC of the packet so far; the last one is the packet CRC.

    Args:
      slots: (error, id, data) per device in instruction order.
      count: bytes the LEN field announces for the slots (default: their real size). A device that
        does not answer leaves its slot out while the first device announced it, which is how a
        missing motor shows up on the wire.
    """
    size = sum(len(d) + 4 for _, _, d in slots) if count is None else count
    n = 1 + size
    out = bytearray(HEADER + bytes((BROADCAST_ID, n & 0xFF, n >> 8, STATUS)))
    crc = crc16(out)
    for err, dev, data in slots:
        chunk = bytes((err, dev)) + bytes(data)
        crc = crc16(chunk, crc)
        out += chunk
        out += bytes((crc & 0xFF, crc >> 8))
        crc = crc16(out[-2:], crc)
    return bytes(out)


# -- parsing --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Packet:
    """A parsed packet (params un-stuffed).

    Attributes:
      id: packet id.
      instruction: instruction byte (0x55 for a status packet).
      params: parameters; for a status packet the error byte is ``params[0]``.
      crc_ok: False for a packet whose CRC did not match (params are then raw, untrusted).
      size: bytes the packet occupied on the wire.
    """

    id: int
    instruction: int
    params: bytes
    crc_ok: bool = True
    size: int = 0

    @property
    def error(self) -> int:
        """Status error byte (status packets only)."""
        return self.params[0]

    @property
    def data(self) -> bytes:
        """Status parameters after the error byte."""
        return self.params[1:]


class PacketReader:
    """Incremental parser: ``feed`` bytes, iterate complete packets.

    Garbage before a header is skipped. A packet whose CRC fails is reported once with
    ``crc_ok=False`` and the parser resynchronises one byte after its header.
    """

    def __init__(self) -> None:
        self.buffer = bytearray()

    def feed(self, data: bytes) -> None:
        self.buffer += data

    def clear(self) -> None:
        self.buffer.clear()

    def __iter__(self) -> Iterator[Packet]:
        buf = self.buffer
        while True:
            i = buf.find(HEADER)
            if i < 0:
                del buf[: max(0, len(buf) - 3)]
                return
            if i:
                del buf[:i]
            if len(buf) < 7:
                return
            length = buf[5] | (buf[6] << 8)
            if length < 3 or length > MAX_LENGTH:
                del buf[:1]
                continue
            total = 7 + length
            if len(buf) < total:
                return
            raw = bytes(buf[:total])
            if crc16(raw[:-2]) == (raw[-2] | (raw[-1] << 8)):
                del buf[:total]
                yield Packet(raw[4], raw[7], unstuff(raw[8:-2]), True, total)
            else:
                del buf[:1]
                yield Packet(raw[4], raw[7], raw[8:-2], False, total)


def parse_packets(data: bytes) -> list[Packet]:
    """All complete packets in ``data``."""
    reader = PacketReader()
    reader.feed(data)
    return list(reader)


# -- values ---------------------------------------------------------------------------------------


def to_signed(value: int, size: int) -> int:
    """Two's-complement decode of an unsigned ``size``-byte register value."""
    bits = 8 * size
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >> (bits - 1) else value


def to_unsigned(value: int, size: int) -> int:
    """Two's-complement encode of a signed value into ``size`` bytes; raises if it does not fit."""
    bits = 8 * size
    if not -(1 << (bits - 1)) <= value < (1 << bits):
        raise ValueError(f"{value} does not fit in {size} bytes")
    return value & ((1 << bits) - 1)


def le_bytes(value: int, size: int) -> bytes:
    """Little-endian bytes of a (possibly negative) register value."""
    return to_unsigned(value, size).to_bytes(size, "little")


BAUD_CODES: dict[int, int] = {0: 9600, 1: 57600, 2: 115200, 3: 1_000_000, 4: 2_000_000,
                              5: 3_000_000, 6: 4_000_000, 7: 4_500_000}
"""Baud Rate register (address 8) value -> bit rate [bit/s] (X-series)."""


def baud_code(baudrate: int) -> int:
    """Baud Rate register value of a bit rate; raises ConfigError (a ValueError) listing the
    supported rates."""
    for code, rate in BAUD_CODES.items():
        if rate == baudrate:
            return code
    raise ConfigError(f"unsupported baud rate {baudrate}; valid: {sorted(BAUD_CODES.values())}")


@dataclass(frozen=True)
class Reply:
    """A status packet on its way to the host: arrives (last byte) at bus time ``time`` [s];
    ``seq`` keeps packets due at the same time in the order they were sent."""

    time: float
    data: bytes
    late: bool = False
    seq: int = 0

    def __lt__(self, other: Reply) -> bool:
        return (self.time, self.seq) < (other.time, other.seq)


class WireDevice(Protocol):
    """What a transport (the in-process port, the pty server) needs from the devices on the far
    end of the wire. ``lowcostdex.hardware.emulated.chain.EmulatedChain`` is one; the transports depend
    on this interface, not on the emulator (no import circle between them).

    Attributes:
      clock: the bus clock (``now()``, ``virtual``, ``advance_to``).
      wire_time: whether bytes take their time on the wire (``wire_time(n, baud)``).
      baudrate: the devices' bit rate [bit/s].
      hand: the hand spec the devices belong to (its ``name`` labels the port).
      plant: the physics behind the devices (its ``model.opt.timestep`` paces a real-time server).
    """

    clock: Any
    wire_time: bool
    baudrate: int
    hand: Any
    plant: Any

    def handle(self, data: bytes, t_in: float, baudrate: int | None = None) -> list[Reply]:
        """The replies to the instruction bytes ``data`` that arrived at bus time ``t_in``."""
        ...

    def advance_to(self, t: float, max_steps: int | None = None) -> None:
        """Run the devices and their physics up to bus time ``t`` [s]."""
        ...
