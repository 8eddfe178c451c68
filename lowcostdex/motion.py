"""The per-step motion bound where the goal arrives: one rule for the robot and the simulation.

A goal may lead the joint's position by ``max_step`` (max_velocity x control period), but the
joint keeps moving between its position's sample and the goal's arrival at the motor (the read's
replies, the goal's write, a retried read, a settle wait, the host's own computing). So the bound
is narrowed by what the joint may move in that time (``in_flight_step``): the Robot
(``hardware.robot``) narrows by the time it measures on its bus, the simulation
(``sim.envs.hand_env``) and everything that plans for it by the time a clean bus takes
(``clean_in_flight``), so on a clean bus the policy trains with the bound the robot applies.

Core: hand specs and motor data only (``lowcostdex.hands``, ``lowcostdex.motors``); the Dynamixel
packet sizes and the wire time the driver uses live here too, so the driver and the simulation
compute the same clean-bus time.
"""

from __future__ import annotations

import numpy as np

from lowcostdex.hands import HandSpec
from lowcostdex.motors import MOTORS

MOTOR_SPEED_MARGIN = 1.5
"""The fastest a joint moves, over its motor's no-load speed: a joint pushed by contacts or by its
finger's swing moves faster than its motor drives it (measured 1.29x in the emulated D'Claw
fault soak, tests/test_robot_faults.py)."""

USB_FRAME = 1e-3
"""[s] one USB frame: what a USB-serial adapter (U2D2) may hold a packet before the wire."""

PRESENT_BLOCK_BYTES = 21
"""Bytes of the Dynamixel X-series block read every control step: Present Current (address 126)
through Present Temperature (146), e-Manual control table (the driver's ``BLOCK``; its test
checks the two agree)."""

DEFAULT_BAUDRATE = 1_000_000
"""The D'Claw's bus rate [bit/s] (``DynamixelConfig.baudrate``)."""


def wire_time(nbytes: int, baudrate: float) -> float:
    """Time [s] to transmit ``nbytes`` at ``baudrate`` with 8N1 framing (10 bits per byte)."""
    return 10.0 * nbytes / baudrate


def sync_read_bytes(n: int, length: int, fast: bool = False) -> tuple[int, int]:
    """(instruction, reply) bytes on the wire of a (fast) sync read of ``length`` bytes from n ids
    (Protocol 2.0)."""
    inst = 14 + n
    reply = 8 + n * (length + 4) if fast else n * (11 + length)
    return inst, reply


def sync_write_bytes(n: int, length: int) -> int:
    """Bytes on the wire of a sync write of ``length`` bytes to n ids (Protocol 2.0)."""
    return 14 + n * (1 + length)


def goal_write_time(n: int, baudrate: float) -> float:
    """Upper bound [s] from handing a Goal Position sync write for ``n`` motors to the adapter
    until the motors have it: the packet's wire time (14 + 5 n bytes) and one USB frame."""
    return wire_time(sync_write_bytes(n, 4), baudrate) + USB_FRAME


def read_reply_time(n: int, length: int, baudrate: float, fast: bool) -> float:
    """Wire time [s] of the replies to one sync read of ``length`` bytes from ``n`` motors
    answering at once (Return Delay Time 0)."""
    return wire_time(sync_read_bytes(n, length, fast)[1], baudrate)


def clean_in_flight(n_read: int, n_goals: int, length: int = PRESENT_BLOCK_BYTES,
                    baudrate: float = DEFAULT_BAUDRATE) -> float:
    """Time [s] from the motors' sample of their present block until goals for ``n_goals`` of
    them arrive on a clean bus (no retry, no settle wait, no host time): the fast sync read's
    replies from ``n_read`` motors, then the goal write. The D'Claw (10 motors, 9 goals):
    2.58 + 0.59 + 1 = 4.17 ms."""
    return read_reply_time(n_read, length, baudrate, fast=True) + goal_write_time(n_goals,
                                                                                  baudrate)


def motor_speed(hand: HandSpec) -> float:
    """Fastest motor speed [rad/s, motor angle]: ``MOTOR_SPEED_MARGIN`` x the hand's motor's
    no-load speed (``motors.MotorSpec``); 0 (no narrowing) for a hand whose motors have no spec
    (the Allegro)."""
    spec = MOTORS.get(hand.motor)
    return 0.0 if spec is None else MOTOR_SPEED_MARGIN * spec.no_load_speed


def joint_speeds(hand: HandSpec) -> np.ndarray:
    """``motor_speed`` seen at each joint (``hand.all_joints`` order) [rad/s]."""
    v = motor_speed(hand)
    return np.array([abs(j.calibration.rate_to_joint(v)) for j in hand.all_joints])


def in_flight_step(max_step: np.ndarray, speed: np.ndarray, elapsed: np.ndarray | float
                   ) -> np.ndarray:
    """The per-step motion bound (n,) [rad] narrowed by what each joint may move (``speed``
    [rad/s]) in ``elapsed`` [s] from its position's sample to its goal's arrival, so the goal
    leads the position by at most ``max_step`` where it arrives; 0 where nothing is left (the
    joint holds)."""
    return np.maximum(max_step - speed * np.maximum(elapsed, 0.0), 0.0)


def motion_bound(hand: HandSpec, period: float, n_motors: int) -> np.ndarray:
    """The per-step motion bound [rad] of the hand's action joints (n,) as the simulation and
    everything that plans for it apply it: ``max_velocity`` x ``period`` [s], narrowed for a
    clean bus of ``n_motors`` motors (the hand's joints and auxiliary motors); not narrowed for a
    hand without a motor spec."""
    n = len(hand.joints)
    elapsed = clean_in_flight(n_motors, n) if hand.motor in MOTORS else 0.0
    return in_flight_step(np.array([j.max_velocity for j in hand.joints]) * period,
                          joint_speeds(hand)[:n], elapsed)
