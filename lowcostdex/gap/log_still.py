"""Checks on entry for measured logs: a position reading that stands still while the motor is
shown moving - a position register pinned at the end of its range (``check_pinned``), or a read
that failed and was logged as the last value it got (``check_stuck``: a sensor dropout). Both
read the motion off the log's own velocity column (a servo's Present Velocity) or the
encoder's window; ``log_checks.check_signals`` calls them, in that order, before the frozen
encoder check (they also look frozen, and say more).
"""

from __future__ import annotations

import math

import numpy as np

from lowcostdex.gap.trajectory import LogError, Trajectory, quantization_step

PINNED_RUN = 5  # samples: a position reading repeated this long at its extreme may be a clip
PINNED_TRAVEL = 0.05  # [rad] how far the logged qvel moves a motor whose reading stands still
PINNED_SPEED = 0.2  # [rad/s] ... at a median speed of at least this (many velocity counts)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[a, b) of every run of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def _travel(traj: Trajectory, j: int, a: int, b: int, side: float) -> float:
    """How far joint ``j``'s logged qvel moves it (towards ``side``: +1 up, -1 down) over rows
    [a, b) at a median |qvel| of PINNED_SPEED [rad]; 0 without qvel or below that speed (one
    0.024 rad/s count through a 3 s stall is 78 mrad on real XL330 logs)."""
    if traj.qvel is None:
        return 0.0
    t, v = traj.time[a:b], traj.qvel[a:b, j]
    if np.median(np.abs(v)) <= PINNED_SPEED:
        return 0.0
    return float(np.max(np.cumsum(side * v[:-1] * np.diff(t)), initial=0))


def check_stuck(traj: Trajectory, j: int) -> None:
    """A reading repeated exactly for PINNED_RUN samples or more while the same log's qvel of
    that joint, at a median |qvel| of PINNED_SPEED, moves the motor PINNED_TRAVEL (0.05 rad,
    33 ticks of a 4096-tick encoder) away from it: the position read failed and the logger wrote
    the last value it had (a dropout), or the columns are of two joints. Refused naming the rows:
    a replay would fit the motion the reading missed. Real logs: a reading stands still for a
    few samples at a turning point while the velocity filter lags (8 mrad in 36 ms on the
    XL330), and through a stall at one velocity count."""
    q, t = traj.qpos[:, j], traj.time
    still = np.concatenate([[False], np.diff(q) == 0])
    still[:-1] |= still[1:]  # a run of repeats includes the row it repeats
    for a, b in _runs(still):
        if b - a < PINNED_RUN:
            continue
        travel = max(_travel(traj, j, a, b, 1.0), _travel(traj, j, a, b, -1.0))
        if travel > PINNED_TRAVEL:
            joint = traj.joints[j]
            raise LogError(
                f"{traj.name}: column 'qpos:{joint}' stands still at {q[a]:.6g} rad for "
                f"{b - a} rows ({t[b - 1] - t[a]:.3g} s from {t[a]:.6g} s, rows {a}-{b - 1}, "
                f"0-based) while 'qvel:{joint}' moves the motor {travel:.3g} rad away from "
                "it: a position read that failed, logged as the last value (a dropout)? "
                "Leave a failed read's cells empty (those rows are dropped and the log cut "
                "there), or cut the rows out")


def check_pinned(traj: Trajectory, j: int, goal: np.ndarray, on: np.ndarray,
                 cross: float) -> None:
    """A reading pinned at its largest (smallest) value for PINNED_RUN samples with torque on
    (``on``) while the goal (``goal``, joint units) is beyond it by ``cross`` [rad], shown to be
    a clip by the logged qvel (see ``_travel``) or by the value being an edge of the encoder's
    one-turn window."""
    q, t = traj.qpos[:, j], traj.time
    grid = quantization_step(q[:, None])
    per_turn = round(2 * math.pi / grid) if grid else 0
    for side, extreme in ((1.0, float(q.max())), (-1.0, float(q.min()))):
        at = (q == extreme) & on
        # goals that acted on each row: a row's goal is written after it was read
        acting = np.concatenate([goal[:1], goal[:-1]])
        beyond = side * (acting - extreme) > cross
        for a, b in _runs(at):  # stretches of the reading at its extreme
            if b - a < PINNED_RUN or not beyond[a:b].any():
                continue
            sign = ""
            travel = _travel(traj, j, a, b, side)  # beyond the reading and back
            if travel > PINNED_TRAVEL:
                sign = (f"while 'qvel:{traj.joints[j]}' takes the motor {travel:.3g} rad "
                        "beyond it and back")
            elif per_turn:
                tick = extreme / grid
                edge = [e for e in (0, per_turn - 1, -per_turn // 2, per_turn // 2 - 1)
                        if abs(tick - e) < 0.01]
                if edge:
                    sign = (f"tick {edge[0]} of {per_turn} per turn, an edge of the encoder's "
                            "one-turn window")
            if sign:
                far = float(np.max(side * (acting[a:b] - extreme)))
                raise LogError(
                    f"{traj.name}: column 'qpos:{traj.joints[j]}' is pinned at its "
                    f"{'largest' if side > 0 else 'smallest'} value {extreme:.6g} rad for "
                    f"{t[b - 1] - t[a]:.3g} s (from {t[a]:.6g} s) while 'goal:{traj.joints[j]}' "
                    f"is up to {far:.3g} rad beyond it, {sign}: a position clipped at its "
                    "register's range; log a reading whose range holds the motion (a multi-turn "
                    "or wider register, the limits moved)")


