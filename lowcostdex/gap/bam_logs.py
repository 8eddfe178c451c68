"""BAM raw-log JSON (Rhoban/bam's pendulum benches) mapped onto the servo bench
(``lowcostdex.sim.models.bench``) from its header (mass, length, arm_mass, kp, vin, motor).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.gap.log_checks import MAX_JSON_BYTES, MAX_SAMPLES, trajectory_from_columns
from lowcostdex.gap.trajectory import LogError, Trajectory
from lowcostdex.outdir import user_path
from lowcostdex.sim import servo
from lowcostdex.sim.models.bench import BENCH_JOINT, BenchConfig

# ------------------------------------------------------------------------------------------------
# BAM raw logs

# BAM motor name -> lowcostdex motor (BAM drives its MX benches with Protocol 1.0 firmware, so
# their kp is the P1 P Gain register)
BAM_MOTORS: dict[str, str] = {
    "xl330": "XL330-M288",
    "mx64": "MX-64(1.0)",
    "mx106": "MX-106(1.0)",
    "sts3250": "STS3250",
    "sts3032": "STS3032",
    "sts3215": "STS3215",  # LeRobot's SO-100/SO-101 servo; BAM's feetech recorder names it so
}
BAM_UNMODELLED: dict[str, str] = {
    "xl330i": "the XL330 in current-based position control (BAM's XL330CurrentActuator): its "
              "firmware closes a current loop this project's servo law does not model",
    "xl320": "the XL320 (1024 ticks over 300 deg, its own firmware): no motor table here",
    "erob80_100": "an eRob joint under BAM's own PD controller, not a hobby servo's firmware",
    "erob80_50": "an eRob joint under BAM's own PD controller, not a hobby servo's firmware",
    "unitree_go1": "a Unitree Go1 joint motor, not a hobby servo's firmware",
}
"""Motors BAM's acquisition knows (Rhoban/bam bam/actuators.py) that this project does not map
onto its servo bench: refused by name and reason rather than as an unknown motor."""
BAM_MOTOR_ALIASES: dict[str, str] = {
    "xl330m288": "xl330", "xl330m288t": "xl330", "mx64(1.0)": "mx64", "mx106(1.0)": "mx106",
}
"""A motor written as its full model name (ROBOTIS/Feetech spelling, any case, with or without
'-', '_' or spaces) -> BAM's name. Only the model BAM's name stands for: XL330-M077 (another
gear ratio) or MX-64(2.0) (Protocol 2 firmware) stay unknown."""
_BAM_HEADER = ("mass", "length", "kp", "vin", "motor", "entries")
_VENDORS = ("robotisdynamixel", "dynamixel", "robotis", "feetech")
_HEADER_MEANING = {
    "mass": "the load at the arm tip, kg",
    "length": "the distance from pivot to load, m",
    "kp": "the firmware position P gain register the log was recorded with",
    "vin": "the nominal supply voltage, V",
    "motor": "the servo model, e.g. xl330 or sts3032",
    "entries": "the samples",
}


def bam_motor(name: str) -> str | None:
    """BAM's motor name for ``name`` (BAM's own, or a full model name), None if unknown."""
    key = "".join(c for c in name.lower() if c not in " -_")
    for vendor in _VENDORS:  # "Dynamixel XL330-M288", "Feetech STS3032"
        if key.startswith(vendor) and len(key) > len(vendor):
            key = key[len(vendor):]
            break
    key = BAM_MOTOR_ALIASES.get(key, key)
    return key if key in BAM_MOTORS else None
_BAM_ENTRY = ("timestamp", "position", "goal_position")


def is_bam(path: str | Path) -> bool:
    """True when ``path`` is to be read as a BAM raw log: a ``.json`` file (the project format is
    CSV/NPZ, so a JSON file that is not a BAM log is refused by ``read_bam`` with its reason)."""
    return Path(path).suffix.lower() == ".json"


def _bam_number(value: object, where: str, positive: bool = False) -> float:
    """A JSON number (not a bool, string or null), finite (and > 0 when ``positive``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise LogError(f"{where}: {json.dumps(value)[:40]} is not a number")
    x = float(value)
    if not math.isfinite(x) or (positive and x <= 0):
        raise LogError(f"{where}: {value!r} must be a finite{' positive' if positive else ''} "
                       "number")
    return x


def _bam_entries(path: Path, entries: object) -> list[dict]:
    """Check the entries' types: a list of objects whose values are numbers (torque_enable may be
    a bool; optional fields may be null)."""
    if not isinstance(entries, list):
        raise LogError(f"{path}: 'entries' must be a list of samples, got "
                       f"{type(entries).__name__}")
    if not entries:
        raise LogError(f"{path}: BAM log has no entries")
    if len(entries) > MAX_SAMPLES:
        raise LogError(f"{path}: {len(entries)} entries; at most {MAX_SAMPLES} per log")
    for i, e in enumerate(entries):
        if not isinstance(e, dict):
            raise LogError(f"{path}: entries[{i}] must be an object with {list(_BAM_ENTRY)}, "
                           f"got {json.dumps(e)[:40]}")
        for k in _BAM_ENTRY:
            if k not in e:
                raise LogError(f"{path}: entries[{i}] lacks {k!r}")
        for k, v in e.items():
            if v is None and k not in _BAM_ENTRY:
                continue
            if k == "torque_enable" and isinstance(v, bool):
                continue
            if k in _BAM_ENTRY or k in _BAM_NUMERIC:
                _bam_number(v, f"{path}: entries[{i}].{k}")
    return entries


_BAM_NUMERIC = ("speed", "load", "input_volts", "temp", "torque_enable")

# Header plausibility (issue 12): ranges from the vendors and from statics, not from what the fit
# accepts. kp is a register: XL330 Position P Gain (address 84) 0-16383 (ROBOTIS e-Manual XL330
# control table); MX-64/106 Protocol 1.0 P Gain (address 28) and the Feetech STS P coefficient
# (address 21) are one byte, 0-254.
_KP_MAX = {"xl330": 16383, "mx64": 254, "mx106": 254, "sts3250": 254, "sts3032": 254,
           "sts3215": 254}
_MAX_LENGTH = 2.0  # [m] a pendulum arm on a hobby servo (BAM's benches: 0.05-0.12 m)
_VIN_RANGE = (0.5, 2.0)  # x the motor's nominal supply (Rhoban ran 5 V XL330s at 7.4 V)
_MAX_LOAD = 3.0  # x the stall torque at the log's supply: a load it can neither lift nor hold
_G = 9.81  # [m/s^2]


def _check_header_ranges(path: Path, raw: dict, motor: str) -> None:
    """Refuse a header whose numbers no BAM bench has: a length beyond ``_MAX_LENGTH``, a supply
    outside ``_VIN_RANGE`` of the motor's nominal one, kp beyond the register, a load whose
    gravity torque (mass at ``length``, ``arm_mass`` at half of it) exceeds ``_MAX_LOAD`` x the
    motor's stall torque at that supply. Raises LogError naming the file, field, value and the
    valid range."""
    mspec = servo.motor_spec(BAM_MOTORS[motor])
    length, mass, vin = float(raw["length"]), float(raw["mass"]), float(raw["vin"])
    arm_mass = float(raw.get("arm_mass") or 0.0)
    if length > _MAX_LENGTH:
        raise LogError(f"{path}: 'length' {raw['length']!r} m is not a pendulum arm on a servo; "
                       f"plausible: up to {_MAX_LENGTH:g} m (mm or cm? write m)")
    lo, hi = (f * mspec.voltage for f in _VIN_RANGE)
    if not lo <= vin <= hi:
        raise LogError(f"{path}: 'vin' {raw['vin']!r} V is no supply for the {mspec.name} "
                       f"(nominal {mspec.voltage:g} V); plausible: {lo:g} to {hi:g} V"
                       + (" (0.1 V units? write V)" if vin > hi else ""))
    if float(raw["kp"]) > _KP_MAX[motor]:
        raise LogError(f"{path}: 'kp' {raw['kp']!r} is beyond the {mspec.name}'s P gain register; "
                       f"valid: 1 to {_KP_MAX[motor]}")
    stall = mspec.stall_torque * vin / mspec.voltage  # [N m] stall torque scales with the supply
    load = (mass + arm_mass / 2) * _G * length
    if load > _MAX_LOAD * stall:
        max_mass = _MAX_LOAD * stall / (_G * length) - arm_mass / 2
        raise LogError(f"{path}: 'mass' {raw['mass']!r} kg at 'length' {length:g} m weighs "
                       f"{load:.3g} N m on the {mspec.name}, whose stall torque at {vin:g} V is "
                       f"{stall:.3g} N m; plausible: up to {_MAX_LOAD:g} x that, a mass up to "
                       f"{max(max_mass, 0.0):.3g} kg at this length (grams? write kg)")


def _vin_from_entries(path: Path, entries: object) -> tuple[float, str]:
    """The nominal supply of a log whose header lacks ``vin``: the median of the entries'
    ``input_volts`` (0.1 V registers, values above 30, scaled), with a note saying so.
    Raises LogError when the entries carry no usable input voltage."""
    volts = []
    if isinstance(entries, list):
        for e in entries:
            v = e.get("input_volts") if isinstance(e, dict) else None
            if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
                volts.append(float(v))
    v = float(np.median(volts)) if volts else math.nan
    if v > 30.0:
        v *= 0.1
    if not (v > 0):
        raise LogError(f"{path}: BAM log lacks 'vin' ({_HEADER_MEANING['vin']}) and its entries "
                       "carry no input_volts to take it from; add \"vin\": <volts> to the header")
    return v, (f"{path.name}: header lacks 'vin'; the supply is taken as the median measured "
               f"input_volts, {v:.2f} V")


_PROJECT_CHANNELS = ("goal", "qpos", "qvel", "current")
_LEROBOT_KEYS = ("observation.state", "action")


def _json_keys(raw: object) -> tuple[set[str], str]:
    """The column names a JSON table holds and its layout: a list of rows (objects), an object
    of columns, or pandas' ``to_json(orient="split")``; (set(), "") for anything else."""
    if isinstance(raw, list) and raw and all(isinstance(r, dict) for r in raw[:100]):
        return set().union(*(map(str, r) for r in raw[:100])), "a list of rows"
    if isinstance(raw, dict) and isinstance(raw.get("columns"), list) and "data" in raw:
        return set(map(str, raw["columns"])), "pandas' split layout"
    if isinstance(raw, dict):
        return set(map(str, raw)), "an object of columns"
    return set(), ""


def other_json_log(raw: object) -> str:
    """What to do with a JSON log that is not BAM's raw format, when its keys say what it is
    (text to append to the refusal; "" otherwise): the project's own columns written as JSON
    (read from CSV or NPZ), LeRobot-style frames (vectors of all joints per step), or a list of
    BAM logs in one file."""
    keys, layout = _json_keys(raw)
    if isinstance(raw, list) and raw and isinstance(raw[0], dict) and "entries" in raw[0]:
        return "; it is a list of BAM logs: give each its own .json file"
    if any(":" in k and k.split(":", 1)[0].strip().lower() in _PROJECT_CHANNELS for k in keys):
        orient = ", orient='split'" if layout == "pandas' split layout" else ""
        return (f"; it holds the project's log columns ({layout}: "
                f"{', '.join(sorted(keys)[:4])}{', ...' if len(keys) > 4 else ''}) as JSON, and "
                "a JSON log is read as BAM's raw format only: the project's logs are CSV or NPZ. "
                f"Write it as a CSV with the same columns, e.g. pandas.read_json(PATH{orient})"
                ".to_csv('log.csv', index=False), and give that")
    if any(k in keys for k in _LEROBOT_KEYS):
        return ("; it looks like LeRobot-style frames ('observation.state' / 'action' vectors "
                "of all joints per step), which the gap analysis does not read: write a CSV "
                "with one column per joint, 'time' [s] (the frames' timestamp), "
                "'goal:<actuator>' (each action element: the command) and 'qpos:<joint>' (each "
                "state element [rad]), named as in your MJCF model (docs/gap_analysis.md)")
    return ""


def read_bam(path: str | Path, timestep: float | None = None) -> tuple[Trajectory, BenchConfig]:
    """Map a BAM raw log onto the servo bench.

    The bench gets the log's ``mass``, ``length``, ``arm_mass`` (or ``arm-mass``, as BAM's
    Dynamixel recorder writes it; 0 when absent, as BAM's loader does), firmware ``kp`` (device
    units) and nominal supply ``vin``; the motor's duty ceiling is the PWM limit. Channels:
    ``speed`` -> qvel, ``input_volts`` -> voltage (raw 0.1 V registers, recognised by values
    above 30, are scaled), ``temp`` -> temperature (dropped when all zero),
    ``torque_enable``. The Rhoban XL330 ``load`` (raw PWM) is not used.

    Returns:
      (trajectory on joint/actuator ``BENCH_JOINT``, bench config). ``trajectory.model`` is a key
      naming the setup, so logs of one rig share a model.
    Raises:
      LogError naming the file, the field and the value: not JSON (binary, empty, truncated),
      wrong types, missing fields, unknown motor, implausible values (see
      ``trajectory_from_columns``).
    """
    path = user_path(path)
    if not path.exists():
        raise LogError(f"{path}: no such file")
    if path.is_dir():
        raise LogError(f"{path}: is a folder, not a log file")
    size = path.stat().st_size
    if size == 0:
        raise LogError(f"{path}: empty file")
    if size > MAX_JSON_BYTES:
        raise LogError(f"{path}: {size / 2**20:.0f} MB; a BAM log is at most "
                       f"{MAX_JSON_BYTES / 2**20:.0f} MB here (split it)")
    try:
        with open(path, encoding="utf-8") as f:
            raw = json.load(f)
    except UnicodeDecodeError:
        raise LogError(f"{path}: not a BAM JSON log (binary data, not text)") from None
    except (OSError, ValueError) as exc:  # JSONDecodeError is a ValueError
        raise LogError(f"{path}: not a readable BAM JSON log ({exc})") from None
    if not isinstance(raw, dict):
        raise LogError(f"{path}: BAM log must be a JSON object, got {type(raw).__name__}"
                       + other_json_log(raw))
    missing = [k for k in _BAM_HEADER if k not in raw]
    if len(missing) == len(_BAM_HEADER):  # another JSON file, e.g. a settings or results file
        keys = ", ".join(sorted(map(str, raw))[:8]) or "none"
        raise LogError(f"{path}: not a BAM raw log (its keys: {keys}); a BAM raw log is an "
                       f"object with {', '.join(_BAM_HEADER)} (Rhoban/bam's acquisition format)"
                       + other_json_log(raw))
    if "arm_mass" not in raw and "arm-mass" in raw:
        # BAM's Dynamixel recorder (bam/dynamixel/record.py) writes the arm's mass as "arm-mass";
        # BAM's loader (bam/logs.py) reads it as arm_mass, and so does this one
        raw = {**raw, "arm_mass": raw["arm-mass"]}
    vin_note = None
    if missing == ["vin"]:  # the supply: the measured input voltage when the entries carry it
        raw = dict(raw)
        raw["vin"], vin_note = _vin_from_entries(path, raw.get("entries"))
        missing = []
    if missing:
        said = "; ".join(f"{k!r} ({_HEADER_MEANING[k]})" for k in missing)
        raise LogError(f"{path}: BAM log lacks fields: {said}; a BAM raw log's header has "
                       f"{', '.join(_BAM_HEADER)} (add the missing field(s) to the file)")
    if not isinstance(raw["motor"], str):
        raise LogError(f"{path}: 'motor' must be a string, got {json.dumps(raw['motor'])[:40]}")
    motor = bam_motor(raw["motor"])
    unmodelled = "".join(c for c in raw["motor"].lower() if c not in " -")
    if motor is None and unmodelled in BAM_UNMODELLED:
        raise LogError(f"{path}: BAM motor {raw['motor']!r} is {BAM_UNMODELLED[unmodelled]}; "
                       "logs of these motors can be analysed here: "
                       + ", ".join(f"{k} ({v})" for k, v in sorted(BAM_MOTORS.items())))
    if motor is None:
        raise LogError(f"{path}: unknown BAM motor {raw['motor']!r}; valid: "
                       + ", ".join(f"{k} ({v})" for k, v in sorted(BAM_MOTORS.items())))
    for k in ("mass", "length", "kp", "vin"):
        _bam_number(raw[k], f"{path}: {k!r}", positive=True)
    if raw.get("arm_mass") is not None:
        if _bam_number(raw["arm_mass"], f"{path}: 'arm_mass'") < 0:
            raise LogError(f"{path}: 'arm_mass' {raw['arm_mass']!r} must be >= 0")
    _check_header_ranges(path, raw, motor)
    entries = _bam_entries(path, raw["entries"])

    def col(key: str, default: float | None = None) -> np.ndarray:
        return np.array([float(e.get(key, default)) if e.get(key, default) is not None
                         else np.nan for e in entries])

    t = col("timestamp")
    volts = col("input_volts", np.nan)
    if np.any(np.isfinite(volts)) and np.nanmedian(volts) > 30.0:  # Feetech: 0.1 V registers
        volts = volts * 0.1
    temp = col("temp", np.nan)
    channels = {"torque_enable": col("torque_enable", 1.0)[:, None]}
    if np.all(np.isfinite(volts)) and np.any(volts > 0):
        channels["voltage"] = volts[:, None]
    if np.all(np.isfinite(temp)) and np.any(temp != 0):
        channels["temperature"] = temp[:, None]
    speed = col("speed", np.nan)
    mspec = servo.motor_spec(BAM_MOTORS[motor])
    kp = float(raw["kp"])
    if not (kp > 0 and kp == int(kp)):
        raise LogError(f"{path}: BAM kp must be a positive integer register value, got {kp}")
    gains = servo.ServoGains(position_p=int(kp), pwm_limit=round(mspec.max_duty * mspec.pwm_max),
                             supply_voltage=float(raw["vin"]))
    arm_mass = float(raw.get("arm_mass", 0.0) or 0.0)
    cfg_kwargs = dict(motor=mspec.name, mass=float(raw["mass"]), length=float(raw["length"]),
                      arm_mass=arm_mass, gains=gains)
    if timestep is not None:
        cfg_kwargs["timestep"] = timestep
    try:
        cfg = BenchConfig(**cfg_kwargs)
    except ConfigError as exc:
        raise LogError(f"{path}: {exc}") from None
    meta = {k: v for k, v in raw.items() if k != "entries"}
    meta["source"] = "bam"
    key = (f"{mspec.name}_m{cfg.mass:g}_l{cfg.length:g}_a{arm_mass:g}_kp{int(kp)}"
           f"_v{float(raw['vin']):g}")
    cols = {"time": t, f"goal:{BENCH_JOINT}": col("goal_position"),
            f"qpos:{BENCH_JOINT}": col("position")}
    if np.all(np.isfinite(speed)):
        cols[f"qvel:{BENCH_JOINT}"] = speed
    for ch, arr in channels.items():
        cols[f"{ch}:{BENCH_JOINT}"] = arr[:, 0]
    traj = trajectory_from_columns(cols, name=path.name)
    traj.model = key
    traj.meta = {**traj.meta, **meta}  # keeps the notes of repairs (rows sorted, ...)
    if vin_note:
        traj.meta["notes"] = [*traj.meta.get("notes", []), vin_note]
    return traj, cfg


def check_one_motor(trajectories: Sequence[Trajectory]) -> None:
    """Refuse BAM logs of more than one servo model in one identification: its parameters
    (gear friction, armature, ...) are one servo's, as BAM fits one actuator at a time. Masses,
    lengths, gains and supplies may differ. Logs that are not BAM's are not checked.

    Raises:
      ConfigError naming each motor with one of its logs.
    """
    seen: dict[str, str] = {}
    for tr in trajectories:
        name = tr.meta.get("motor") if tr.meta.get("source") == "bam" else None
        bam = bam_motor(name) if isinstance(name, str) else None
        if bam is not None:
            seen.setdefault(BAM_MOTORS[bam], tr.name)
    if len(seen) > 1:
        said = ", ".join(f"{m} ({log})" for m, log in seen.items())
        raise ConfigError(f"these logs are of {len(seen)} servo models: {said}; identification "
                          "fits one servo's parameters: run it once per motor")
