"""The deadband's motion-phase signature on torque-commanded joints (``motion_band_scores``):
while a joint moves, a band takes a fixed force off its drive on the COMMAND's side, where a dry
friction takes it off on the SPEED's side. Where a joint decelerates (command against the speed)
the two part: the band weakens the braking, friction strengthens it. Rests alone cannot tell a
band from a reading offset when every loaded rest leans one way (sim6's torque rig); the moves
can. Only ``motor`` actuators (a host writing torques): there the force between two rows is the
logged command, exactly; a position servo's force moves with the unlogged path inside a row,
and the same fit on position servos scored clean logs 8-9.5 standard errors (sim2's clean
pendulums: measured, so not used there; their rests carry ``gap.offer``'s gate).

Per trajectory, the readings are smoothed by a local quadratic over ``WINDOW`` s (their speed
and acceleration at each row); every force is compared through the same filter (a force held
over each row period, integrated twice through a unit mass and differentiated twice by the same
local quadratic: exact for a constant mass), so that a goal's step is seen as the filter sees
the motion it causes. Per effect joint the residual of the nominal model's dynamics,

    r = M qacc + bias - passive - actuator   (N m, at the smoothed state, goals as logged)

is fitted (least squares, every row not at a contact or limit, torque on) by the catalogue's
confusable terms written out, each through the filter: a gain on the actuator's force, the
gravity load (a mass error; an inertia error moves the fit along these two and the damping),
the load's slope (a reading offset), a constant, viscous (-qdot) and Coulomb (-sign qdot where
the joint moves) friction, the actuator force's rate (a latency), and the band's term:
-sign(command) times the gear where the command is beyond a tenth of its median size (the band
width w, N m of command, is its coefficient). Its standard error comes from a jackknife over
``BLOCKS`` contiguous blocks of rows (the smoothing correlates neighbouring rows), and its
score is coefficient / standard error (``gap.offer.band_shown`` offers the deadband above
``MOTION_Z``).
"""

from __future__ import annotations

import mujoco
import numpy as np

from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.diagnostics import noise_floor
from lowcostdex.sim.effects.base import driving_actuator
from lowcostdex.sim.effects.deadband import torque_motor

WINDOW = 0.03  # [s] half-width of the local quadratic (at least ``MIN_HALF`` rows)
MIN_HALF = 3
BLOCKS = 20  # jackknife blocks
MIN_ROWS = 200  # rows a joint needs for the fit to judge
TERMS = ("gain", "gravity", "slope", "constant", "viscous", "coulomb", "rate", "band")


def _quadratic_filters(t: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """(rows, 2 half + 1) weights giving each inner row's first and second derivatives from a
    least-squares quadratic through the rows around it (actual times)."""
    n = len(t) - 2 * half
    idx = np.arange(n)[:, None] + np.arange(2 * half + 1)[None, :]
    dt = t[idx] - t[half:len(t) - half, None]
    x = np.stack([np.ones_like(dt), dt, dt * dt], axis=2)  # (n, w, 3)
    xtx = np.einsum("nwi,nwj->nij", x, x)
    pinv = np.linalg.solve(xtx, np.transpose(x, (0, 2, 1)))  # (n, 3, w)
    return pinv[:, 1, :], 2.0 * pinv[:, 2, :]


def _through_filter(t: np.ndarray, f: np.ndarray, d2: np.ndarray, half: int) -> np.ndarray:
    """A force series held over each row's period (T, k), seen through the acceleration filter:
    integrated twice through a unit mass, then ``d2``."""
    h = np.diff(t)[:, None]
    v = np.concatenate([np.zeros((1, f.shape[1])), np.cumsum(f[:-1] * h, axis=0)])
    p = np.concatenate([np.zeros((1, f.shape[1])),
                        np.cumsum(v[:-1] * h + 0.5 * f[:-1] * h * h, axis=0)])
    idx = np.arange(len(t) - 2 * half)[:, None] + np.arange(2 * half + 1)[None, :]
    return np.einsum("nw,nwk->nk", d2, p[idx])


def _rows(ds: Dataset, ti: int, floor: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per effect joint of trajectory ``ti``: (residual (n,), regressors (n, len(TERMS)))."""
    tr = ds.trajectories[ti]
    m = ds.compiled(tr.model)
    d = mujoco.MjData(m)
    joints = [j for j in ds.effect_joints if j in tr.joints
              and is_motor(m, driving_actuator(m, j)) and _name(m, driving_actuator(m, j)) in tr.actuators]
    t = tr.time
    if not joints or len(t) < 3:
        return {}
    period = float(np.median(np.diff(t)))
    half = max(MIN_HALF, int(round(WINDOW / period)))
    if len(t) < 4 * half + 2:
        return {}
    d1, d2 = _quadratic_filters(t, half)
    idx = np.arange(len(t) - 2 * half)[:, None] + np.arange(2 * half + 1)[None, :]
    qd = np.einsum("nw,nwk->nk", d1, tr.qpos[idx])
    qdd = np.einsum("nw,nwk->nk", d2, tr.qpos[idx])
    inner = np.arange(half, len(t) - half)
    adr = [int(m.jnt_qposadr[m.joint(n).id]) for n in tr.joints]
    dof = [int(m.jnt_dofadr[m.joint(n).id]) for n in tr.joints]
    act = [m.actuator(n).id for n in tr.actuators]
    vj = [int(m.jnt_dofadr[m.joint(j).id]) for j in joints]
    aj = [driving_actuator(m, j) for j in joints]
    gear = np.array([float(m.actuator_gear[a, 0]) for a in aj])
    # per row (all rows: forces held over each period): actuator, gravity, passive, drive
    T = len(t)
    fact, grav, slope, passive, drive = (np.zeros((T, len(joints))) for _ in range(5))
    blocked = np.zeros((T, len(joints)), bool)
    on = tr.channels.get("torque_enable")
    qv_all = np.zeros((T, len(tr.joints)))
    qv_all[half:T - half] = qd
    for k in range(T):
        set_pose(m, d, adr, act, tr.qpos[k], tr.goal[k])
        grav[k] = d.qfrc_bias[vj]
        blocked[k] = blocked_dofs(m, d)[vj]
        d.qvel[dof] = qv_all[k]
        mujoco.mj_forward(m, d)
        fact[k] = d.qfrc_actuator[vj]
        passive[k] = d.qfrc_passive[vj] - (d.qfrc_bias[vj] - grav[k])
        drive[k] = d.ctrl[aj]
    for c, v in enumerate(vj):  # the load's slope: a reading offset moves the load by it
        jc = tr.joints.index(joints[c])
        slope[:, c] = _slope(m, d, adr, tr.qpos, v, jc, max(float(floor[jc]), 1e-4), grav[:, c])
    out = {}
    mass = np.zeros((len(inner), len(joints)))
    for n, k in enumerate(inner):
        mujoco.mj_resetData(m, d)
        d.qpos[adr] = tr.qpos[k]
        mujoco.mj_forward(m, d)
        acc, res = np.zeros(m.nv), np.zeros(m.nv)
        acc[dof] = qdd[n]
        mujoco.mj_mulM(m, d, res, acc)
        mass[n] = res[vj]
    rate = np.gradient(fact, t, axis=0)
    filt = lambda f: _through_filter(t, f, d2, half)  # noqa: E731
    known = filt(fact + passive - grav)
    for c, j in enumerate(joints):
        jc = tr.joints.index(j)
        speed = qd[:, jc]
        moving = np.abs(speed) > 20 * max(float(floor[jc]), 1e-4) / (2 * half * period)
        coul = np.zeros(T)
        coul[inner] = -np.sign(speed) * moving
        big = np.abs(drive[:, c]) > 0.1 * np.median(np.abs(drive[:, c])) + 1e-12
        band = -np.sign(drive[:, c]) * gear[c] * big
        visc = np.zeros(T)
        visc[inner] = -speed
        raw = np.column_stack([fact[:, c], -grav[:, c], slope[:, c], np.ones(T),
                               visc, coul, rate[:, c], band])
        x = filt(raw)
        y = mass[:, c] - known[:, c]
        ok = ~blocked[inner, c]
        ok &= ~_near(blocked[:, c], half)[inner]
        if on is not None:
            ok &= ~_near(on[:, tr.actuators.index(_name(m, aj[c]))] < 0.5, half)[inner]
        out[j] = (y[ok], x[ok])
    return out


def _near(flag: np.ndarray, half: int) -> np.ndarray:
    """(T,) rows within ``half`` rows of a flagged one."""
    return np.convolve(flag.astype(float), np.ones(2 * half + 1), "same") > 0


def set_pose(m: mujoco.MjModel, d: mujoco.MjData, adr: list[int], act: list[int],
             q: np.ndarray, goal: np.ndarray) -> None:
    """``mj_forward`` at pose ``q`` (at ``adr``), velocity 0, goals held (a filtered position
    goal settled at its goal)."""
    mujoco.mj_resetData(m, d)
    d.qpos[adr] = q
    d.ctrl[act] = goal
    for i, a in enumerate(act):
        if m.actuator_actadr[a] >= 0 and m.actuator_dyntype[a] != mujoco.mjtDyn.mjDYN_INTEGRATOR:
            d.act[m.actuator_actadr[a]] = goal[i]
    mujoco.mj_forward(m, d)


def _slope(m: mujoco.MjModel, d: mujoco.MjData, adr: list[int], qpos: np.ndarray, v: int,
           jc: int, h: float, grav: np.ndarray) -> np.ndarray:
    """(T,) d(gravity load on dof v)/d(joint jc) at each row [N m/rad]."""
    out = np.empty(len(qpos))
    for k in range(len(qpos)):
        mujoco.mj_resetData(m, d)
        d.qpos[adr] = qpos[k]
        d.qpos[adr[jc]] += h
        mujoco.mj_forward(m, d)
        out[k] = (d.qfrc_bias[v] - grav[k]) / h
    return out


def _name(m: mujoco.MjModel, a: int) -> str:
    """Actuator ``a``'s name."""
    return mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a)


def is_motor(m: mujoco.MjModel, a: int) -> bool:
    """A torque-driven actuator (fixed gain, no bias, no activation): its goal is a command."""
    return bool(torque_motor(m.actuator_gaintype[a], m.actuator_biastype[a],
                             m.actuator_dyntype[a]))


def blocked_dofs(m: mujoco.MjModel, d: mujoco.MjData) -> np.ndarray:
    """(nv,) dofs held by a contact or a joint limit at the last ``mj_forward``'s pose."""
    out = np.zeros(m.nv, bool)
    if d.ncon:
        out[:] = True  # (a contact's Jacobian spans the chain: leave the rest out)
    for i in range(d.nefc):
        if d.efc_type[i] == mujoco.mjtConstraint.mjCNSTR_LIMIT_JOINT:
            out[m.jnt_dofadr[d.efc_id[i]]] = True
    return out


def motion_band_fits(ds: Dataset) -> dict[str, dict]:
    """Per effect joint: {"coef": per TERMS, "z": per TERMS (jackknife), "rows": n}."""
    floor = noise_floor(ds.trajectories)
    ys: dict[str, list] = {}
    xs: dict[str, list] = {}
    for ti in range(len(ds.trajectories)):
        for j, (y, x) in _rows(ds, ti, floor).items():
            ys.setdefault(j, []).append(y)
            xs.setdefault(j, []).append(x)
    out = {}
    for j in ys:
        y, x = np.concatenate(ys[j]), np.concatenate(xs[j])
        keep = np.any(x != 0, axis=0)
        if len(y) < MIN_ROWS or not keep[-1]:
            continue
        xk = x[:, keep]
        scale = np.maximum(np.abs(xk).max(axis=0), 1e-300)
        xs_ = xk / scale
        coef = np.linalg.lstsq(xs_, y, rcond=None)[0]
        parts = np.array_split(np.arange(len(y)), BLOCKS)
        jack = np.array([np.linalg.lstsq(np.delete(xs_, p, 0), np.delete(y, p), rcond=None)[0]
                         for p in parts])
        se = np.sqrt((BLOCKS - 1) / BLOCKS * np.sum((jack - jack.mean(0)) ** 2, axis=0))
        rss = float(np.sum((y - xs_ @ coef) ** 2))
        rest = np.linalg.lstsq(xs_[:, :-1], y, rcond=None)[0]
        rss0 = float(np.sum((y - xs_[:, :-1] @ rest) ** 2))
        c_full = np.full(len(TERMS), np.nan)
        z_full = np.full(len(TERMS), np.nan)
        c_full[keep] = coef / scale
        z_full[keep] = coef / np.maximum(se, 1e-300)
        out[j] = {"coef": dict(zip(TERMS, c_full, strict=True)),
                  "z": dict(zip(TERMS, z_full, strict=True)), "rows": int(len(y)),
                  "share": (rss0 - rss) / max(rss0, 1e-300)}
    return out


def motion_band_scores(ds: Dataset) -> dict[str, float]:
    """Per torque-commanded effect joint with enough moving rows: the band term's coefficient
    over its jackknife standard error (``motion_band_fits``)."""
    return {j: float(r["z"]["band"]) for j, r in motion_band_fits(ds).items()}
