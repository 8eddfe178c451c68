"""Torque off confirmed, and torque on without a jump.

Torque off (``disable_confirmed``): Torque Enable := 0 with its status checked; a motor whose
statuses were all lost (the write itself may well have landed) gets the write again in one
SYNC_WRITE, which needs no status, and is confirmed by reading Torque Enable back. Without this
the thermal guard's relaxation of a hot motor raised BusError out of ``Robot.step`` after 4 lost
statuses (1 in 125 at 30 % lost or corrupt status packets), ending the run although the motor
was off.

Torque on: each motor's Goal Position := its present position read just before,
then Torque Enable, as one tight sequence per motor.

A motor with torque off moves on its own (a limp finger falls or coasts after a thermal pause or
a torque-off; a watchdog-stopped one settles), so a goal set from a reading taken earlier - the
first of several read attempts, or before the other motors' writes and their retries - sends the
motor back to where it was: on a bus losing 20 % of its status packets the emulated D'Claw's
motors received torque-on goals up to 0.33 rad from where they were, 120 ms after the reading
(device side, ``EmulatedChain.goal_audit``). Here each attempt is one read of that motor, one
Goal Position write and one Torque Enable write, each tried once; any lost or corrupt reply
starts the motor over with a fresh read, so a goal reaches its motor one clean read and one
write after its sample (at most 0.49 ms in the emulated soaks at 1 Mbit/s), whatever the bus
loses.
"""

from __future__ import annotations

from typing import Any

from lowcostdex.hardware.bus import BusError, MotorFault
from lowcostdex.hardware.dynamixel.config import InstructionError, PositionOutOfLimits
from lowcostdex.hardware.dynamixel.control_table import Reg
from lowcostdex.hardware.dynamixel.protocol import ALERT, hardware_error_names

DynamixelBus = Any  # ``driver.DynamixelBus`` (imported there, so not imported here)

ATTEMPTS_PER_RETRY = 4
"""Tries of each single transaction of a torque change: this times (``retries`` + 1) (16 by
default; at 30 % lost or corrupt status packets all 16 fail with 0.3^16 = 4e-9)."""
SEQUENCES_PER_RETRY = 16
"""Fresh read -> goal -> torque attempts per motor: this times (``retries`` + 1) (64 by default;
at 30 % lost or corrupt status packets one attempt succeeds with 0.7^3 = 0.34, all 64 fail
with 0.66^64 = 3e-12; with 16 attempts, 1 re-enable of 9 motors in 80 failed)."""


def torque_on_attempts(bus: DynamixelBus) -> int:
    """Attempts of each transaction of a torque change (``ATTEMPTS_PER_RETRY`` x
    (``retries`` + 1)): a run that learns for hours turns torque on after every pause and
    watchdog stop, and with 4 tries the set-up reads and writes of 9 motors failed in 1 of 6
    re-enables at 30 % lost or corrupt status packets (each caller had to retry)."""
    return ATTEMPTS_PER_RETRY * (bus.config.retries + 1)


def disable_confirmed(bus: DynamixelBus, ids: tuple[int, ...]) -> list[str]:
    """Torque off for ``ids``, each confirmed (see the module docstring); returns the motors not
    confirmed off, each with the reason."""
    failed: dict[int, BusError] = {}
    for i in ids:
        try:
            bus.write_register(i, Reg.TORQUE_ENABLE, 0)
            bus._torque_ids.discard(i)
        except BusError as exc:
            failed[i] = exc
    if not failed:
        return []
    for _ in range(ATTEMPTS_PER_RETRY):
        params = [b for i in failed for b in (i, 0)]
        bus._begin()
        bus.ph.syncWriteTxOnly(bus.port, bus._addr[Reg.TORQUE_ENABLE], 1, params, len(params))
        for i in list(failed):
            try:
                if bus.read_register(i, Reg.TORQUE_ENABLE) == 0:
                    bus._torque_ids.discard(i)
                    del failed[i]
            except BusError as exc:
                failed[i] = exc
        if not failed:
            break
    return [f"{i}: {exc}" for i, exc in failed.items()]


def hold_goal(bus: DynamixelBus, motor_id: int, present: int) -> int:
    """The Goal Position [ticks] that holds a motor at ``present`` (within one turn in position
    mode); raises PositionOutOfLimits when it sits outside its limits."""
    k = bus._index[motor_id]
    g = present % int(bus._tpr[k]) if bus.config.operating_mode == 3 else present
    if not bus._lo[k] <= g <= bus._hi[k]:
        raise PositionOutOfLimits(
            f"motor {motor_id} is at tick {g}, outside its limits [{bus._lo[k]}, {bus._hi[k]}];"
            " move it inside (torque off) before enabling torque")
    return g


def enable_holding(bus: DynamixelBus, motor_id: int) -> None:
    """Goal := present (read in the same attempt), then torque on, for one motor (see the module
    docstring). Raises MotorFault when the motor refuses because of a latched hardware error,
    PositionOutOfLimits when it sits outside its limits, BusError when every attempt lost a
    reply."""
    attempts = SEQUENCES_PER_RETRY * (bus.config.retries + 1)
    for _ in range(attempts):
        valid, _, raw = bus._read_block((motor_id,), fast=False)
        if not valid[motor_id]:
            continue
        goal = hold_goal(bus, motor_id, bus._position_ticks(raw[motor_id]))
        try:
            bus.write_register(motor_id, Reg.GOAL_POSITION, goal, tries=1)
            bus.write_register(motor_id, Reg.TORQUE_ENABLE, 1, tries=1)
        except InstructionError as exc:
            if exc.error & ALERT:
                bits = bus.read_register(motor_id, Reg.HARDWARE_ERROR_STATUS)
                bus._note_hardware_error(motor_id, bits)
                raise MotorFault(motor_id, hardware_error_names(bits),
                                 f"motor {motor_id} refused torque: latched hardware error "
                                 f"({', '.join(hardware_error_names(bits))}); reboot it"
                                 ) from exc
            raise
        except BusError:
            continue  # a reply lost: read again, so the goal is never older than one attempt
        return
    raise BusError(f"motor {motor_id}: torque on failed in {attempts} attempts (fresh read, "
                   "Goal Position := present, Torque Enable): a reply was lost in each")


def arm_watchdog(bus: DynamixelBus, ids: tuple[int, ...]) -> None:
    """Arm the Bus Watchdog (``config.watchdog_ms``) of every motor in ``ids`` that has one.

    A broadcast SYNC_WRITE (no status) arms them all together, then each motor not yet confirmed
    is read back; the SYNC_WRITE is sent again before every read, so no timer runs out while the
    others are confirmed. (Unicast write retries after a failed sync read let the first motors'
    100 ms run out on a bus losing 30 % of its statuses: the next write raised "data range
    error"; one SYNC_WRITE per round of 9 reads did too, once, after 100 ms of timeouts.)
    Raises BusError naming the motors not confirmed after ``torque_on_attempts`` reads each."""
    wd = bus.config.watchdog_ms // 20
    ids = bus._watchdog_ids(ids)
    if not wd or not ids:
        return
    addr = bus._addr[Reg.BUS_WATCHDOG]
    params = [b for i in ids for b in (i, wd)]
    reads = torque_on_attempts(bus)

    def sync_write() -> None:
        bus._begin()
        bus.ph.syncWriteTxOnly(bus.port, addr, 1, params, len(params))

    sync_write()
    valid, _, raw = bus._sync_read(ids, addr, 1, fast=False)
    todo = [i for i in ids if not (valid[i] and raw[i][0] == wd)]
    for _ in range(reads - 1):
        for i in list(todo):
            sync_write()
            if bus._try_read(i, addr, 1) == wd:
                todo.remove(i)
        if not todo:
            return
    if todo:
        raise BusError(f"motors {todo}: Bus Watchdog ({wd * 20} ms) not confirmed armed in "
                       f"{reads} reads (SYNC_WRITE, read back): a reply was lost in each")
