"""``goal_profile``'s data gate (``gap.offer.GATES``), read from the logs before any replay.

``goal_profile`` (a servo firmware's motion profile on the goal: Dynamixel Profile Velocity /
Profile Acceleration) is fitted by default only when the logs show its signature (reference 04,
section 6: "ramped response independent of load; identical shape across loads"): after a goal
step the joint ramps to the new goal at a speed that does not grow with the step's size and is
the same both ways. A servo without a profile answers a step at a speed proportional to the step
(a linear loop: its mid-move speed doubles with the step), a torque limit at a speed that
depends on the load's direction. Fitting the profile everywhere cost 12.9 % more CPU on the
independent bench (tests/test_gap_independent_bench.py, session 21) for nothing on logs without
it; without it a profile was named ``velocity_limit`` (60.4 -> 11.9 mrad held out, a wrong cause).

The statistic (``profile_moves``, ``ramp_law``): each goal step of at least ``JUMP`` in one row,
held at least ``HOLD_ROWS`` rows, taken with its joint at rest, that moves the joint at least
``MIN_MOVE`` is one move of size d (the angle the joint settles at minus where it stood) and
speed s = d / 2 over the time it takes from 25 % to 75 % of the way (the middle of the move: the
servo's own lag and settling left out). Over a joint's moves, ``beta`` is the Theil-Sen slope of
log s on log |d| (the median over move pairs at least 1.5x apart in size: robust to a move
disturbed by another joint), ``gamma`` the log ratio of the speeds moving positive and negative
once the slope is taken out (medians). A velocity profile gives beta ~ 0 (every move long enough
cruises at the profile velocity), an acceleration-limited one at most 0.5 (a triangle: s =
0.85 sqrt(a d)), a linear servo 1. The profile is offered when some joint with ``MIN_MOVES`` moves
both ways has beta <= ``BETA_MAX`` and |gamma| <= ``GAMMA_MAX``.

Measured (gap-profile17, bench/RESULTS.md): tests/gap_truth_sim8.py's profiles beta -0.29 to
0.46 (0.46: 3 rad/s and 12 rad/s^2, every move a triangle), |gamma| <= 0.02; its torque-limited
loaded arm beta 0.48 but gamma 0.69 (faster with gravity); its clean servo 0.85; the independent
bench and finger (gap_truth_sim) >= 0.64 (a gain 5x, saturating), the README main run's
D'Claw logs >= 0.90. A saturating servo's moves approach the triangle law too (sim4's kp x3
position servo: 0.52); a speed limit is the profile's confusable (sim3's torque-speed line:
0.02): there both are offered and the fits decide.
"""

from __future__ import annotations

import mujoco
import numpy as np

from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.logs import rate_goal_actuators
from lowcostdex.gap.trajectory import Trajectory
from lowcostdex.sim import servo
from lowcostdex.sim.effects import effect
from lowcostdex.sim.effects.profile import profile_step

JUMP = 0.05        # rad (joint units): a goal change in one row this large is a step
MIN_MOVE = 0.1     # rad: a move this large is timed (a smaller one is the servo's own lag)
HOLD_ROWS = 5      # rows the goal must hold after a step
REST = 0.02        # rad: the joint moved less than this over the 3 rows before the step
PAIR_RATIO = 1.5   # move sizes at least this far apart make a pair for the slope
MIN_MOVES = 4      # moves per joint, both directions among them
BETA_MAX = 0.55    # speed ~ size^beta: a profile <= 0.5, a linear servo ~1
GAMMA_MAX = 0.25   # |log(speed moving positive / negative)|: a load's direction shows more
ACCEL_SHARE = 0.3  # the moves' acceleration at most this share of the nominal servo's force / inertia
SPEED_SHARE = 0.5  # their speed at most this share of a nominal dcmotor's no-load speed
UNCAPPED = 1e9     # rad/s: a profile velocity no move reaches (an infinite one is no profile)
TRIANGLE = 0.8536  # mid-move speed of a rest-to-rest triangle / sqrt(acceleration x size)


def position_goal_columns(ds: Dataset) -> list[tuple[int, int, float]]:
    """(goal column, qpos column, gear) of each logged actuator that takes a position goal on a
    measured joint: a ``dcmotor`` servo or an affine position law (``position``, ``general``
    written so), not a velocity goal (``intvelocity``, ``velocity``) nor a torque (``motor``)."""
    m = ds.compiled(ds.trajectories[0].model)
    rate = rate_goal_actuators(m)
    joints = ds.trajectories[0].joints
    out = []
    for col, name in enumerate(ds.actuators):
        a = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
        if a < 0 or name in rate or m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT:
            continue
        dc = m.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_DCMOTOR
        law = m.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_AFFINE and m.actuator_biasprm[a, 1] < 0
        joint = m.joint(int(m.actuator_trnid[a, 0])).name
        if (dc or law) and joint in joints and m.actuator_gear[a, 0] != 0:
            out.append((col, joints.index(joint), float(m.actuator_gear[a, 0])))
    return out


def profile_moves(tr: Trajectory, col: int, jcol: int, gear: float = 1.0) -> np.ndarray:
    """(n, 2) moves (size d [rad], mid-move speed s [rad/s]) after the goal steps of goal column
    ``col`` (joint units: goal / ``gear``) on joint column ``jcol`` (module doc)."""
    g = tr.goal[:, col] / gear
    q, t = tr.qpos[:, jcol], tr.time
    change = np.flatnonzero(np.abs(np.diff(g)) > 0) + 1
    ends = np.append(change[1:], len(g))[:len(change)]  # each step's goal holds until the next
    out = []
    for i, end in zip(change, ends, strict=True):
        if abs(g[i] - g[i - 1]) < JUMP or end - i < HOLD_ROWS or i < 4:
            continue
        if abs(q[i - 1] - q[i - 4]) > REST:
            continue
        q0 = q[i - 1]
        d = float(np.median(q[end - 3:end])) - q0
        if abs(d) < MIN_MOVE:
            continue
        f = (q[i - 1:end] - q0) / d
        tt = t[i - 1:end]
        mid = []
        for x in (0.25, 0.75):
            k = int(np.argmax(f >= x))
            if f[k] < x or k == 0:
                break
            mid.append(tt[k - 1] + (x - f[k - 1]) / (f[k] - f[k - 1]) * (tt[k] - tt[k - 1]))
        if len(mid) == 2 and mid[1] > mid[0]:
            out.append((d, 0.5 * abs(d) / (mid[1] - mid[0])))
    return np.array(out).reshape(-1, 2)


def ramp_law(moves: np.ndarray) -> tuple[float, float] | None:
    """(beta, gamma) of moves (n, 2) (module doc), None when they cannot tell: fewer than
    ``MIN_MOVES``, one direction only, or fewer than 3 pairs of sizes ``PAIR_RATIO`` apart."""
    d, s = np.abs(moves[:, 0]), moves[:, 1]
    up = moves[:, 0] > 0
    if len(d) < MIN_MOVES or up.all() or not up.any():
        return None
    ld, ls = np.log(d), np.log(s)
    i, j = np.nonzero(ld[None, :] - ld[:, None] >= np.log(PAIR_RATIO))
    if len(i) < 3:
        return None
    beta = float(np.median((ls[j] - ls[i]) / (ld[j] - ld[i])))
    r = ls - beta * ld
    return beta, float(np.median(r[up]) - np.median(r[~up]))


def nominal_limits(ds: Dataset, col: int, jcol: int, gear: float) -> tuple[float, float]:
    """(acceleration [rad/s^2], speed [rad/s]) the nominal servo of goal column ``col`` can give
    its joint (column ``jcol``): its force limit x |gear| over the joint's inertia (armature
    included) with every measured joint at its median reading in the first log (inf without a
    force limit), and a ``dcmotor``'s no-load speed Vmax / (K |gear|) (inf for other kinds or
    without a drive limit)."""
    m = ds.compiled(ds.trajectories[0].model)
    a = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, ds.actuators[col])
    d = mujoco.MjData(m)
    tr = ds.trajectories[0]
    for k, name in enumerate(tr.joints):
        d.qpos[m.jnt_qposadr[m.joint(name).id]] = float(np.median(tr.qpos[:, k]))
    mujoco.mj_forward(m, d)
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    dof = m.jnt_dofadr[m.joint(tr.joints[jcol]).id]
    force = float(servo.stall_torque(m, np.array([a]))[0])
    if not np.isfinite(force) and m.actuator_forcelimited[a]:
        force = float(np.abs(m.actuator_forcerange[a]).max())
    g = m.actuator_gainprm[a]
    dc = m.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_DCMOTOR and g[servo.GAIN_VMAX] > 0
    speed = g[servo.GAIN_VMAX] / (g[servo.GAIN_K] * abs(gear)) if dc else np.inf
    return force * abs(gear) / float(full[dof, dof]), float(speed)


def shows_profile(ds: Dataset) -> bool:
    """Whether the logs show a goal profile's ramps on some joint (module doc): its moves'
    speeds follow a profile's law, and they move slower than the nominal servo can (their
    acceleration as a triangle's, (s / TRIANGLE)^2 / |d|, at most ``ACCEL_SHARE`` of its force
    over the inertia; their speed at most ``SPEED_SHARE`` of a dcmotor's no-load speed): a
    saturating servo's moves follow the triangle law at its force, a dcmotor's plateau at its
    back-EMF, both in the nominal model already."""
    for col, jcol, gear in position_goal_columns(ds):
        moves = np.concatenate([profile_moves(tr, col, jcol, gear) for tr in ds.trajectories])
        law = ramp_law(moves)
        if law is None or law[0] > BETA_MAX or abs(law[1]) > GAMMA_MAX:
            continue
        accel, speed = nominal_limits(ds, col, jcol, gear)
        shown = float(np.median((moves[:, 1] / TRIANGLE) ** 2 / np.abs(moves[:, 0])))
        if shown <= ACCEL_SHARE * accel and np.median(moves[:, 1]) <= SPEED_SHARE * speed:
            return True
    return False


def fastest_profile(tr: Trajectory, col: int, gear: float, acceleration: float) -> float:
    """The fastest a profile without a velocity cap, at ``acceleration`` [rad/s^2], moves its
    setpoint over trajectory ``tr``'s goals of column ``col`` (joint units; each row's goal held
    to the next row, stepped at 1 ms or finer) [rad/s]: a profile velocity above it caps no move
    of these logs."""
    g = tr.goal[:, col] / gear
    p, w, top = np.array(g[0]), np.array(0.0), 0.0
    for k in range(len(g) - 1):
        span = float(tr.time[k + 1] - tr.time[k])
        n = max(1, int(np.ceil(span / 1e-3)))
        for _ in range(n):
            p, w = profile_step(p, w, np.array(g[k]), np.array(UNCAPPED), np.array(acceleration),
                                span / n)
            top = max(top, abs(float(w)))
    return top


def _fastest(ds: Dataset, col: int, gear: float, acceleration: float) -> float:
    """``fastest_profile`` over the logs."""
    return max(fastest_profile(tr, col, gear, acceleration) for tr in ds.trajectories)


def uncapped_velocity(ds: Dataset, joints: tuple[str, ...], params: dict) -> list[str]:
    """``goal_profile``'s velocity where no move of the logs reaches it (sim8's 3 rad/s with 12
    rad/s^2: every move a triangle): any velocity above the fastest the profile moves at the
    fitted acceleration (``fastest_profile``) replays the logs alike, so the data bound it from
    below only, by that speed at the acceleration's lower 95 % end (a triangle's peak grows as
    its root). There the velocity's interval becomes [that speed, the search's limit],
    ``lower_bound_only`` is set per joint, and a line says so (returned, for the cause's
    flags). ``params``: the cause's report (``results.param_report``), changed in place;
    ``joints``: its joints."""
    vel, acc = params.get("velocity"), params.get("acceleration")
    if vel is None:
        return []
    cols = {ds.trajectories[0].joints[j]: (c, g) for c, j, g in position_goal_columns(ds)}
    hi = effect("goal_profile").param("velocity").limit[1]
    out = []
    vel["lower_bound_only"] = [False] * len(joints)
    for k, name in enumerate(joints):
        v = vel["value"][k]
        a, a_lo = (acc["value"][k], acc["interval"][k][0]) if acc is not None else (0.0, 0.0)
        if name not in cols or v is None or not 0 < v < np.inf or a is None or not 0 < a < np.inf:
            continue  # (without an acceleration limit every goal step moves at the velocity)
        c, g = cols[name]
        if _fastest(ds, c, g, a) >= v:
            continue
        lo = _fastest(ds, c, g, a_lo if a_lo is not None and 0 < a_lo < a else a)
        vel["interval"][k] = [lo, hi]
        vel["lower_bound_only"][k] = True
        out.append(f"velocity[{name}]: no move reaches it (the profile moves at most "
                   f"{lo:.3g} rad/s at the acceleration's lower end): at least {lo:.3g} rad/s, "
                   f"not identifiable above (the interval's upper end is the search's limit)")
    return out
