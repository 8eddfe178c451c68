"""Positions and velocities of a log in another unit than rad and rad/s, told from the data
itself: a logged velocity that integrates to another multiple of the positions' distance
(deg/s, rpm, Dynamixel counts - or positions in degrees beside velocities in rad/s), and
positions on a whole-degree encoder grid (a 4096-tick encoder read in degrees steps by
360/4096 = 0.0879; in rad it steps by 0.00153). A log in degrees that moves less than
4 pi (12.6 deg) passes the plausible-range check of ``log_checks``; these checks name it.
What an actuator's input is (a position, a velocity, a force: only positions are angles) is
said here too (``actuator_input``).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from lowcostdex.gap.trajectory import LogError, Trajectory

if TYPE_CHECKING:
    import mujoco

# velocity units whose values fit the plausible range at a slow joint: unit -> values per rad/s
VELOCITY_UNITS = {"deg/s": 180 / math.pi, "rpm": 30 / math.pi,
                  "0.229 rpm counts (Dynamixel X)": 30 / (0.229 * math.pi),
                  "0.114 rpm counts (Dynamixel MX, Protocol 1)": 30 / (0.114 * math.pi),
                  "steps/s (4096 a turn)": 4096 / (2 * math.pi)}
TO_RAD = "multiply the 'qpos:' and 'goal:' columns by pi/180 (numpy.radians)"

DEGREE_GRIDS: tuple[tuple[float, str], ...] = (
    # (one encoder step in degrees, the encoder): steps as Dynamixel's e-manual rounds them too
    (360 / 4096, "360/4096: a 4096-tick encoder (Dynamixel X/MX, Feetech STS)"),
    (0.088, "0.088 deg: the Dynamixel e-manual's position unit"),
    (300 / 1024, "300/1024: a 1024-tick servo over 300 deg (Dynamixel AX, XL-320)"),
    (0.29, "0.29 deg: the Dynamixel AX e-manual's position unit"),
    (360 / 16384, "360/16384: a 14-bit magnetic encoder (AS5048)"),
)
RADIAN_GRIDS: tuple[tuple[float, str], ...] = (
    (2 * math.pi / 4096, "2 pi/4096 rad: a 4096-tick encoder (Dynamixel X/MX, Feetech STS)"),
    (math.radians(300) / 1024, "300 deg/1024 in rad: a 1024-tick servo (Dynamixel AX, XL-320)"),
    (2 * math.pi / 16384, "2 pi/16384 rad: a 14-bit magnetic encoder (AS5048)"),
)
GRID_TOLERANCE = 0.05  # of a step: each difference between readings this close to whole steps
GRID_VALUES = 8  # distinct readings needed to call a grid


def check_velocity_unit(t: np.ndarray, q: np.ndarray, v: np.ndarray, joint: str,
                        name: str) -> None:
    """Refuse a logged velocity in another unit, named: the distance it integrates to is the
    positions' (sum |v| dt / sum |dq| was 0.98-1.22 on every measured BAM log) - unless it is
    within 25 % of a unit's factor, and the joint moved at least 0.5 (rad, as logged) in all.
    A ratio of pi/180 is positions in degrees beside velocities in rad/s."""
    dq = float(np.nansum(np.abs(np.diff(q))))
    if dq < 0.5:
        return
    ratio = float(np.nansum(np.abs(v[1:]) * np.diff(t))) / dq
    units = [f"{u} (x{f:.3g})" for u, f in VELOCITY_UNITS.items() if 0.75 < ratio / f < 1.25]
    if units:
        raise LogError(f"{name}: column 'qvel:{joint}' integrates to {ratio:.3g} x the distance "
                       f"'qpos:{joint}' moves: {' or '.join(units)}? write rad/s")
    if 0.75 < ratio * 180 / math.pi < 1.25:
        raise LogError(f"{name}: column 'qvel:{joint}' integrates to {ratio:.3g} x the distance "
                       f"'qpos:{joint}' moves (pi/180 = 0.0175): positions in degrees beside "
                       f"velocities in rad/s? write rad: {TO_RAD}")


def degree_grid(q: np.ndarray, grids: tuple[tuple[float, str], ...] = DEGREE_GRIDS) -> str:
    """The encoder whose step in degrees ``q``'s readings (T,) lie on ('' if none): every
    difference between two distinct readings a whole number of one ``grids`` step
    (within ``GRID_TOLERANCE`` of a step; an offset added to every reading keeps it), one step
    among them, over at least ``GRID_VALUES`` distinct readings."""
    u = np.unique(q[np.isfinite(q)])
    if len(u) < GRID_VALUES:
        return ""
    d = np.diff(u)
    for step, what in grids:
        k = d / step
        if np.all(np.abs(k - np.round(k)) < GRID_TOLERANCE) and np.any(np.round(k) == 1):
            return what
    return ""


def check_degree_grid(q: np.ndarray, joint: str, name: str) -> None:
    """Refuse positions read in degrees, told by their encoder grid (``degree_grid``)."""
    what = degree_grid(q)
    if what:
        raise LogError(f"{name}: column 'qpos:{joint}' reads on a grid of {what}, its "
                       f"{len(np.unique(q))} distinct values whole steps apart: an encoder read "
                       f"in degrees? (in rad a 4096-tick encoder steps by "
                       f"{math.radians(360 / 4096):.3g}); its values {float(np.min(q)):.6g} to "
                       f"{float(np.max(q)):.6g} are degrees, not rad: {TO_RAD}")


def check_goal_degrees(traj: Trajectory, model: mujoco.MjModel, i: int, joint: str,
                       margin: float) -> None:
    """Goals in degrees beside positions in rad: a position servo's goal (goal / gear) beyond
    its limited joint's range by more than the range's width, inside it read as degrees, and
    the joint following it at pi/180 of its swing (the least-squares slope of the reading on
    the goal within 0.4-1.6 x pi/180, correlation above 0.9). A goal far beyond the range
    alone is not refused: a servo pushed against a hard stop reads still at the stop.
    ``i``: the actuator (a position servo on ``joint``); ``margin`` [rad]: the slack of the
    range (``log_checks.RANGE_MARGIN``)."""
    actuator = model.actuator(i).name
    jid = model.joint(joint).id
    if not model.jnt_limited[jid] or actuator not in traj.actuators or joint not in traj.joints:
        return
    lo, hi = (float(x) for x in model.jnt_range[jid])
    g = traj.goal[:, traj.actuators.index(actuator)] / float(model.actuator_gear[i, 0] or 1.0)
    q = traj.qpos[:, traj.joints.index(joint)]
    width = max(hi - lo, margin)
    far = (g < lo - width) | (g > hi + width)
    deg = np.radians(g)
    if not far.any() or np.any((deg < lo - margin) | (deg > hi + margin)):
        return
    sg, sq = float(np.std(g)), float(np.std(q))
    if sg == 0.0 or sq == 0.0:
        return
    corr = float(np.mean((g - g.mean()) * (q - q.mean())) / (sg * sq))
    slope = corr * sq / sg
    if corr < 0.9 or not 0.4 < slope * 180 / math.pi < 1.6:
        return
    r = int(np.argmax(far))
    why = (f"goals in degrees beside positions in rad: read as degrees the goals span "
           f"[{deg.min():.4g}, {deg.max():.4g}] rad, inside the range, and 'qpos:{joint}' "
           f"follows them at {slope:.3g} x (pi/180 = 0.0175); multiply the 'goal:' column by "
           "pi/180 (numpy.radians)")
    raise LogError(f"{traj.name}: column 'goal:{actuator}' reads {g[r]:.6g} rad at row {r} "
                   f"(0-based), beyond joint {joint!r}'s range [{lo:.4g}, {hi:.4g}] rad by more "
                   f"than its width ({why})")


def check_not_radians(q: np.ndarray, joint: str, name: str) -> None:
    """Refuse a log read as degrees (``gap analyze --units deg``) whose positions, as written,
    lie on an encoder's grid in rad (``RADIAN_GRIDS``): it was in rad already, and the
    conversion would shrink its motion 57 times."""
    what = degree_grid(q, RADIAN_GRIDS)
    if what:
        raise LogError(f"{name}: column 'qpos:{joint}' as written reads on a grid of {what}, "
                       f"its {len(np.unique(q))} distinct values whole steps apart: the log is "
                       "in rad already; leave out --units deg (read_log's angle_scale: 1)")


ACTUATOR_INPUTS = ("position", "velocity", "muscle", "force")
"""What an actuator's input is (``actuator_input``)."""


def actuator_input(model: mujoco.MjModel, i: int) -> str:
    """What actuator ``i``'s input (ctrl, a log's ``goal:`` column) is, one of
    ``ACTUATOR_INPUTS``: 'position' for a setpoint (a ``dcmotor`` servo, or an affine bias with a
    position term, as ``position``, ``intvelocity`` and ``general`` servos write it),
    'velocity' (an affine bias with a velocity term only), 'muscle', or 'force' (a force or
    torque, times its gear: ``motor`` and the rest)."""
    import mujoco

    if model.actuator_gaintype[i] == mujoco.mjtGain.mjGAIN_DCMOTOR:
        return "position"
    if model.actuator_biastype[i] == mujoco.mjtBias.mjBIAS_AFFINE:
        if model.actuator_biasprm[i, 1] < 0:
            return "position"
        if model.actuator_biasprm[i, 2] < 0:
            return "velocity"
    if model.actuator_gaintype[i] == mujoco.mjtGain.mjGAIN_MUSCLE:
        return "muscle"
    return "force"


def not_a_position_servo(model: mujoco.MjModel, i: int) -> str:
    """What actuator ``i`` is, said for a message, when its input is not a position setpoint
    ('' when it is one; ``actuator_input`` is the predicate)."""
    kind = actuator_input(model, i)
    if kind == "position":
        return ""
    if kind == "velocity":
        return "a velocity servo (its input is a velocity)"
    if kind == "muscle":
        return "a muscle"
    gear = float(model.actuator_gear[i, 0])
    return ("a motor: its input is a force or torque" + (f" (x gear {gear:g})" if gear != 1
                                                          else "") + ", not a position")


def actuators_taking(model: mujoco.MjModel, kinds: tuple[str, ...]) -> frozenset[str]:
    """The names of ``model``'s actuators whose input (``actuator_input``) is one of ``kinds``."""
    return frozenset(model.actuator(i).name for i in range(model.nu)
                     if actuator_input(model, i) in kinds)


SUSTAINED_SPEED = 50.0  # [rad/s] past any servo's (the motor table's fastest: XL330-M077, 40.1)
SUSTAINED_TRAVEL = 2 * math.pi  # [rad] a whole turn at that speed, in one stretch, no servo does


def longest_fast_travel(t: np.ndarray, q: np.ndarray, speed: float = SUSTAINED_SPEED
                        ) -> tuple[float, float, int]:
    """(travel [rad], duration [s], first row) of the stretch of consecutive steps of ``q``
    (T,) over ``t`` (T,) [s] each faster than ``speed`` [rad/s] that covers the most distance;
    (0, 0, 0) when no step is that fast."""
    dq = np.abs(np.diff(q))
    dt = np.diff(t)
    fast = dq > speed * dt
    if not fast.any():
        return 0.0, 0.0, 0
    edges = np.diff(np.concatenate([[0], fast.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    cum_q, cum_t = np.concatenate([[0.0], np.cumsum(dq)]), np.concatenate([[0.0], np.cumsum(dt)])
    travel = cum_q[ends] - cum_q[starts]
    k = int(np.argmax(travel))
    return float(travel[k]), float(cum_t[ends[k]] - cum_t[starts[k]]), int(starts[k])


def check_sustained_speed(traj: Trajectory) -> None:
    """Refuse positions that cover SUSTAINED_TRAVEL (a whole turn) in one stretch of steps all
    faster than SUSTAINED_SPEED: no servo turns that fast for that long, and a smooth log in
    degrees does (a 12 deg, 1 Hz sine read as rad: 18 'rad' at over 50 'rad/s' in each swing,
    while its 99th-percentile speed, 75, stays under the 100 rad/s limit of
    ``log_checks.check_signals``). A stiff arm's step is brief: a plain MuJoCo position servo
    stepping 5.2 rad (tests/test_gap_offer.py) covers at most 4.3 rad above 50 rad/s; the 104
    readable real BAM logs move below 16.2 rad/s throughout."""
    for j, joint in enumerate(traj.joints):
        travel, seconds, row = longest_fast_travel(traj.time, traj.qpos[:, j])
        if travel >= SUSTAINED_TRAVEL:
            peak = float(np.max(np.abs(np.diff(traj.qpos[:, j])) / np.diff(traj.time)))
            raise LogError(
                f"{traj.name}: column 'qpos:{joint}' moves at up to {peak:.4g} rad/s and "
                f"{travel:.4g} rad in {seconds:.3g} s from row {row} (0-based), every step faster "
                f"than {SUSTAINED_SPEED:g} rad/s: servos move below {SUSTAINED_SPEED:g} rad/s "
                "(the fastest, XL330-M077, 40.1 unloaded), never a whole turn beyond it; is "
                f"'qpos' in degrees (then {TO_RAD}) and 'time' in seconds?")


MODEL_SPEED_MARGIN = 3.0  # x the model's top speed; measured logs reach at most 0.87 of it
MODEL_SPEED_WINDOW = 0.1  # [s] shortest stretch held above it (or 3 of the joint's I / b)


def model_top_speed(model: mujoco.MjModel, joint: str) -> tuple[float, float, float, float]:
    """(top speed [rad/s], drive [N m], damping [N m s/rad], time constant [s]) of the hinge
    ``joint`` in ``model``: the speed at which its damping eats the most its own actuators
    and gravity can push, (F + G) / b. F: each joint-transmission actuator's force range top
    (a dcmotor servo: its stall torque K Vmax / R, its back-EMF K^2 / R added to b), times its
    gear; G: gravity on the joint's subtree at its farthest (sum of m g |r|, r from the axis's
    anchor at qpos0); b: the joint's damping. The actuators' own damping (kv) is left out, so
    the bound is high. inf where nothing bounds it: a joint without its own actuator (contacts
    or tendons drive it), one in a tendon or a joint equality, an actuator without a force
    limit, or no damping."""
    import mujoco

    from lowcostdex.sim import servo  # only here: log checks without a model do not need it

    j = model.joint(joint).id
    if int(model.jnt_type[j]) != int(mujoco.mjtJoint.mjJNT_HINGE):  # degrees: hinges only
        return math.inf, 0.0, 0.0, 0.0
    if _coupled(model, j):
        return math.inf, 0.0, 0.0, 0.0
    own = np.flatnonzero(model.actuator_trnid[:, 0] == j)
    force, damping = 0.0, float(model.dof_damping[model.jnt_dofadr[j]])
    for i in own:
        gear = abs(float(model.actuator_gear[i, 0]))
        top = (float(np.abs(model.actuator_forcerange[i]).max())
               if model.actuator_forcelimited[i] else math.inf)
        g = model.actuator_gainprm[i]
        r, k, vmax = (float(g[x]) for x in (servo.GAIN_R, servo.GAIN_K, servo.GAIN_VMAX))
        if (int(model.actuator_gaintype[i]) == int(mujoco.mjtGain.mjGAIN_DCMOTOR)
                and vmax > 0 and r > 0):
            top = min(top, k * vmax / r)
            damping += gear ** 2 * k * k / r
        force += gear * top
    if not len(own) or not math.isfinite(force) or damping <= 0:
        return math.inf, 0.0, 0.0, 0.0
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    mujoco.mj_comPos(model, data)
    sub = [b for b in range(model.nbody) if _descends(model, b, int(model.jnt_bodyid[j]))]
    arm = [float(np.linalg.norm(data.xipos[b] - data.xanchor[j])) for b in sub]
    gravity = float(np.linalg.norm(model.opt.gravity)) * float(
        np.dot(model.body_mass[sub], arm))
    inertia = float(model.dof_M0[model.jnt_dofadr[j]])
    return (force + gravity) / damping, force + gravity, damping, inertia / damping


def speed_unchecked(model: mujoco.MjModel, trajs: list[Trajectory]) -> list[str]:
    """Notes on the measured continuous hinges (no range) that turn more than a whole turn
    (2 pi, read as rad) in ``trajs``, driven by an actuator of their own, whose model gives no
    top speed (``model_top_speed``: an actuator without a force range, or a joint without
    damping): on them ``check_model_speed`` cannot tell a log in degrees from one in rad (a
    position servo without a force limit is linear: the same log at 57 x the scale replays as
    well), and a degrees log of a 6.3 deg swing reads as a whole turn. The unit was taken on
    trust; said, with what lets the analysis check."""
    import mujoco

    notes = []
    for name in dict.fromkeys(j for tr in trajs for j in tr.joints):
        j = model.joint(name).id
        span = max(float(np.ptp(tr.qpos[:, tr.joints.index(name)])) for tr in trajs
                   if name in tr.joints)
        own = np.flatnonzero((model.actuator_trnid[:, 0] == j)
                             & (model.actuator_trntype == int(mujoco.mjtTrn.mjTRN_JOINT)))
        if (span <= 2 * math.pi or int(model.jnt_type[j]) != int(mujoco.mjtJoint.mjJNT_HINGE)
                or model.jnt_limited[j] or not len(own) or _coupled(model, j)
                or math.isfinite(model_top_speed(model, name)[0])):
            continue
        why = [f"actuator {model.actuator(int(i)).name!r} has no forcerange" for i in own
               if not model.actuator_forcelimited[i]
               and int(model.actuator_gaintype[i]) != int(mujoco.mjtGain.mjGAIN_DCMOTOR)]
        if float(model.dof_damping[model.jnt_dofadr[j]]) <= 0:
            why.append(f"joint {name!r} has no damping")
        if why:  # (a dcmotor without its stall numbers: nothing simple to add)
            notes.append(f"joint {name!r} turns {span:.3g} rad without a range and its model "
                         f"gives it no top speed ({'; '.join(why)}), so a log in degrees could "
                         "not be told from one in rad: its 'qpos' was read as rad (give --units "
                         "deg if it is in degrees); the servo's stall torque as forcerange and "
                         "the joint's damping in the MJCF let the analysis check")
    return notes


def _coupled(model: mujoco.MjModel, j: int) -> bool:
    """Whether something other than its own joint actuators drives joint ``j``: an actuator of
    the model on another transmission, a tendon through it, a joint equality on it."""
    import mujoco

    joint_trn = int(mujoco.mjtTrn.mjTRN_JOINT)
    return bool(np.any(model.actuator_trntype != joint_trn) or np.any(model.wrap_objid[
        model.wrap_type == int(mujoco.mjtWrap.mjWRAP_JOINT)] == j)
        or np.any((model.eq_type == int(mujoco.mjtEq.mjEQ_JOINT))
                  & ((model.eq_obj1id == j) | (model.eq_obj2id == j))))


def _descends(model: mujoco.MjModel, body: int, root: int) -> bool:
    while body > 0:
        if body == root:
            return True
        body = int(model.body_parentid[body])
    return False


def check_model_speed(traj: Trajectory, model: mujoco.MjModel) -> None:
    """Refuse a joint that stays faster than MODEL_SPEED_MARGIN x its model's top speed
    (``model_top_speed``) for MODEL_SPEED_WINDOW (or 3 time constants I / b): a log in
    degrees read as rad moves 57 times as fast, which no range check sees on a continuous
    joint that turns less than 4 pi degrees. On the 104 readable real BAM logs (their bench
    models) and 425 joints of the truth simulators' logs (sim2-sim10, their users' models)
    the fastest such stretch was 0.86 and 0.87 of the top speed."""
    for c, joint in enumerate(traj.joints):
        if joint not in {model.joint(i).name for i in range(model.njnt)}:
            continue
        top, drive, damping, tau = model_top_speed(model, joint)
        if not math.isfinite(top):
            continue
        dt = np.diff(traj.time)
        speed = np.abs(np.diff(traj.qpos[:, c])) / dt
        window = max(MODEL_SPEED_WINDOW, 3 * tau)
        n = max(2, math.ceil(window / float(np.median(dt))))
        if len(speed) < n:
            continue
        held = np.lib.stride_tricks.sliding_window_view(speed, n).min(axis=1)
        row = int(np.argmax(held))
        if held[row] <= MODEL_SPEED_MARGIN * top:
            continue
        raise LogError(
            f"{traj.name}: column 'qpos:{joint}' moves at {held[row]:.4g} rad/s or faster for "
            f"{n} rows from row {row} (0-based), {held[row] / top:.3g} x the fastest its model "
            f"can drive it: {drive:.3g} N m (its actuator's top and gravity's) against its "
            f"damping {damping:.3g} N m s/rad stop it at {top:.3g} rad/s. Read as degrees it "
            f"moves at {math.radians(held[row]):.3g} rad/s: is 'qpos' in degrees? (then "
            f"{TO_RAD}); else the model's damping or force range is off by more than "
            f"{MODEL_SPEED_MARGIN:g}x: correct them in the MJCF")
