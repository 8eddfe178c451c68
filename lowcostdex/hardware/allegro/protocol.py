"""Allegro Hand v4 CAN protocol: frame ids, payload codecs and unit conversions.

One module for the wire format, shared by the driver (``allegro.AllegroBus``) and the emulated
hand (``allegro_emulator.EmulatedAllegro``). Facts from 05-dynamixel-protocol.md section 6
(the v4 C++ driver): CAN 2.0A at 1 Mbit/s; frame id = ``(command << 2) | device_id`` with a
2-bit device id; the hand streams four FINGER_POSE frames per period (3 ms = 333 Hz) after
``SET_PERIOD`` + ``SYSTEM_ON``; the host answers each complete set with four SET_TORQUE frames.

Payloads (little endian):
  FINGER_POSE (0x20 + finger): 4 x int16 joint positions, ``deg = raw * 333.3 / 65536``.
  SET_TORQUE (0x60 + finger): 4 x int16 PWM, ``pwm = tau * 1200`` [tau in N m] on a v4 hand,
    ``tau * 800`` on a v3 hand (``torque_scale``), clamped.
  SET_PERIOD (0x81): 3 x uint16 periods [ms] for position, IMU, temperature (0 = off).
  HAND_INFO (0x80, RTR): hw version u16, fw version u16, side u8 (0 right / 1 left),
    palm temperature u8 [deg C], status u8. The hardware version's high byte is the hand's major
    version (4 on a v4 hand: the v4 ROS driver switches its torque constant on it, 1200 for 4,
    800 otherwise). Status bits: bit0 servo on and bit1 high-temperature fault in every driver;
    bit2 is "internal communication fault" to the Wonik drivers but "joint temperature throttle"
    to Meta's Python driver, and a working hand in Meta's published trace reports 0x05, so bit2
    (and the Meta-only bits 3, 4) are reported as flags, not as faults.
  TEMPERATURE (0x38 + finger, RTR): 4 bytes, one unsigned byte per joint [deg C] (a real v4
    hand's trace: ``2B 2A 29 25`` = 43, 42, 41, 37 deg C; the Wonik v4 Linux demo prints the four
    bytes). The hand answers a remote request whatever its streaming periods (Wonik's CAN
    protocol v4.0 page), which is how the reference drivers ask for temperatures.
    A byte with its high bit set (0x80..0xFF) is not a joint temperature: the same trace's
    thumb reads ``30 26 24 F6``, and 0xF6 is 246 deg C unsigned or -10 deg C signed, beside 15
    joints at 36..48 deg C and a palm at 60 deg C while that hand's own high-temperature fault
    bit is clear (status 0x05). Every reference driver decodes the byte unsigned and passes it
    on unchecked (Meta ``struct.unpack("4B")``, Wonik's v4 SDK ``uint8_t joint_temperature``,
    Wonik's Linux demo ``printf %d``); ``temperatures_celsius`` reports such a byte as unknown
    (NaN) and the driver names the joint as a temperature-sensor fault.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass

import can
import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.hands import ALLEGRO_POSITION_UNIT

# Commands (the frame id is ``cmd << 2 | device_id``).
SYSTEM_ON = 0x40
SYSTEM_OFF = 0x41
SET_TORQUE = 0x60  # + finger (0..3)
SET_POSE = 0xE0  # + finger
SET_PERIOD = 0x81
CONFIG = 0x68
HAND_INFO = 0x80
SERIAL = 0x88
FINGER_POSE = 0x20  # + finger
IMU = 0x30
TEMPERATURE = 0x38  # + finger

N_FINGERS = 4
JOINTS_PER_FINGER = 4
N_JOINTS = N_FINGERS * JOINTS_PER_FINGER
POSITION_UNIT = ALLEGRO_POSITION_UNIT  # [rad per raw count]; hand specs check limits with it
TORQUE_TO_PWM = 1200.0  # v4 ``_tau_cov_const`` [PWM per N m]
PWM_MAX = 1200  # global clamp at 12 V
# Hand major version -> (torque constant [PWM per N m], global PWM clamp): the v4 ROS driver's
# 1200 at 12 V for a v4 hand and 800 at 8 V for a v3 hand. Other versions (v5 speaks another
# protocol) are refused.
TORQUE_SCALES = {4: (1200.0, 1200), 3: (800.0, 800)}
# Per-joint PWM clamps of the v4 driver: fingers (roll, near, middle, far), thumb.
PWM_LIMIT_FINGER = (375, 675, 450, 285)
PWM_LIMIT_THUMB = (525, 405, 270, 270)
STATUS_SERVO_ON, STATUS_HIGH_TEMPERATURE = 0x01, 0x02
# Status bits read differently by different drivers (flags, not faults): the Wonik drivers' name
# and Meta's Python driver's name.
STATUS_FLAGS = {0x04: "bit2 (communication fault to Wonik, temperature throttle to Meta)",
                0x08: "bit3 (joint communication fault to Meta)",
                0x10: "bit4 (palm temperature fault to Meta)"}
_I16 = struct.Struct("<4h")


def frame_id(command: int, device_id: int = 0) -> int:
    """11-bit arbitration id of ``command`` for the hand with ``device_id`` (0..3)."""
    if not 0 <= device_id <= 3:
        raise ConfigError(f"Allegro device id {device_id} outside 0..3")
    return (command << 2) | device_id


def split_id(arbitration_id: int) -> tuple[int, int]:
    """(command, device_id) of an arbitration id."""
    return (arbitration_id & ~3) >> 2, arbitration_id & 3


def torque_scale(major_version: int) -> tuple[float, int]:
    """(torque constant [PWM counts per N m], global PWM clamp) of a hand's major version.

    Raises:
      ConfigError: for a version the driver does not know (not 3 or 4).
    """
    if major_version not in TORQUE_SCALES:
        raise ConfigError(
            f"Allegro hardware version {major_version} is not supported (known: "
            f"{sorted(TORQUE_SCALES)}); its torque constant is unknown, so torques would be "
            "wrong. A v5 hand speaks a different CAN protocol.")
    return TORQUE_SCALES[major_version]


def pwm_limits(pwm_max: int = PWM_MAX) -> np.ndarray:
    """Per-joint PWM clamps (16,) in joint order index, middle, ring, thumb, within the global
    clamp ``pwm_max``."""
    return np.minimum(np.array(PWM_LIMIT_FINGER * 3 + PWM_LIMIT_THUMB, dtype=float), pwm_max)


def torque_to_pwm(tau: np.ndarray, scale: float = TORQUE_TO_PWM, pwm_max: int = PWM_MAX
                  ) -> np.ndarray:
    """Joint torques (16,) [N m] -> PWM counts (16,) int, clamped per joint.

    ``scale`` [PWM counts per N m] and ``pwm_max`` are the hand version's (``torque_scale``);
    the defaults are the v4 hand's."""
    lim = pwm_limits(pwm_max)
    return np.clip(np.rint(np.asarray(tau, float) * scale), -lim, lim).astype(int)


def pwm_to_torque(pwm: np.ndarray, scale: float = TORQUE_TO_PWM) -> np.ndarray:
    """PWM counts -> joint torques [N m] (``scale``: the hand version's torque constant)."""
    return np.asarray(pwm, float) / scale


def pack_temperatures(celsius: Sequence[float]) -> bytes:
    """TEMPERATURE payload: four joint temperatures [deg C] as unsigned bytes (rounded, 0..255)."""
    return bytes(int(min(max(round(float(t)), 0), 255)) for t in celsius)


def unpack_temperatures(data: bytes | bytearray) -> tuple[int, int, int, int]:
    """Four joint temperatures [deg C] of a TEMPERATURE payload (4 unsigned bytes)."""
    if len(data) != 4:
        raise ValueError(f"expected 4 temperature bytes, got {len(data)}")
    return tuple(bytes(data))  # type: ignore[return-value]


TEMPERATURE_SENSOR_FAULT = 0x80
"""TEMPERATURE bytes at or above this are sensor faults, not temperatures (module docstring)."""


def temperatures_celsius(raw: Sequence[int] | np.ndarray) -> np.ndarray:
    """Joint temperatures [deg C] (float) of raw TEMPERATURE bytes: NaN where a byte is a sensor
    fault (>= ``TEMPERATURE_SENSOR_FAULT``), so the thermal guard reads it as unknown rather
    than as a 246 deg C joint."""
    t = np.asarray(raw, float)
    return np.where(t >= TEMPERATURE_SENSOR_FAULT, np.nan, t)


def pack4(values: Sequence[int]) -> bytes:
    """Four signed 16-bit integers, little endian (8 bytes); values are clamped to int16."""
    v = [int(min(max(x, -32768), 32767)) for x in values]
    return _I16.pack(*v)


def unpack4(data: bytes | bytearray) -> tuple[int, int, int, int]:
    """Inverse of ``pack4``."""
    if len(data) != 8:
        raise ValueError(f"expected 8 data bytes, got {len(data)}")
    return _I16.unpack(bytes(data))


def radians_to_raw(q: np.ndarray) -> np.ndarray:
    """Joint angles [rad] -> FINGER_POSE counts (rounded, clamped to int16)."""
    return np.clip(np.rint(np.asarray(q, float) / POSITION_UNIT), -32768, 32767).astype(int)


def raw_to_radians(raw: np.ndarray) -> np.ndarray:
    """FINGER_POSE counts -> joint angles [rad]."""
    return np.asarray(raw, float) * POSITION_UNIT


def message(command: int, data: bytes = b"", device_id: int = 0, remote: bool = False
            ) -> can.Message:
    """A standard (11-bit) CAN frame for ``command``."""
    return can.Message(arbitration_id=frame_id(command, device_id), is_extended_id=False,
                       data=data, dlc=len(data), is_remote_frame=remote)


def pose_message(finger: int, q: np.ndarray, device_id: int = 0) -> can.Message:
    """FINGER_POSE frame of one finger from its 4 joint angles [rad]."""
    return message(FINGER_POSE + finger, pack4(radians_to_raw(q)), device_id)


def torque_message(finger: int, pwm: np.ndarray, device_id: int = 0) -> can.Message:
    """SET_TORQUE frame of one finger from its 4 PWM values."""
    return message(SET_TORQUE + finger, pack4(pwm), device_id)


def period_message(position_ms: int, imu_ms: int = 0, temperature_ms: int = 0,
                   device_id: int = 0) -> can.Message:
    """SET_PERIOD frame: streaming periods [ms] (0 stops a stream)."""
    data = struct.pack("<3H", position_ms, imu_ms, temperature_ms)
    return message(SET_PERIOD, data, device_id)


def parse_period(data: bytes | bytearray) -> tuple[int, int, int]:
    """(position, IMU, temperature) periods [ms] of a SET_PERIOD payload (missing = 0; unsigned
    16-bit like Wonik's ``data_period_t``; Meta's driver sends a fourth, status period)."""
    raw = bytes(data) + b"\x00" * (6 - len(data))
    return struct.unpack("<3H", raw[:6])


@dataclass(frozen=True)
class HandInfo:
    """HAND_INFO reply.

    Attributes:
      hardware_version, firmware_version: version numbers (u16; the hardware version's high
        byte is the major version, e.g. 0x0402 on a v4 hand).
      left: True for a left hand.
      palm_temperature: [deg C].
      status: status bits (``STATUS_*``).
    """

    hardware_version: int
    firmware_version: int
    left: bool
    palm_temperature: int
    status: int

    def pack(self) -> bytes:
        return struct.pack("<HHBBB", self.hardware_version, self.firmware_version,
                           int(self.left), self.palm_temperature & 0xFF, self.status & 0xFF)

    @classmethod
    def unpack(cls, data: bytes | bytearray) -> HandInfo:
        hw, fw, side, temp, status = struct.unpack("<HHBBB", bytes(data[:7]))
        return cls(hw, fw, bool(side), temp, status)

    @property
    def major_version(self) -> int:
        """The hand's major version (4 for a v4 hand): the hardware version's high byte."""
        return self.hardware_version >> 8

    @property
    def servo_on(self) -> bool:
        return bool(self.status & STATUS_SERVO_ON)

    @property
    def faults(self) -> tuple[str, ...]:
        """Faults every driver agrees on (the high-temperature bit)."""
        return ("high_temperature",) if self.status & STATUS_HIGH_TEMPERATURE else ()

    @property
    def flags(self) -> tuple[str, ...]:
        """Set status bits whose meaning differs between drivers (``STATUS_FLAGS``)."""
        return tuple(name for bit, name in STATUS_FLAGS.items() if self.status & bit)
