"""Dynamixel control tables as data.

Addresses and sizes are read from the ``.model`` files that ``dynamixel-sdk`` ships in
``dynamixel_easy_sdk/control_table/`` (``dynamixel.model`` maps model numbers to files), so they
are ROBOTIS's own data, not a transcription. What those files lack and a device needs (access
rights, EEPROM area, factory defaults, value ranges) is kept here as data, per model family, from
the ROBOTIS e-Manual X-series pages (05-dynamixel-protocol.md section 4).

Code names registers through ``Reg`` (an Enum of the e-Manual names), so a typo fails at import,
not on the wire::

    table = load_control_table("XM430-W210")      # or the model number 1030
    table[Reg.PRESENT_POSITION]                    # Item(name='Present Position', address=132, size=4)
"""

from __future__ import annotations

import enum
import functools
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib.resources import files
from numbers import Integral

from lowcostdex.errors import ConfigError, check_choice

SDK_TABLES = files("dynamixel_easy_sdk") / "control_table"
EEPROM_END = 64  # items below this address are EEPROM: writable only with torque off


class Reg(str, enum.Enum):
    """Control-table items by their e-Manual names (the ``.model`` files' "Data Name")."""

    MODEL_NUMBER = "Model Number"
    MODEL_INFORMATION = "Model Information"
    FIRMWARE_VERSION = "Firmware Version"
    ID = "ID"
    BAUD_RATE = "Baud Rate"
    RETURN_DELAY_TIME = "Return Delay Time"
    DRIVE_MODE = "Drive Mode"
    OPERATING_MODE = "Operating Mode"
    SECONDARY_ID = "Secondary(Shadow) ID"
    PROTOCOL_TYPE = "Protocol Type"
    HOMING_OFFSET = "Homing Offset"
    MOVING_THRESHOLD = "Moving Threshold"
    TEMPERATURE_LIMIT = "Temperature Limit"
    MAX_VOLTAGE_LIMIT = "Max Voltage Limit"
    MIN_VOLTAGE_LIMIT = "Min Voltage Limit"
    PWM_LIMIT = "PWM Limit"
    CURRENT_LIMIT = "Current Limit"
    VELOCITY_LIMIT = "Velocity Limit"
    MAX_POSITION_LIMIT = "Max Position Limit"
    MIN_POSITION_LIMIT = "Min Position Limit"
    SHUTDOWN = "Shutdown"
    TORQUE_ENABLE = "Torque Enable"
    LED = "LED"
    STATUS_RETURN_LEVEL = "Status Return Level"
    REGISTERED_INSTRUCTION = "Registered Instruction"
    HARDWARE_ERROR_STATUS = "Hardware Error Status"
    VELOCITY_I_GAIN = "Velocity I Gain"
    VELOCITY_P_GAIN = "Velocity P Gain"
    POSITION_D_GAIN = "Position D Gain"
    POSITION_I_GAIN = "Position I Gain"
    POSITION_P_GAIN = "Position P Gain"
    FEEDFORWARD_2ND_GAIN = "Feedforward 2nd Gain"
    FEEDFORWARD_1ST_GAIN = "Feedforward 1st Gain"
    BUS_WATCHDOG = "Bus Watchdog"
    GOAL_PWM = "Goal PWM"
    GOAL_CURRENT = "Goal Current"
    GOAL_VELOCITY = "Goal Velocity"
    PROFILE_ACCELERATION = "Profile Acceleration"
    PROFILE_VELOCITY = "Profile Velocity"
    GOAL_POSITION = "Goal Position"
    REALTIME_TICK = "Realtime Tick"
    MOVING = "Moving"
    MOVING_STATUS = "Moving Status"
    PRESENT_PWM = "Present PWM"
    PRESENT_CURRENT = "Present Current"
    PRESENT_VELOCITY = "Present Velocity"
    PRESENT_POSITION = "Present Position"
    VELOCITY_TRAJECTORY = "Velocity Trajectory"
    POSITION_TRAJECTORY = "Position Trajectory"
    PRESENT_INPUT_VOLTAGE = "Present Input Voltage"
    PRESENT_TEMPERATURE = "Present Temperature"


READ_ONLY = frozenset({
    Reg.MODEL_NUMBER, Reg.MODEL_INFORMATION, Reg.FIRMWARE_VERSION, Reg.REGISTERED_INSTRUCTION,
    Reg.HARDWARE_ERROR_STATUS, Reg.REALTIME_TICK, Reg.MOVING, Reg.MOVING_STATUS, Reg.PRESENT_PWM,
    Reg.PRESENT_CURRENT, Reg.PRESENT_VELOCITY, Reg.PRESENT_POSITION, Reg.VELOCITY_TRAJECTORY,
    Reg.POSITION_TRAJECTORY, Reg.PRESENT_INPUT_VOLTAGE, Reg.PRESENT_TEMPERATURE,
})
SIGNED = frozenset({
    Reg.HOMING_OFFSET, Reg.GOAL_PWM, Reg.GOAL_CURRENT, Reg.GOAL_VELOCITY, Reg.GOAL_POSITION,
    Reg.PRESENT_PWM, Reg.PRESENT_CURRENT, Reg.PRESENT_VELOCITY, Reg.PRESENT_POSITION,
    Reg.VELOCITY_TRAJECTORY, Reg.POSITION_TRAJECTORY, Reg.BUS_WATCHDOG,
})
GOALS = frozenset({Reg.GOAL_PWM, Reg.GOAL_CURRENT, Reg.GOAL_VELOCITY, Reg.GOAL_POSITION})
_REG_BY_NAME = {r.value: r for r in Reg}
# The SDK's files spell a few names differently per series (the MX(2.0) files: "BUS Watchdog");
# items are keyed by the e-Manual name above whatever the case.
_CANONICAL = {r.value.lower(): r.value for r in Reg}


@dataclass(frozen=True)
class Item:
    """One control-table item: e-Manual name, address, size [bytes]."""

    name: str
    address: int
    size: int

    @property
    def end(self) -> int:
        return self.address + self.size

    @property
    def reg(self) -> Reg | None:
        return _REG_BY_NAME.get(self.name)


@dataclass(frozen=True)
class ControlTable:
    """The control table of one model.

    Attributes:
      model: model name, e.g. "XM430-W210".
      model_number: Model Number register value.
      items: name -> Item, in address order.
      raw_start: first address of the indirect-address area (plain RAM bytes to the end).
      size: bytes of device memory (through the last indirect data byte).
      zero_tick: tick the SDK's ``.model`` file calls 0 rad (lowcostdex uses tick 0 = 0 rad).
    """

    model: str
    model_number: int
    items: Mapping[str, Item]
    raw_start: int
    size: int
    zero_tick: int = 2048
    _by_address: dict[int, Item] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        for it in self.items.values():
            self._by_address.setdefault(it.address, it)

    def __getitem__(self, reg: Reg | str) -> Item:
        name = reg.value if isinstance(reg, Reg) else reg
        if name not in self.items:
            check_choice(f"{self.model} control-table item", name, self.items)
        return self.items[name]

    def __contains__(self, reg: Reg | str) -> bool:
        return (reg.value if isinstance(reg, Reg) else reg) in self.items

    def address(self, reg: Reg | str) -> int:
        return self[reg].address

    def item_at(self, address: int) -> Item | None:
        """The item starting at ``address`` (None inside an item, in a gap or in raw RAM)."""
        return self._by_address.get(address)


def _model_name(filename: str) -> str:
    stem = filename.removesuffix(".model")
    head, _, rest = stem.partition("_")
    return (head + ("-" + rest.replace("_", "-") if rest else "")).upper()


@functools.lru_cache(maxsize=1)
def model_numbers() -> dict[int, str]:
    """Model Number -> model name for every model the SDK ships a table for."""
    out = {}
    for line in (SDK_TABLES / "dynamixel.model").read_text().splitlines()[1:]:
        parts = line.split()
        if len(parts) == 2 and parts[0].isdigit():
            out[int(parts[0])] = _model_name(parts[1])
    return out


def model_name(number: int) -> str:
    """Model name of a Model Number, or ``"unknown(<n>)"``."""
    return model_numbers().get(number, f"unknown({number})")


def _parse_model_file(text: str) -> tuple[dict[str, Item], int]:
    section = ""
    items: dict[str, Item] = {}
    zero = 2048
    for line in text.splitlines():
        line = line.strip()
        if not line:
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        cols = line.split("\t")
        if section == "control table" and cols[0].isdigit():
            name = _CANONICAL.get(cols[2].lower(), cols[2])
            items.setdefault(name, Item(name, int(cols[0]), int(cols[1])))
        elif section == "type info" and cols[0] == "value_of_zero_radian_position":
            zero = int(cols[1])
    return dict(sorted(items.items(), key=lambda kv: kv[1].address)), zero


def load_control_table(model: str | int) -> ControlTable:
    """The control table of a model (name such as "XH430-W350", or Model Number); one shared
    instance per model.

    Raises ConfigError listing the known models when the SDK has no table for it.
    """
    numbers = model_numbers()
    if isinstance(model, Integral) and not isinstance(model, bool):  # numpy ints too (a scan)
        model = int(model)
        check_choice("Dynamixel model number", model, numbers)
        return _load(numbers[model], model)
    by_name = {name: num for num, name in numbers.items()}
    check_choice("Dynamixel model", model, by_name)
    return _load(model, by_name[model])


@functools.cache
def _load(name: str, number: int) -> ControlTable:
    filename = name.lower().replace("-", "_") + ".model"
    items, zero = _parse_model_file((SDK_TABLES / filename).read_text())
    indirect = [it.address for n, it in items.items() if n.startswith("Indirect")]
    raw_start = min(indirect) if indirect else max(it.end for it in items.values())
    # the last listed item is the first byte of a 28-byte indirect-data block
    size = max(it.end for it in items.values()) + (27 if indirect else 0)
    return ControlTable(name, number, items, raw_start, size, zero)


# -- device-side data ------------------------------------------------------------------------------

_X430_DEFAULTS: dict[Reg, int] = {
    Reg.MODEL_INFORMATION: 0, Reg.ID: 1, Reg.BAUD_RATE: 1, Reg.RETURN_DELAY_TIME: 250,
    Reg.DRIVE_MODE: 0, Reg.OPERATING_MODE: 3, Reg.SECONDARY_ID: 255, Reg.PROTOCOL_TYPE: 2,
    Reg.HOMING_OFFSET: 0, Reg.MOVING_THRESHOLD: 10, Reg.TEMPERATURE_LIMIT: 80,
    Reg.MAX_VOLTAGE_LIMIT: 160, Reg.MIN_VOLTAGE_LIMIT: 95, Reg.PWM_LIMIT: 885,
    Reg.CURRENT_LIMIT: 1193, Reg.VELOCITY_LIMIT: 330, Reg.MAX_POSITION_LIMIT: 4095,
    Reg.MIN_POSITION_LIMIT: 0, Reg.SHUTDOWN: 52, Reg.TORQUE_ENABLE: 0, Reg.LED: 0,
    Reg.STATUS_RETURN_LEVEL: 2, Reg.VELOCITY_I_GAIN: 1920, Reg.VELOCITY_P_GAIN: 100,
    Reg.POSITION_D_GAIN: 0, Reg.POSITION_I_GAIN: 0, Reg.POSITION_P_GAIN: 800,
    Reg.FEEDFORWARD_2ND_GAIN: 0, Reg.FEEDFORWARD_1ST_GAIN: 0, Reg.BUS_WATCHDOG: 0,
    Reg.GOAL_PWM: 885, Reg.GOAL_CURRENT: 1193, Reg.GOAL_VELOCITY: 0,
    Reg.PROFILE_ACCELERATION: 0, Reg.PROFILE_VELOCITY: 0,
}
# Per-model differences (the e-Manual model pages' control tables; every value is checked
# against the e-Manual in tests/test_vendor_units.py).
_MODEL_DEFAULTS: dict[str, dict[Reg, int]] = {
    "XM430-W210": {},
    "XM430-W350": {Reg.VELOCITY_LIMIT: 200},
    "XH430-W210": {Reg.CURRENT_LIMIT: 648, Reg.GOAL_CURRENT: 648, Reg.VELOCITY_LIMIT: 210},
    "XH430-W350": {Reg.CURRENT_LIMIT: 648, Reg.GOAL_CURRENT: 648, Reg.VELOCITY_LIMIT: 130},
    "XH430-V210": {Reg.CURRENT_LIMIT: 689, Reg.GOAL_CURRENT: 689, Reg.VELOCITY_LIMIT: 380,
                   Reg.MAX_VOLTAGE_LIMIT: 300, Reg.MIN_VOLTAGE_LIMIT: 110},
    "XH430-V350": {Reg.CURRENT_LIMIT: 689, Reg.GOAL_CURRENT: 689, Reg.VELOCITY_LIMIT: 135,
                   Reg.MAX_VOLTAGE_LIMIT: 300, Reg.MIN_VOLTAGE_LIMIT: 110},
    "XL330-M288": {Reg.TEMPERATURE_LIMIT: 70, Reg.MAX_VOLTAGE_LIMIT: 70,
                   Reg.MIN_VOLTAGE_LIMIT: 35, Reg.CURRENT_LIMIT: 1750, Reg.GOAL_CURRENT: 1750,
                   Reg.VELOCITY_LIMIT: 445, Reg.VELOCITY_I_GAIN: 1600,
                   Reg.VELOCITY_P_GAIN: 180, Reg.SHUTDOWN: 53},
    "XL330-M077": {Reg.TEMPERATURE_LIMIT: 70, Reg.MAX_VOLTAGE_LIMIT: 70,
                   Reg.MIN_VOLTAGE_LIMIT: 35, Reg.CURRENT_LIMIT: 1750, Reg.GOAL_CURRENT: 1750,
                   Reg.VELOCITY_LIMIT: 1620, Reg.VELOCITY_I_GAIN: 400,
                   Reg.VELOCITY_P_GAIN: 40, Reg.SHUTDOWN: 53},
    # MX(2.0) pages (mx-64-2, mx-106-2): the X430 defaults but for these rows
    "MX-64": {Reg.CURRENT_LIMIT: 1941, Reg.GOAL_CURRENT: 1941, Reg.VELOCITY_LIMIT: 435},
    "MX-106": {Reg.CURRENT_LIMIT: 2047, Reg.GOAL_CURRENT: 2047, Reg.VELOCITY_LIMIT: 360},
}
SUPPORTED_MODELS = tuple(_MODEL_DEFAULTS)
"""Models the emulator can impersonate (factory defaults known)."""


def factory_defaults(model: str) -> dict[Reg, int]:
    """Factory value of every writable item of ``model`` (device units).

    The Position P/I/D Gain defaults are the servo model's (``lowcostdex.sim.servo.MotorSpec``
    ``default_p/i/d``) so the emulated firmware and the nominal simulation start from the same
    gains.
    """
    from lowcostdex.sim.servo import motor_spec

    check_choice("emulated Dynamixel model", model, SUPPORTED_MODELS)
    out = {**_X430_DEFAULTS, **_MODEL_DEFAULTS[model]}
    m = motor_spec(model)
    out[Reg.POSITION_P_GAIN] = m.default_p
    out[Reg.POSITION_I_GAIN] = m.default_i
    out[Reg.POSITION_D_GAIN] = m.default_d
    return out


def value_range(reg: Reg, values: Mapping[Reg, int], model: str) -> tuple[int, int] | None:
    """Accepted [low, high] of a writable item of ``model`` given its current register ``values``
    (None: any value of the item's size).

    Goal Position is not here: its bounds depend on the operating mode (firmware checks them).
    """
    if reg in _MODEL_RANGES.get(model, {}):
        return _MODEL_RANGES[model][reg]
    if reg in _FIXED_RANGES:
        return _FIXED_RANGES[reg]
    if reg in _GAINS:
        return (0, 16383)
    if reg == Reg.CURRENT_LIMIT:
        return (0, factory_defaults(model)[Reg.CURRENT_LIMIT])
    if reg == Reg.GOAL_PWM:
        lim = values[Reg.PWM_LIMIT]
        return (-lim, lim)
    if reg == Reg.GOAL_CURRENT:
        lim = values[Reg.CURRENT_LIMIT]
        return (-lim, lim)
    if reg == Reg.GOAL_VELOCITY:
        lim = values[Reg.VELOCITY_LIMIT]
        return (-lim, lim)
    return None


_GAINS = frozenset({Reg.VELOCITY_I_GAIN, Reg.VELOCITY_P_GAIN, Reg.POSITION_D_GAIN,
                    Reg.POSITION_I_GAIN, Reg.POSITION_P_GAIN, Reg.FEEDFORWARD_2ND_GAIN,
                    Reg.FEEDFORWARD_1ST_GAIN})
_FIXED_RANGES: dict[Reg, tuple[int, int]] = {
    Reg.ID: (0, 252), Reg.BAUD_RATE: (0, 7), Reg.RETURN_DELAY_TIME: (0, 254),
    Reg.DRIVE_MODE: (0, 13), Reg.PROTOCOL_TYPE: (1, 2), Reg.SECONDARY_ID: (0, 255),
    Reg.HOMING_OFFSET: (-1_044_479, 1_044_479), Reg.MOVING_THRESHOLD: (0, 1023),
    Reg.TEMPERATURE_LIMIT: (0, 100), Reg.MAX_VOLTAGE_LIMIT: (0, 300),
    Reg.MIN_VOLTAGE_LIMIT: (0, 300), Reg.PWM_LIMIT: (0, 885), Reg.VELOCITY_LIMIT: (0, 1023),
    Reg.MAX_POSITION_LIMIT: (0, 4095), Reg.MIN_POSITION_LIMIT: (0, 4095),
    Reg.SHUTDOWN: (0, 255), Reg.TORQUE_ENABLE: (0, 1), Reg.LED: (0, 1),
    Reg.STATUS_RETURN_LEVEL: (0, 2), Reg.BUS_WATCHDOG: (0, 127),
    Reg.PROFILE_ACCELERATION: (0, 32767), Reg.PROFILE_VELOCITY: (0, 32767),
}
# Where a model's Range column differs from the X430 pages' (tests/test_vendor_units.py types them):
# the XL330 pages have no 4.5 Mbps (Baud Rate 0 ~ 6), Drive Mode 0 ~ 5, a 3.1-7.0 V supply window
# and a Velocity Limit up to 2,047 (the M077's factory value, 1,620, is above the X430's 1,023).
_XL330_RANGES = {Reg.BAUD_RATE: (0, 6), Reg.DRIVE_MODE: (0, 5), Reg.MAX_VOLTAGE_LIMIT: (31, 70),
                 Reg.MIN_VOLTAGE_LIMIT: (31, 70), Reg.VELOCITY_LIMIT: (0, 2047)}
_MODEL_RANGES: dict[str, dict[Reg, tuple[int, int]]] = {
    "XL330-M288": _XL330_RANGES, "XL330-M077": _XL330_RANGES}
DEPENDENT = frozenset({Reg.GOAL_PWM, Reg.GOAL_CURRENT, Reg.GOAL_VELOCITY})
"""Items whose range depends on other registers (PWM / Current / Velocity Limit)."""


def check_same_layout(tables: Mapping[int, ControlTable], regs: tuple[Reg, ...]) -> None:
    """Raise ConfigError unless every table has ``regs`` at the same addresses and sizes."""
    ref_id, ref = next(iter(tables.items()))
    for motor_id, t in tables.items():
        for r in regs:
            if r not in t:
                raise ConfigError(f"motor {motor_id} ({t.model}) has no {r.value!r} register")
            if (t[r].address, t[r].size) != (ref[r].address, ref[r].size):
                raise ConfigError(f"{r.value!r} is at {t[r].address} on motor {motor_id} "
                                  f"({t.model}) but at {ref[r].address} on motor {ref_id}")
