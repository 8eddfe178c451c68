"""One measured trajectory (``Trajectory``), the error a bad log raises, zero-order-hold
resampling, gaps in its time stamps and the encoder grid of its readings. The log formats are
described in ``lowcostdex.gap.logs``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from lowcostdex.errors import InputError


class LogError(InputError):
    """A measured log is unusable; the message names the file, the column and the problem."""


GAP_FACTOR = 10.0  # a step this many median steps long (and >= GAP_MIN) is a gap
GAP_MIN = 0.1  # [s]


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

    def check_shapes(self) -> None:
        """LogError naming the array or name list that does not fit the others (a trajectory
        built by hand for ``write_log``): names as a tuple of strings (a string is not one),
        ``time`` (T,), ``goal`` and every channel (T, len(actuators)), ``qpos`` and ``qvel``
        (T, len(joints)), ``goal_time`` (T,)."""
        for what in ("actuators", "joints"):
            names = getattr(self, what)
            if isinstance(names, str) or not all(isinstance(n, str) for n in names):
                example = (names,) if isinstance(names, str) else ("j",)
                raise LogError(f"Trajectory {self.name!r}: {what}={names!r} must be a tuple of "
                               f"names, e.g. {example!r}")
        n = np.shape(self.time)[0] if np.ndim(self.time) == 1 else None
        if n is None:
            raise LogError(f"Trajectory {self.name!r}: time has shape {np.shape(self.time)}; it "
                           "must be (T,), one time [s] per sample")
        arrays = [("goal", self.goal, "actuators"), ("qpos", self.qpos, "joints"),
                  ("qvel", self.qvel, "joints"),
                  *((f"channels[{k!r}]", v, "actuators") for k, v in self.channels.items())]
        for what, arr, per in arrays:
            names = getattr(self, per)
            need = (n, len(names))
            if arr is None or np.shape(arr) == need:
                continue
            hint = (f"; for one {per[:-1]} give {what}[:, None]"
                    if np.shape(arr) == (n,) and len(names) == 1 else "")
            raise LogError(f"Trajectory {self.name!r}: {what} has shape {np.shape(arr)}; it must "
                           f"be {need}: one row per time sample ({n}), one column per name in "
                           f"{per}={tuple(names)!r}{hint}")
        if self.goal_time is not None and np.shape(self.goal_time) != (n,):
            raise LogError(f"Trajectory {self.name!r}: goal_time has shape "
                           f"{np.shape(self.goal_time)}; it must be ({n},) like time")

    def check_times(self) -> None:
        """LogError unless ``time`` is finite and strictly increasing [s] (a reader sorts rows a
        little out of order with a note and refuses the rest: the writer says so first)."""
        t = np.asarray(self.time, dtype=float)
        dt = np.diff(t)
        if np.all(np.isfinite(t)) and np.all(dt > 0):
            return
        if not np.all(np.isfinite(t)):
            i = int(np.argmax(~np.isfinite(t)))
            raise LogError(f"Trajectory {self.name!r}: time[{i}] is {t[i]}: sample times [s] "
                           "must be finite numbers")
        i = int(np.argmax(dt <= 0))
        raise LogError(f"Trajectory {self.name!r}: time must be strictly increasing [s], but "
                       f"time[{i + 1}]={t[i + 1]:.9g} {'repeats' if dt[i] == 0 else 'is before'} "
                       f"time[{i}]={t[i]:.9g} (sort the rows by time: order = "
                       "np.argsort(traj.time, kind='stable'))")

    def to_columns(self) -> dict[str, np.ndarray]:
        """The log-format columns {name: (T,)}; LogError from ``check_shapes`` and
        ``check_times`` first."""
        self.check_shapes()
        self.check_times()
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
    Raises:
      LogError: source times not finite and increasing, destination times not finite, or
        values of another length than the source times (before: a silently wrong hold; a NaN
        destination time held the last value).
    """
    src, dst, values = np.asarray(t_src, float), np.asarray(t_dst, float), np.asarray(values)
    if src.ndim != 1 or len(values) != len(src) or not len(src):
        raise LogError(f"zoh: t_src of shape {src.shape} and values of shape {values.shape}: "
                       "one source time [s] per value row, at least one")
    if not (np.all(np.isfinite(src)) and np.all(np.diff(src) > 0)):
        raise LogError("zoh: t_src must be finite, strictly increasing times [s]")
    if not np.all(np.isfinite(dst)):
        raise LogError(f"zoh: t_dst holds {dst[~np.isfinite(dst)].ravel()[0]}: times [s] are "
                       "finite")
    return values[zoh_index(src, dst)]


def find_gaps(t: np.ndarray) -> np.ndarray:
    """Indices i where the step t[i] -> t[i + 1] is a gap (GAP_FACTOR median steps, >= GAP_MIN)."""
    dt = np.diff(np.asarray(t, float))
    if not len(dt):
        return np.zeros(0, int)
    return np.flatnonzero(dt > max(GAP_FACTOR * float(np.median(dt)), GAP_MIN))


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
