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

from lowcostdex.errors import ConfigError, did_you_mean
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
      ConfigError: ``reference`` names a joint the hand does not have, or holds an angle that is
        not finite or outside the joint's limits (degrees given for radians?); ``samples`` is
        not a positive integer; the bus lacks one of the hand's motors. Checked before any read.
    """
    reference = _check_reference(hand, reference or {})
    if isinstance(samples, bool) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ConfigError(f"samples={samples!r} must be an integer >= 1 (reads per joint; "
                          "e.g. samples=20)")
    missing = [f"{j.name} (id {j.motor_id})" for j in hand.all_joints
               if j.motor_id not in bus.ids]
    if missing:
        raise ConfigError(f"the bus has no motor for {', '.join(missing)} (its ids: "
                          f"{list(bus.ids)}); make the bus from the same hand spec, e.g. "
                          "DynamixelBus.from_hand(hand, port)")
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


def _check_reference(hand: HandSpec, reference: dict[str, float]) -> dict[str, float]:
    """``reference`` checked against the hand: a misspelt joint would silently read as 0 rad,
    an angle in degrees would put every later goal off by the difference."""
    if not isinstance(reference, dict):
        raise ConfigError(f"reference must be a dict joint name -> angle [rad], got "
                          f"{type(reference).__name__}")
    names = [j.name for j in hand.all_joints]
    out = {}
    for name, value in reference.items():
        if name not in names:
            raise ConfigError(f"reference: hand {hand.name} has no joint {name!r}"
                              f"{did_you_mean(name, names)}; its joints: {', '.join(names)}")
        j = hand.joint(name)
        try:
            q = float(value)
        except (TypeError, ValueError):
            q = float("nan")
        if not np.isfinite(q):
            raise ConfigError(f"reference[{name!r}] must be a finite angle [rad], got {value!r}")
        if not j.low <= q <= j.high:
            hint = (f"; in degrees? {q:g} deg = {np.radians(q):.4f} rad"
                    if j.low <= np.radians(q) <= j.high else "")
            raise ConfigError(f"reference[{name!r}] = {q:g} rad is outside the joint's limits "
                              f"[{j.low:g}, {j.high:g}] rad{hint}: the hand cannot be held "
                              "there; give the pose in radians")
        out[name] = q
    return out


def format_report(old: HandSpec, new: HandSpec) -> str:
    """A table of old and new offsets per joint [rad]."""
    rows = [f"{'joint':<12} {'id':>3} {'old offset':>11} {'new offset':>11} {'change':>8}"]
    for a, b in zip(old.all_joints, new.all_joints, strict=True):
        d = b.calibration.offset - a.calibration.offset
        rows.append(f"{a.name:<12} {a.motor_id:>3} {a.calibration.offset:>11.4f} "
                    f"{b.calibration.offset:>11.4f} {d:>+8.4f}")
    return "\n".join(rows)
