"""Measured servo logs: the project's CSV/NPZ format, BAM raw-log JSON, validation, ZOH resampling.

The project's log format (one file = one trajectory) has one row per sample and columns

    time                    [s]     strictly increasing (host clock when the row's values
                                    were sampled)
    goal:<actuator>         [rad]   goal position written right after the row was read
    goal_time               [s]     (optional) when that goal reached the motors; absent: at
                                    ``time``. On a bus the goal follows the read's replies and
                                    its own packet, a few ms that otherwise look like latency.
    qpos:<joint>            [rad]   measured joint position
    qvel:<joint>            [rad/s] measured joint velocity (optional)
    current:<actuator>      [A]     (optional)
    voltage:<actuator>      [V]     measured supply at the servo (optional)
    temperature:<actuator>  [deg C] (optional)
    torque_enable:<actuator> 0/1    (optional; 1 when absent)

as CSV (a header row of these names) or NPZ (one 1-D array per name). Goals are held between rows
(zero-order hold), never interpolated. BAM raw-log JSON (Rhoban/bam's pendulum benches) is mapped
onto the servo bench (``lowcostdex.sim.models.bench``) from its header (mass, length, arm_mass,
kp, vin, motor); see ``read_bam``.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.sim import servo
from lowcostdex.sim.models.bench import BENCH_JOINT, BenchConfig

PREFIXES_ACTUATOR = ("goal", "current", "voltage", "temperature", "torque_enable")
PREFIXES_JOINT = ("qpos", "qvel")
CHANNELS = ("current", "voltage", "temperature", "torque_enable")
MIN_SAMPLES = 20
MIN_DURATION = 0.5  # [s]


class LogError(ConfigError):
    """A measured log is unusable; the message names the file, the column and the problem."""


@dataclass
class Trajectory:
    """One measured trajectory (all arrays share the sample axis T).

    Attributes:
      name: where it came from (file name, or file name and chunk).
      time: (T,) sample times [s], strictly increasing.
      goal: (T, na) goal positions [rad] per actuator in ``actuators``.
      qpos: (T, nj) measured positions [rad] per joint in ``joints``.
      actuators: actuator names (columns of ``goal`` and of every channel).
      joints: measured joint names (columns of ``qpos``/``qvel``).
      qvel: (T, nj) measured velocities [rad/s] or None.
      channels: {"current"|"voltage"|"temperature"|"torque_enable": (T, na)}.
      model: key of the model it replays on (``Dataset.models``).
      meta: free-form provenance (e.g. a BAM header).
      goal_time: (T,) when each row's goal took effect [s], >= ``time``; None: at ``time``.
    """

    name: str
    time: np.ndarray
    goal: np.ndarray
    qpos: np.ndarray
    actuators: tuple[str, ...]
    joints: tuple[str, ...]
    qvel: np.ndarray | None = None
    channels: dict[str, np.ndarray] = field(default_factory=dict)
    model: str = "model"
    meta: dict = field(default_factory=dict)
    goal_time: np.ndarray | None = None

    @property
    def goal_times(self) -> np.ndarray:
        """(T,) when each row's goal took effect [s]."""
        return self.time if self.goal_time is None else self.goal_time

    @property
    def duration(self) -> float:
        return float(self.time[-1] - self.time[0])

    def __len__(self) -> int:
        return len(self.time)

    def slice(self, start: int, stop: int, name: str | None = None) -> Trajectory:
        """Rows [start, stop) as a new trajectory (arrays are views)."""
        sl = slice(start, stop)
        return replace(self, name=name or self.name, time=self.time[sl], goal=self.goal[sl],
                       qpos=self.qpos[sl], qvel=None if self.qvel is None else self.qvel[sl],
                       channels={k: v[sl] for k, v in self.channels.items()},
                       goal_time=None if self.goal_time is None else self.goal_time[sl])

    def to_columns(self) -> dict[str, np.ndarray]:
        """The log-format columns {name: (T,)}."""
        cols = {"time": self.time}
        if self.goal_time is not None:
            cols["goal_time"] = self.goal_time
        for i, a in enumerate(self.actuators):
            cols[f"goal:{a}"] = self.goal[:, i]
        for i, j in enumerate(self.joints):
            cols[f"qpos:{j}"] = self.qpos[:, i]
            if self.qvel is not None:
                cols[f"qvel:{j}"] = self.qvel[:, i]
        for ch, arr in self.channels.items():
            for i, a in enumerate(self.actuators):
                cols[f"{ch}:{a}"] = arr[:, i]
        return cols


# ------------------------------------------------------------------------------------------------
# zero-order hold


def zoh_index(t_src: np.ndarray, t_dst: np.ndarray) -> np.ndarray:
    """Index of the sample held at each destination time: the last ``t_src <= t_dst``.

    Destination times before the first source sample hold the first sample.

    Args:
      t_src: (n,) increasing source times [s].
      t_dst: (m,) destination times [s].
    Returns:
      (m,) int indices into the source.
    """
    idx = np.searchsorted(np.asarray(t_src), np.asarray(t_dst), side="right") - 1
    return np.clip(idx, 0, len(t_src) - 1)


def zoh(t_src: np.ndarray, values: np.ndarray, t_dst: np.ndarray) -> np.ndarray:
    """Zero-order-hold resampling (commands are held, not interpolated: sysid trap 4).

    Args:
      t_src: (n,) increasing source times [s].
      values: (n, ...) values written at ``t_src``.
      t_dst: (m,) destination times [s].
    Returns:
      (m, ...) the value in force at each destination time.
    """
    return np.asarray(values)[zoh_index(t_src, t_dst)]


# ------------------------------------------------------------------------------------------------
# reading and writing the project format


def read_columns(path: Path) -> dict[str, np.ndarray]:
    """Read a CSV or NPZ log into {column: float array}."""
    path = Path(path)
    if not path.exists():
        raise LogError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        with np.load(path, allow_pickle=False) as z:
            cols = {k: np.asarray(z[k], dtype=float) for k in z.files}
    elif suffix == ".csv":
        cols = _read_csv(path)
    else:
        raise LogError(f"{path}: unknown log type {suffix!r}; valid: .csv, .npz, .json (BAM)")
    for k, v in cols.items():
        if v.ndim != 1:
            raise LogError(f"{path}: column {k!r} must be 1-D, got shape {v.shape}")
    lengths = {len(v) for v in cols.values()}
    if len(lengths) > 1:
        raise LogError(f"{path}: columns have different lengths {sorted(lengths)}")
    return cols


def _read_csv(path: Path) -> dict[str, np.ndarray]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        raise LogError(f"{path}: empty file")
    header = [h.strip() for h in rows[0]]
    if len(set(header)) != len(header):
        dup = sorted({h for h in header if header.count(h) > 1})
        raise LogError(f"{path}: duplicate columns {dup}")
    data = np.full((len(rows) - 1, len(header)), np.nan)
    for r, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise LogError(f"{path}: row {r + 2} has {len(row)} fields, header has {len(header)}")
        for c, cell in enumerate(row):
            try:
                data[r, c] = float(cell) if cell.strip() else np.nan
            except ValueError:
                raise LogError(f"{path}: row {r + 2}, column {header[c]!r}: "
                               f"{cell!r} is not a number") from None
    return {h: data[:, i] for i, h in enumerate(header)}


def trajectory_from_columns(cols: dict[str, np.ndarray], name: str = "log") -> Trajectory:
    """Parse log-format columns; raises LogError naming bad columns, NaNs or too little data."""
    if "time" not in cols:
        raise LogError(f"{name}: missing column 'time' [s]")
    acts: dict[str, dict[str, np.ndarray]] = {}
    joints: dict[str, dict[str, np.ndarray]] = {}
    for key, arr in cols.items():
        if key in ("time", "goal_time"):
            continue
        prefix, sep, target = key.partition(":")
        if not sep or not target:
            raise LogError(f"{name}: column {key!r} is not '<kind>:<name>'; kinds: time, "
                           + ", ".join(PREFIXES_ACTUATOR + PREFIXES_JOINT))
        if prefix in PREFIXES_ACTUATOR:
            acts.setdefault(target, {})[prefix] = arr
        elif prefix in PREFIXES_JOINT:
            joints.setdefault(target, {})[prefix] = arr
        else:
            raise LogError(f"{name}: column {key!r} has unknown kind {prefix!r}; valid kinds: "
                           + ", ".join(PREFIXES_ACTUATOR + PREFIXES_JOINT))
    goal_acts = [a for a, d in acts.items() if "goal" in d]
    if not goal_acts:
        raise LogError(f"{name}: no 'goal:<actuator>' column (commanded position [rad])")
    for a, d in acts.items():
        if "goal" not in d:
            raise LogError(f"{name}: channels {sorted(d)} for actuator {a!r} but no 'goal:{a}'")
    meas = [j for j, d in joints.items() if "qpos" in d]
    if not meas:
        raise LogError(f"{name}: no 'qpos:<joint>' column (measured position [rad])")
    for j, d in joints.items():
        if "qpos" not in d:
            raise LogError(f"{name}: 'qvel:{j}' without 'qpos:{j}'")
    for key, arr in cols.items():
        bad = ~np.isfinite(arr)
        if bad.any():
            raise LogError(f"{name}: column {key!r} has {int(bad.sum())} NaN/inf values "
                           f"(first at row {int(np.argmax(bad))})")
    t = np.asarray(cols["time"], dtype=float)
    _check_time(t, name)
    goal_time = None
    if "goal_time" in cols:
        goal_time = np.asarray(cols["goal_time"], dtype=float)
        if np.any(goal_time < t) or np.any(np.diff(goal_time) <= 0):
            raise LogError(f"{name}: 'goal_time' must be >= 'time' row by row and strictly "
                           "increasing")
    has_qvel = all("qvel" in joints[j] for j in meas)
    channels = {}
    for ch in CHANNELS:
        present = [a for a in goal_acts if ch in acts[a]]
        if present and len(present) != len(goal_acts):
            missing = sorted(set(goal_acts) - set(present))
            raise LogError(f"{name}: channel {ch!r} is missing for actuators {missing}")
        if present:
            channels[ch] = np.stack([acts[a][ch] for a in goal_acts], axis=1)
    return Trajectory(
        name=name, time=t,
        goal=np.stack([acts[a]["goal"] for a in goal_acts], axis=1),
        qpos=np.stack([joints[j]["qpos"] for j in meas], axis=1),
        actuators=tuple(goal_acts), joints=tuple(meas),
        qvel=np.stack([joints[j]["qvel"] for j in meas], axis=1) if has_qvel else None,
        channels=channels, goal_time=goal_time)


def _check_time(t: np.ndarray, name: str) -> None:
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise LogError(f"{name}: 'time' must be strictly increasing (row {i + 1}: "
                       f"{t[i + 1]:.6g} s after {t[i]:.6g} s)")
    if len(t) < MIN_SAMPLES or t[-1] - t[0] < MIN_DURATION:
        dur = float(t[-1] - t[0]) if len(t) else 0.0
        raise LogError(f"{name}: too little data: {len(t)} samples over {dur:.3g} s; need at "
                       f"least {MIN_SAMPLES} samples and {MIN_DURATION} s")


def read_log(path: str | Path) -> Trajectory:
    """Read one log (CSV, NPZ or BAM JSON; BAM logs carry their bench setup in ``meta``)."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        return read_bam(path)[0]
    return trajectory_from_columns(read_columns(path), name=path.name)


def write_log(path: str | Path, traj: Trajectory) -> Path:
    """Write a trajectory in the project format (CSV or NPZ by suffix)."""
    path = Path(path)
    cols = traj.to_columns()
    if path.suffix.lower() == ".npz":
        np.savez_compressed(path, **cols)
    elif path.suffix.lower() == ".csv":
        names = list(cols)
        data = np.stack([cols[n] for n in names], axis=1)
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(names)
            for row in data:
                w.writerow([repr(float(x)) for x in row])
    else:
        raise LogError(f"{path}: unknown log type {path.suffix!r}; valid: .csv, .npz")
    return path


def check_against_model(traj: Trajectory, model: mujoco.MjModel) -> None:
    """Check that the log's names exist in ``model`` and that every actuator has a goal.

    Raises:
      LogError naming the unknown or missing names and listing the model's.
    """
    act_names = [model.actuator(i).name for i in range(model.nu)]
    jnt_names = [model.joint(i).name for i in range(model.njnt)]
    for a in traj.actuators:
        if a not in act_names:
            raise LogError(f"{traj.name}: 'goal:{a}': no actuator {a!r} in the model; "
                           f"actuators: {', '.join(act_names)}")
    for j in traj.joints:
        if j not in jnt_names:
            raise LogError(f"{traj.name}: 'qpos:{j}': no joint {j!r} in the model; "
                           f"joints: {', '.join(jnt_names)}")
        jt = model.jnt_type[model.joint(j).id]
        if int(jt) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise LogError(f"{traj.name}: joint {j!r} is not a hinge or slide joint")
    missing = [a for a in act_names if a not in traj.actuators]
    if missing:
        raise LogError(f"{traj.name}: no goal for actuators {missing}; the log must command "
                       "every actuator of the model")


# ------------------------------------------------------------------------------------------------
# BAM raw logs

# BAM motor name -> (lowcostdex motor, input_volts scale when the raw register is in 0.1 V)
BAM_MOTORS: dict[str, str] = {
    "xl330": "XL330-M288",
    "mx64": "MX-64",
    "mx106": "MX-106",
    "sts3250": "STS3250",
    "sts3032": "STS3032",
}
_BAM_HEADER = ("mass", "length", "kp", "vin", "motor", "entries")
_BAM_ENTRY = ("timestamp", "position", "goal_position")


def is_bam(path: str | Path) -> bool:
    """True when ``path`` looks like a BAM raw log (JSON with ``entries``)."""
    path = Path(path)
    if path.suffix.lower() != ".json":
        return False
    try:
        with open(path) as f:
            head = f.read(4096)
    except OSError:
        return False
    return '"entries"' in head or '"mass"' in head


def read_bam(path: str | Path, timestep: float | None = None) -> tuple[Trajectory, BenchConfig]:
    """Map a BAM raw log onto the servo bench.

    The bench gets the log's ``mass``, ``length``, ``arm_mass`` (0 when absent, as BAM's loader
    does), firmware ``kp`` (device units) and nominal supply ``vin``; the motor's duty ceiling is
    the PWM limit. Channels: ``speed`` -> qvel, ``input_volts`` -> voltage (raw 0.1 V registers,
    recognised by values above 30, are scaled), ``temp`` -> temperature (dropped when all zero),
    ``torque_enable``. The Rhoban XL330 ``load`` (raw PWM) is not used.

    Returns:
      (trajectory on joint/actuator ``BENCH_JOINT``, bench config). ``trajectory.model`` is a key
      naming the setup, so logs of one rig share a model.
    """
    path = Path(path)
    try:
        with open(path) as f:
            raw = json.load(f)
    except (OSError, json.JSONDecodeError) as exc:
        raise LogError(f"{path}: not a readable BAM JSON log ({exc})") from None
    if not isinstance(raw, dict):
        raise LogError(f"{path}: BAM log must be a JSON object")
    missing = [k for k in _BAM_HEADER if k not in raw]
    if missing:
        raise LogError(f"{path}: BAM log lacks fields {missing}; need {list(_BAM_HEADER)}")
    motor = str(raw["motor"]).lower()
    if motor not in BAM_MOTORS:
        raise LogError(f"{path}: unknown BAM motor {raw['motor']!r}; valid: "
                       + ", ".join(sorted(BAM_MOTORS)))
    entries = raw["entries"]
    if not entries:
        raise LogError(f"{path}: BAM log has no entries")
    for k in _BAM_ENTRY:
        if k not in entries[0]:
            raise LogError(f"{path}: BAM entries lack {k!r}")

    def col(key: str, default: float | None = None) -> np.ndarray:
        return np.array([float(e.get(key, default)) if e.get(key, default) is not None
                         else np.nan for e in entries])

    t = col("timestamp")
    volts = col("input_volts", np.nan)
    if np.nanmedian(volts) > 30.0:  # Feetech registers in 0.1 V
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
    traj.meta = meta
    return traj, cfg


def estimate_velocity(time: np.ndarray, qpos: np.ndarray, window: float = 0.02) -> np.ndarray:
    """Velocity [rad/s] by a local linear fit over +-``window`` s (robust to quantization).

    Args:
      time: (T,) [s]; qpos: (T, n) [rad].
    Returns:
      (T, n) velocity estimates.
    """
    t = np.asarray(time, float)
    q = np.asarray(qpos, float)
    lo = np.searchsorted(t, t - window, side="left")
    hi = np.searchsorted(t, t + window, side="right")
    cs_t = np.concatenate([[0.0], np.cumsum(t)])
    cs_tt = np.concatenate([[0.0], np.cumsum(t * t)])
    cs_q = np.vstack([np.zeros((1, q.shape[1])), np.cumsum(q, axis=0)])
    cs_tq = np.vstack([np.zeros((1, q.shape[1])), np.cumsum(t[:, None] * q, axis=0)])
    n = (hi - lo).astype(float)
    st, stt = cs_t[hi] - cs_t[lo], cs_tt[hi] - cs_tt[lo]
    sq, stq = cs_q[hi] - cs_q[lo], cs_tq[hi] - cs_tq[lo]
    den = n * stt - st * st
    with np.errstate(divide="ignore", invalid="ignore"):
        v = (n[:, None] * stq - st[:, None] * sq) / den[:, None]
    return np.where(np.isfinite(v) & (n[:, None] >= 2), v, 0.0)


def quantization_step(qpos: np.ndarray) -> float:
    """Encoder step [rad] if the readings sit on a grid (e.g. 2 pi / 4096), else 0."""
    d = np.abs(np.diff(np.asarray(qpos, float), axis=0)).ravel()
    d = d[d > 1e-9]
    if len(d) < 10:
        return 0.0
    step = float(np.min(d))
    ratio = d / step
    on_grid = np.abs(ratio - np.round(ratio)) < 0.02
    if on_grid.mean() > 0.95 and step < 0.05:
        # a 2 pi / N encoder: snap to the nearest power-of-two resolution when it matches
        n = 2 * math.pi / step
        n2 = 2 ** round(math.log2(n))
        return 2 * math.pi / n2 if abs(n / n2 - 1) < 0.01 else step
    return 0.0
