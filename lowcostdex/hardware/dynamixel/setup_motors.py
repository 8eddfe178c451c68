"""Motors out of the box to a hand: assign each Dynamixel its id and baud rate, one at a time.

New X-series motors all answer as id 1 at 57,600 bps (e-Manual: ID(7) initial value 1, Baud
Rate(8) initial value 1 = 57,600 bps), so they must be set up alone on the bus before they can
share it. ``setup_motors`` asks the person to connect one motor at a time, finds it at any baud
rate the SDK can speak (unicast pings of its target id and of id 1 first, a broadcast ping when
those are silent), refuses when more than one motor answers or when the motor already carries
another of the hand's ids, writes ID (7) then Baud Rate (8) with torque off, verifies both at the
new baud rate and ends with a scan of the whole hand.

Every transaction is retried when its reply is missing, garbled or mixed with another: after a
failure the next request waits ``settle_ms`` so a late reply arrives and is flushed (the SDK's
``clearPort``) instead of being taken for the next reply, and a read-back that disagrees is read
again (a late reply disagrees once, a motor that really holds another value every time). On the
emulated pty at load 10 on 2 cores, without these, 3 runs of 3 failed (a timed-out torque-off
write; "Baud Rate reads 22": the late reply of the ID read taken for the baud read).

The wire work runs on the unmodified ``dynamixel_sdk`` (a ``transport.DxlPort``), so it is the
same against a U2D2, the emulator on a pty or the in-process emulator.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS, PacketHandler

from lowcostdex.errors import ConfigError
from lowcostdex.hands import HandSpec, JointSpec
from lowcostdex.hardware.bus import BusError
from lowcostdex.hardware.dynamixel import transport
from lowcostdex.hardware.dynamixel.control_table import Reg, load_control_table, model_name
from lowcostdex.hardware.dynamixel.protocol import BAUD_CODES, HEADER, baud_code

FACTORY_ID = 1  # e-Manual ID(7) initial value
FACTORY_BAUD = 57_600  # e-Manual Baud Rate(8) initial value 1
# Baud rates searched after the target: the factory rate first, then the other X-series rates
# the SDK accepts (4.5 Mbps, code 7, is refused by dynamixel_sdk's PortHandler).
SEARCH_BAUDS = (FACTORY_BAUD, 1_000_000, 115_200, 2_000_000, 3_000_000, 4_000_000, 9_600)


class SetupError(BusError):
    """The motor on the bus is not one this step can set up; the message says what to do."""


@dataclass(frozen=True)
class Found:
    """A motor found alone on the bus."""

    motor_id: int
    baudrate: int
    model_number: int

    @property
    def model(self) -> str:
        return model_name(self.model_number)


@dataclass(frozen=True)
class SetupResult:
    """One joint's motor: where it was found and what it is now."""

    joint: str
    motor_id: int
    found: Found
    changed: bool


class MotorSetup:
    """The bus side of the set-up: find a lone motor, give it an id and a baud rate, verify.

    Args:
      port: device path or a ``transport.DxlPort`` (e.g. ``EmulatedChain.port()``).
      latency_ms: USB latency timer the SDK timeouts assume [ms] (16 = the Linux default).
      retries: extra attempts of a transaction that failed (no reply, garbled, or a read-back
        that disagrees).
      settle_ms: wait before the next transaction after a failed one [ms].
    """

    def __init__(self, port: str | transport.DxlPort, latency_ms: float = 16.0,
                 retries: int = 3, settle_ms: float = 50.0):
        self.port = transport.DxlPort(port, latency_ms) if isinstance(port, str) else port
        self.ph = PacketHandler(2.0)
        self.retries = retries
        self.settle_ms = settle_ms
        self._baud: int | None = None
        self._dirty = False

    def _begin(self) -> None:
        """Before a transaction: after a failed one, let late replies arrive (the SDK flushes
        them when it sends)."""
        if self._dirty:
            self.port.sleep(self.settle_ms / 1000.0)
            self._dirty = False
        self.port.is_using = False
        self.port.rx_trace.clear()

    def _end(self, ok: bool, expected_headers: int = 1) -> bool:
        """After a transaction: clean if it succeeded, consumed exactly the status packets it
        asked for and left nothing waiting; else the next one settles first."""
        clean = (ok and self.port.rx_trace.count(HEADER) == expected_headers
                 and self.port.getBytesAvailable() == 0)
        self._dirty = self._dirty or not clean
        return clean

    def open(self, baudrate: int) -> None:
        if not self.port.is_open:
            self.port.baudrate = baudrate
            try:
                opened = self.port.openPort()
            except Exception as exc:  # pyserial's SerialException / OSError
                raise BusError(f"cannot open {self.port.getPortName()}: {exc}") from exc
            if not opened:
                raise BusError(f"cannot open {self.port.getPortName()} at {baudrate} bps")
            self._baud = baudrate
        if self._baud != baudrate:
            # every byte sent at the old rate leaves first (tcdrain; on a pty: until the
            # emulator has read it, or it would hear the packet at the new rate)
            self.port.ser.flush()
            if not self.port.setBaudRate(baudrate):
                raise BusError(f"{self.port.getPortName()}: cannot set {baudrate} bps")
            self._baud = baudrate
            self._dirty = True  # bytes of the old rate may still be on their way

    def close(self) -> None:
        if self.port.is_open:
            self.port.is_using = False
            self.port.closePort()
        self._baud = None

    def _ping(self, motor_id: int) -> tuple[int | None, int]:
        self._begin()
        model, result, _ = self.ph.ping(self.port, motor_id)
        ok = self._end(result == COMM_SUCCESS)
        return (model if ok else None), result

    def find(self, ids: Sequence[int], bauds: Sequence[int]) -> Found | None:
        """The lone motor on the bus, or None if nothing answers at any rate.

        Raises:
          SetupError: more than one motor answers, or replies are garbled (several motors with
            one id answering at once).
        """
        bauds = list(dict.fromkeys(bauds))
        for b in bauds:  # fast: unicast pings of the likely ids
            self.open(b)
            for i in dict.fromkeys(ids):
                model, result = self._ping(i)
                if result == COMM_RX_CORRUPT:
                    raise SetupError(f"garbled reply from id {i} at {b} bps: several motors "
                                     "with the same id are connected; connect only one motor")
                if model is not None:
                    return self._alone(Found(i, b, model))
        for b in bauds:  # slow: broadcast ping (any id)
            self.open(b)
            found = self._broadcast()
            if found:
                motor_id, model = next(iter(found.items()))
                return self._alone(Found(motor_id, b, model), found)
        return None

    def _broadcast(self) -> dict[int, int]:
        self._begin()
        found, _ = self.ph.broadcastPing(self.port)
        self._dirty = True  # it waits out every id's slot; stragglers are flushed next time
        return {i: v[0] for i, v in sorted(found.items())}

    def _alone(self, motor: Found, found: dict[int, int] | None = None) -> Found:
        found = self._broadcast() if found is None else found
        others = sorted(set(found) - {motor.motor_id})
        if others:
            ids = ", ".join(str(i) for i in [motor.motor_id, *others])
            raise SetupError(f"{len(others) + 1} motors answer at {motor.baudrate} bps (ids "
                             f"{ids}): connect only the one motor being set up")
        return motor

    def assign(self, motor: Found, motor_id: int, baudrate: int) -> None:
        """Torque off, write ID then Baud Rate (EEPROM), verify both at ``baudrate``; when the
        verification fails, find the motor again (at its old or new id and rate: a write may
        not have landed) and repeat, up to ``retries`` times."""
        for attempt in range(self.retries + 1):
            try:
                self._assign_once(motor, motor_id, baudrate)
                return
            except SetupError:
                if attempt == self.retries:
                    raise
                again = self.find((motor_id, motor.motor_id), (motor.baudrate, baudrate))
                if again is None or again.model_number != motor.model_number:
                    raise
                motor = again

    def _assign_once(self, motor: Found, motor_id: int, baudrate: int) -> None:
        table = load_control_table(motor.model_number)
        self.open(motor.baudrate)
        self._write(motor.motor_id, table.address(Reg.TORQUE_ENABLE), 0, "torque off")
        # Whether the status packet of an ID or Baud Rate write comes from the old or the new id
        # and at which rate is not documented: a missing reply is not an error here, a refusal
        # (error byte) is, and the read-back at the new id and rate below is what counts.
        if motor.motor_id != motor_id:
            self._write(motor.motor_id, table.address(Reg.ID), motor_id, f"ID := {motor_id}",
                        reply_optional=True)
        if motor.baudrate != baudrate:
            self._write(motor_id, table.address(Reg.BAUD_RATE), baud_code(baudrate),
                        f"Baud Rate := {baud_code(baudrate)}", reply_optional=True)
        self.verify(motor_id, baudrate, motor.model_number)

    def verify(self, motor_id: int, baudrate: int, model_number: int) -> None:
        """The motor answers as ``motor_id`` at ``baudrate`` with those registers set."""
        table = load_control_table(model_number)
        self.open(baudrate)
        model = None
        for _ in range(self.retries + 1):
            model, _ = self._ping(motor_id)
            if model is not None:
                break
        if model != model_number:
            raise SetupError(f"after writing, no {model_name(model_number)} answers as id "
                             f"{motor_id} at {baudrate} bps; check the cable and run again")
        for reg, want in ((Reg.ID, motor_id), (Reg.BAUD_RATE, baud_code(baudrate))):
            read = None
            for _ in range(self.retries + 1):
                self._begin()
                value, result, err = self.ph.read1ByteTxRx(self.port, motor_id,
                                                           table.address(reg))
                if self._end(result == COMM_SUCCESS):
                    read = (value, err)
                    if value == want and not err & 0x7F:
                        break
                    self._dirty = True  # perhaps a late reply: read again
            if read is None:
                raise SetupError(f"motor {motor_id}: reading {reg.value} failed "
                                 f"({self.ph.getTxRxResult(result)}); check the cable")
            value, err = read
            if err & 0x7F or value != want:
                raise SetupError(f"motor {motor_id}: {reg.value} reads {value}, expected {want}")

    def _write(self, motor_id: int, address: int, value: int, what: str,
               reply_optional: bool = False) -> None:
        """One register write; retried without a clean reply unless ``reply_optional`` (an ID
        or Baud Rate write, whose reply may come from the new id or rate: written once)."""
        for _ in range(1 if reply_optional else self.retries + 1):
            self._begin()
            result, err = self.ph.write1ByteTxRx(self.port, motor_id, address, value)
            clean = self._end(result == COMM_SUCCESS)
            if reply_optional and result == COMM_RX_TIMEOUT:
                return
            if result == COMM_SUCCESS and err & 0x7F:
                break  # the motor refused: no retry changes that
            if clean:
                return
        raise SetupError(f"motor {motor_id}: {what} failed "
                         f"({self.ph.getTxRxResult(result)}, error {err:#04x})")


def setup_motors(port: str | transport.DxlPort, hand: HandSpec, *, baudrate: int = 1_000_000,
                 ids: Sequence[int] | None = None,
                 prompt: Callable[[JointSpec], None] = lambda joint: None,
                 say: Callable[[str], None] = print, reassign: bool = False,
                 latency_ms: float = 16.0) -> list[SetupResult]:
    """Set up the hand's motors one at a time, then scan the whole hand.

    Args:
      port: the adapter's device path or a ``transport.DxlPort``.
      hand: the hand (joint names, motor ids, motor model).
      baudrate: the rate every motor is set to [bit/s] (a Baud Rate register value's rate).
      ids: set up only these of the hand's ids (default all).
      prompt: called before each motor with its joint; returns once that motor (alone) is
        connected and powered (the CLI asks the person and waits for Enter).
      say: progress messages.
      reassign: accept a motor that carries another of the hand's ids (give it this joint's).
      latency_ms: the adapter's USB latency timer [ms].

    Returns:
      One ``SetupResult`` per motor, in the hand's order.

    Raises:
      SetupError: a motor cannot be set up (none found, several on the bus, wrong model, already
        another joint's id); ``ConfigError`` for ids or a rate the hand or the motors do not have.
    """
    if baudrate not in BAUD_CODES.values() or baudrate == 4_500_000:
        raise ConfigError(f"baud rate {baudrate}: one of "
                          f"{sorted(set(BAUD_CODES.values()) - {4_500_000})}")
    joints = list(hand.all_joints)
    hand_ids = [j.motor_id for j in joints]
    if ids is not None:
        unknown = sorted(set(ids) - set(hand_ids))
        if unknown:
            raise ConfigError(f"ids {unknown} are not in hand {hand.name} (ids {hand_ids})")
        joints = [j for j in joints if j.motor_id in ids]
    expected = load_control_table(hand.motor).model_number
    bus = MotorSetup(port, latency_ms)
    results: list[SetupResult] = []
    done: dict[int, str] = {}
    try:
        for joint in joints:
            target = joint.motor_id
            bus.close()  # the person unplugs and plugs: start from a fresh port
            prompt(joint)
            say(f"{joint.name} (id {target}): searching ...")
            motor = bus.find((target, FACTORY_ID), (baudrate, *SEARCH_BAUDS))
            if motor is None:
                raise SetupError(f"{joint.name}: no motor answers at any baud rate "
                                 f"({', '.join(str(b) for b in (baudrate, *SEARCH_BAUDS))}); "
                                 "check power (12 V for X430) and the cable, then run again "
                                 f"with --ids {target}")
            if motor.model_number != expected:
                raise SetupError(f"{joint.name}: found a {motor.model} (id {motor.motor_id}), the "
                                 f"hand spec wants {hand.motor}; connect the right motor")
            if motor.motor_id in done:
                raise SetupError(f"{joint.name}: this motor was just set up as id "
                                 f"{motor.motor_id} ({done[motor.motor_id]}); disconnect it and "
                                 f"connect the motor for {joint.name}")
            if motor.motor_id != target and motor.motor_id in hand_ids and not reassign:
                other = hand_ids.index(motor.motor_id)
                raise SetupError(
                    f"{joint.name}: the motor found already has id {motor.motor_id}, the id of "
                    f"{hand.all_joints[other].name}; two motors must not share an id. Connect "
                    f"a new motor for {joint.name}, or run with --reassign to give this one id "
                    f"{target}")
            changed = (motor.motor_id, motor.baudrate) != (target, baudrate)
            bus.assign(motor, target, baudrate)
            done[target] = joint.name
            results.append(SetupResult(joint.name, target, motor, changed))
            say(f"{joint.name}: id {motor.motor_id} at {motor.baudrate} bps -> id {target} at "
                f"{baudrate} bps, verified" if changed else
                f"{joint.name}: already id {target} at {baudrate} bps, verified")
    finally:
        bus.close()
    return results


def check_hand(found: Sequence, hand: HandSpec, ids: Sequence[int] | None = None) -> list[str]:
    """Problems of a scan (``dynamixel.scan`` output) of the whole hand: missing ids, ids the
    hand does not have, wrong models."""
    want = {j.motor_id: j.name for j in hand.all_joints
            if ids is None or j.motor_id in ids}
    got = {m.motor_id: m for m in found}
    out = [f"id {i} ({want[i]}) does not answer" for i in sorted(set(want) - set(got))]
    out += [f"id {i} answers but is not one of the hand's ids" for i in sorted(set(got) - set(want))
            if ids is None]
    out += [f"id {i} is a {got[i].model}, the hand spec wants {hand.motor}"
            for i in sorted(set(want) & set(got)) if got[i].model != hand.motor]
    return out
