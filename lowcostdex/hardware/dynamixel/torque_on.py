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
"""Fresh read -> goal -> torque attempts per motor: this times (``retries`` + 1) (16 by default;
at 30 % lost or corrupt status packets one attempt succeeds with 0.7^3 = 0.34, all 16 fail
with 0.66^16 = 0.1 %)."""


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
    attempts = ATTEMPTS_PER_RETRY * (bus.config.retries + 1)
    for _ in range(attempts):
        valid, _, raw = bus._read_block((motor_id,), fast=False)
        bus._stale((motor_id,), valid, raw, bus._sample_time)
        if not valid[motor_id]:
            continue
        if bus.config.realtime_tick:
            bus._ticks[motor_id] = (bus._sample_time, bus._tick(raw[motor_id]))
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
