"""Recording joint calibration offsets from a hand held in a known pose.

With the hand in its reference pose (default: every joint at 0 rad) and torque off, each joint's
offset is solved from ``q_joint = sign * scale * q_motor + offset`` (``hands.Calibration``) using
the median of ``samples`` reads of the motor angle; sign and scale are kept from the spec. Nothing
is written to the motors (no Homing Offset in EEPROM): the result is a hand spec JSON the Robot
loads.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from lowcostdex.hands import HandSpec, JointSpec
from lowcostdex.hardware.bus import BusError, MotorBus


def calibrate_offsets(bus: MotorBus, hand: HandSpec, reference: dict[str, float] | None = None,
                      samples: int = 20) -> HandSpec:
    """A copy of ``hand`` whose offsets make the present pose read as ``reference``.

    Args:
      bus: a connected bus whose ``ids`` include every motor of ``hand``.
      hand: the spec to start from (sign and scale are kept).
      reference: joint name -> angle [rad] of the pose the hand is held in (default 0 for all).
      samples: reads per joint; the median motor angle is used.

    Raises:
      BusError: a motor never gave a valid reading.
    """
    reference = reference or {}
    index = {i: k for k, i in enumerate(bus.ids)}
    reads = []
    for _ in range(samples):
        s = bus.read_state()
        reads.append(np.where(s.valid, s.position, np.nan))
    angles = np.array(reads)  # (samples, n)

    def update(j: JointSpec) -> JointSpec:
        col = angles[:, index[j.motor_id]]
        if np.all(np.isnan(col)):
            raise BusError(f"motor {j.motor_id} ({j.name}) gave no valid reading")
        q_motor = float(np.nanmedian(col))
        c = j.calibration
        offset = reference.get(j.name, 0.0) - c.sign * c.scale * q_motor
        return dataclasses.replace(j, calibration=dataclasses.replace(c, offset=offset))

    return dataclasses.replace(hand, joints=tuple(update(j) for j in hand.joints),
                               aux_joints=tuple(update(j) for j in hand.aux_joints))


def format_report(old: HandSpec, new: HandSpec) -> str:
    """A table of old and new offsets per joint [rad]."""
    rows = [f"{'joint':<12} {'id':>3} {'old offset':>11} {'new offset':>11} {'change':>8}"]
    for a, b in zip(old.all_joints, new.all_joints, strict=True):
        d = b.calibration.offset - a.calibration.offset
        rows.append(f"{a.name:<12} {a.motor_id:>3} {a.calibration.offset:>11.4f} "
                    f"{b.calibration.offset:>11.4f} {d:>+8.4f}")
    return "\n".join(rows)
