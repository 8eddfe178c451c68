"""What a servo's torque-off swings say on their own: its reflected rotor inertia and friction.

With the torque off (``torque_enable`` < 0.5, BAM's lift_and_drop logs) a pendulum bench is a
plain pendulum back-driving the gearbox: no motor law, no firmware gain, no supply. Its swing's
period gives the rotor's inertia reflected through the gears (the armature) beside the link's
own, and its decay the friction of the back-driven gearbox. ``swing_fit`` fits every torque-off
swing of the given logs at once, the pendulum written out here (link inertia about the joint and
gravity torque read from each log's compiled nominal model, one hinge):

    (I_link + armature) qdd = tau_g(q) - coulomb tanh(qd / 0.01) - viscous qd
                              [- load |tau_g(q)| tanh(qd / 0.01)]

semi-implicit Euler at 1 ms from each swing's first state (50 ms after the release: the drive's
current decays), least squares on the measured positions, each swing weighted equally. With
``centre`` each swing also gets the angle it hangs at in the reading (the servo reads q + centre,
as ``mounting_offset`` has it): an arm re-mounted between recordings hangs at its own.

Measured 2026-11-28 on Rhoban XL330's four lift_and_drop logs (0.49 kg at 0.10 m): armature
0.0018-0.0020 kg m^2 per swing (BAM's six published XL330 fits: 0.00181-0.00192; the project's
catalogue XL330-M288: 0.0003), Coulomb ~0.01 N m, viscous ~0.0075 N m s/rad, and the load share
of the friction small (0.01-0.07 per N m of gravity torque): bench/RESULTS.md (gap-real12).
Measured 2026-11-29 on STS3032's 18 lift_and_drop swings (qua-robotics, 9 set-ups, fitted a set-up
at a time): they hang at 0.095-0.108 rad (0.05 m arm), 0.16-0.174 (0.07 m) and 0.111-0.119 (0.1 m),
for every mass and gain; per swing 80-168 mrad off without the centre, 9-23 with it; armature
0.00096-0.00106 kg m^2 (BAM's fitted M1 0.00103), Coulomb 0.003-0.005 N m, viscous ~0.002 N m s/rad
(bench/RESULTS.md gap-real20).

``release_delay`` measures how long the servo still holds its load after the torque-off command
(raw timestamps): each swing fitted alone from ``SETTLE`` on, then let go from rest at the last
torque-on reading ``delay`` after the command. Measured 2026-11-29 (bench/RESULTS.md gap-real21):
STS3032 5.3 ms median over 18 logs (3.0-10.8), Rhoban XL330 4.5 (1.2-12.6; ``MotorSpec.release``);
``release_plan`` picks the delay a replay uses (``bam_measure.resample(release=)``: off by
default, measured worse on STS3032's split).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np
from scipy.optimize import least_squares

from lowcostdex.gap.dataset import Dataset

SETTLE = 0.05  # [s] after the release before a swing is fitted
STEP = 0.001  # [s] integration step
VSMOOTH = 0.01  # [rad/s] the friction's sign smoothed over this speed


@dataclass(frozen=True)
class Swing:
    """One torque-off swing: measured positions [rad] every ``dt`` from its first state, the
    link's inertia about the joint without the armature [kg m^2], gravity torque
    tau_g(q) = gs sin q + gc cos q [N m], the nominal model's armature [kg m^2], and its log."""

    q: np.ndarray
    v0: float
    dt: float
    inertia: float
    gs: float
    gc: float
    armature: float
    log: int


@dataclass(frozen=True)
class SwingFit:
    """``swing_fit``'s result: armature [kg m^2], Coulomb [N m], viscous [N m s/rad], load
    share [1] (0 unless fitted), each swing's position MAE [rad], the catalogue armature (the
    nominal models'), the logs used, and (fitted with ``centre``, else empty) the angle each
    swing hangs at in the reading [rad]."""

    armature: float
    coulomb: float
    viscous: float
    load: float
    mae: tuple[float, ...]
    catalogue_armature: float
    logs: tuple[int, ...]
    centres: tuple[float, ...] = ()


def swings(ds: Dataset, logs: Sequence[int], settle: float = SETTLE, min_travel: float = 0.0
           ) -> list[Swing]:
    """The first torque-off run of each of ``logs`` (from ``settle`` s after the release, 40
    samples at least, travelling ``min_travel`` rad or more peak to peak) on a one-joint
    model."""
    out = []
    for i in logs:
        tr = ds.trajectories[i]
        on = tr.channels.get("torque_enable")
        if on is None or tr.qpos.shape[1] != 1:
            continue
        off = np.flatnonzero(np.asarray(on).ravel() < 0.5)
        if not len(off):
            continue
        end = off[0] + int(np.argmax(np.diff(np.r_[off, -2]) != 1)) + 1  # first run's end
        k0 = int(np.searchsorted(tr.time, tr.time[off[0]] + settle))
        if end - k0 < 40:
            continue
        link, gs, gc, arm = _pendulum(ds, tr)
        dt = float(np.median(np.diff(tr.time[k0:end])))
        q = tr.qpos[k0:end, 0]
        if np.ptp(q) < min_travel:
            continue
        v0 = float(np.polyfit(tr.time[k0:k0 + 5] - tr.time[k0], q[:5], 2)[1])
        out.append(Swing(q.copy(), v0, dt, link - arm, gs, gc, arm, int(i)))
    return out


def simulate(p: np.ndarray, sw: Swing, centre: np.ndarray | float = 0.0) -> np.ndarray:
    """Positions of swing ``sw`` as read [rad] under parameters p[k] = (armature, coulomb,
    viscous[, load]), one row per k (all k integrated together), the arm hanging at
    ``centre[k]`` in the reading (the servo reads q + centre)."""
    p = np.atleast_2d(p)
    a, c, b = p[:, 0], p[:, 1], p[:, 2]
    mu = p[:, 3] if p.shape[1] > 3 else np.zeros(len(p))
    centre = np.broadcast_to(np.asarray(centre, float), (len(p),))
    sub = max(1, int(round(sw.dt / STEP)))
    h = sw.dt / sub
    q = sw.q[0] - centre
    v = np.full(len(p), sw.v0)
    inv = 1.0 / (sw.inertia + a)
    out = np.empty((len(p), len(sw.q)))
    for k in range(len(sw.q)):
        out[:, k] = q + centre
        for _ in range(sub):
            tg = sw.gs * np.sin(q) + sw.gc * np.cos(q)
            s = np.tanh(v / VSMOOTH)
            v = v + h * (tg - (c + mu * np.abs(tg)) * s - b * v) * inv
            q = q + h * v
    return out


CENTRE = 0.5  # [rad] a swing's centre is fitted within +-this


def swing_fit(ds: Dataset, logs: Sequence[int], load: bool = False, min_travel: float = 0.0,
              centre: bool = False) -> SwingFit | None:
    """Armature, Coulomb and viscous friction (and with ``load`` a friction share per N m of
    gravity torque, with ``centre`` the angle each swing hangs at in the reading) fitted to the
    torque-off swings of ``logs`` (module doc) that travel ``min_travel`` rad or more; None when
    none of them has a torque-off run long enough."""
    sws = swings(ds, logs, min_travel=min_travel)
    if not sws:
        return None
    cat = float(np.median([s.armature for s in sws]))
    n = 4 if load else 3  # the shared parameters; then one centre per swing
    nc = len(sws) if centre else 0
    p0 = np.array([cat, 0.005, 0.005, 0.05][:n] + [float(np.median(s.q)) for s in sws][:nc])
    lo = np.r_[np.zeros(n), np.full(nc, -CENTRE)]
    hi = np.r_[np.array([0.05, 0.5, 0.5, 0.5])[:n], np.full(nc, CENTRE)]
    p0 = np.clip(p0, lo, hi)
    step = np.r_[np.array([1e-5, 1e-4, 1e-4, 1e-3])[:n], np.full(nc, 1e-4)]
    scale = np.r_[np.array([1e-3, 1e-2, 1e-2, 0.1])[:n], np.full(nc, 0.01)]
    wts = [1.0 / np.sqrt(len(s.q)) for s in sws]

    def batch(ps: np.ndarray) -> np.ndarray:
        return np.concatenate([(simulate(ps[:, :n], s, ps[:, n + k] if centre else 0.0) - s.q) * w
                               for k, (s, w) in enumerate(zip(sws, wts, strict=True))], 1)

    def jac(p: np.ndarray) -> np.ndarray:  # forward differences, all columns in one pass
        ps = np.vstack([p, p + np.diag(step)])
        r = batch(ps)
        return ((r[1:] - r[0]) / step[:, None]).T

    sol = least_squares(lambda p: batch(p[None])[0], p0, jac=jac, bounds=(lo, hi),
                        x_scale=scale, max_nfev=100)
    x = sol.x
    cs = tuple(float(v) for v in x[n:]) if centre else ()
    mae = tuple(float(np.mean(np.abs(simulate(x[:n], s, cs[k] if centre else 0.0)[0] - s.q)))
                for k, s in enumerate(sws))
    return SwingFit(float(x[0]), float(x[1]), float(x[2]), float(x[3]) if load else 0.0, mae,
                    cat, tuple(s.log for s in sws), cs)


# ``armature_seed``: a swing that travels less than this [rad] says nothing of the armature (Pham
# XL330's unloaded arm stays where the torque went off: 2 mrad), and a catalogue armature within
# this factor of the swings' is kept as the start (STS3032: 0.00106 vs 0.00103).
SEED_TRAVEL = 0.2
SEED_FACTOR = 1.5


def armature_seed(ds: Dataset, logs: Sequence[int]) -> SwingFit | None:
    """``swing_fit`` of the torque-off swings of ``logs`` (Coulomb + viscous) when they travel
    ``SEED_TRAVEL`` or more and put the armature ``SEED_FACTOR`` or more away from the nominal
    models' (identification then starts the armature's scale there: ``gap.identify``); else
    None."""
    f = swing_fit(ds, logs, min_travel=SEED_TRAVEL)
    if f is None or not f.catalogue_armature > 0:
        return None
    ratio = f.armature / f.catalogue_armature
    return f if max(ratio, 1.0 / max(ratio, 1e-12)) >= SEED_FACTOR else None


# Without a torque-off log (no swing) the armature is told only through the position loop's
# response, where it trades against the drive's constants: STS3032, 5 drawn kp 32 logs without
# one (seed 2) fit its scale to the 0.1 floor and the drive's fall with the duty to its 1.5 cap
# (held out 122.3 mrad, worse than the catalogue on 25 of 36 logs; bench/RESULTS.md gap-real22).
# Holding them at the catalogue's instead measured no better (inertia 125.7, inertia and voltage
# sag 126.7: gap-real23): the user is warned (``no_swing_warning``), nothing is held.


def no_swing_warning(swung: bool) -> str | None:
    """The plain warning for training logs without a torque-off swing (None with one)."""
    if swung:
        return None
    return ("WARNING: no training log has the torque off (a log that lets the arm fall and swing "
            "with the torque off, as BAM's lift_and_drop): the servo's back-driven friction and "
            "its reflected rotor inertia (armature) cannot be told from torque-on logs; the "
            "back-driven friction is the servo catalogue's (where it has one) and the armature's "
            "fit may stand in for other effects (at a search bound it is no measurement). Record "
            "one such log for a measured value")


# ``release_delay``: the first RELEASE_WINDOW [s] after a torque-off command, a delay sought in
# [-RELEASE_MIN, RELEASE_MAX] [s] at RELEASE_STEP.
RELEASE_WINDOW = 0.3
RELEASE_MIN, RELEASE_MAX, RELEASE_STEP = 0.01, 0.03, 1e-4
RELEASE_H = 2e-4  # [s] integration step of the fall


@dataclass(frozen=True)
class Release:
    """``release_delay``'s result: the delay [s] (median over the logs), each log's delay [s]
    and position RMS [rad] at it and with none, and the logs used."""

    delay: float
    delays: tuple[float, ...]
    rms: tuple[float, ...]
    rms_none: tuple[float, ...]
    logs: tuple[int, ...]


def fall(q0: float, inertia: float, gs: float, gc: float, coulomb: float, viscous: float,
         duration: float, h: float = RELEASE_H) -> tuple[np.ndarray, np.ndarray]:
    """A pendulum let go from rest at q0 [rad]: times [s] and positions [rad] every ``h`` up to
    ``duration``, semi-implicit Euler on
    inertia qdd = gs sin q + gc cos q - coulomb tanh(qd / VSMOOTH) - viscous qd."""
    n = int(np.ceil(duration / h)) + 1
    q, v = float(q0), 0.0
    out = np.empty(n)
    for k in range(n):
        out[k] = q
        tg = gs * np.sin(q) + gc * np.cos(q)
        v += h * (tg - coulomb * np.tanh(v / VSMOOTH) - viscous * v) / inertia
        q += h * v
    return np.arange(n) * h, out


def release_delay(raw: Dataset, grid: Dataset, logs: Sequence[int],
                  window: float = RELEASE_WINDOW) -> Release | None:
    """How long the servo holds the arm after each torque-off command of ``logs``, the
    swing's own physics written out: each log's swing from ``SETTLE`` s after the release is
    fitted alone on ``grid`` (the logs on a fixed step: ``swing_fit`` with ``centre``: its
    armature, Coulomb, viscous and hanging angle), then that pendulum is let go from rest at
    the last torque-on reading of ``raw`` (the same logs, raw timestamps) ``delay`` after the
    first sample logged with the torque off (``fall``; a held arm shifts the fall in time:
    read at t - delay). Each log's delay minimises the position RMS over its raw samples of
    the first ``window`` s. None when no log has a torque-off swing to fit (``swings``:
    40 samples, ``SEED_TRAVEL`` rad of travel).

    Measured 2026-11-29 (bench/RESULTS.md gap-real21): STS3032's 18 lift_and_drop logs 5.3 ms
    median (3.0-10.8; per log 6-18 mrad RMS over 0.3 s, with none 30-85), Rhoban XL330's four
    4.5 ms (1.2-12.6); a delay and a drive decaying exponentially fit alike, a constant brake
    or friction do not."""
    delays, rms, none, used = [], [], [], []
    span = np.arange(-RELEASE_MIN, RELEASE_MAX + 0.5 * RELEASE_STEP, RELEASE_STEP)
    for i in logs:
        f = swing_fit(grid, [i], min_travel=SEED_TRAVEL, centre=True)
        if f is None:
            continue
        tr = raw.trajectories[i]
        on = np.asarray(tr.channels["torque_enable"]).ravel() > 0.5
        starts = np.flatnonzero(~on[1:] & on[:-1]) + 1
        if not len(starts):
            continue
        k = int(starts[0])
        t_off = float(tr.time[k])
        run = k + (int(np.argmax(on[k:])) if np.any(on[k:]) else len(on) - k)
        w = np.arange(len(on)) < run
        w &= (tr.time >= t_off) & (tr.time <= t_off + window)
        t, q = tr.time[w] - t_off, tr.qpos[w, 0]
        c, q0 = f.centres[0], float(tr.qpos[k - 1, 0])
        link, gs, gc, nominal = _pendulum(raw, tr)
        ts, qs = fall(q0 - c, link - nominal + f.armature, gs, gc, f.coulomb, f.viscous,
                      window + RELEASE_MIN)
        err = np.array([np.sqrt(np.mean((np.interp(t - d, ts, qs + c, left=q0) - q) ** 2))
                        for d in span])
        j = int(np.argmin(err))
        delays.append(float(span[j]))
        rms.append(float(err[j]))
        none.append(float(err[int(np.argmin(np.abs(span)))]))
        used.append(int(i))
    if not used:
        return None
    return Release(float(np.median(delays)), tuple(delays), tuple(rms), tuple(none), tuple(used))


def _pendulum(ds: Dataset, tr) -> tuple[float, float, float, float]:
    """The one-joint model's inertia about the joint with its armature [kg m^2], gravity
    torque tau_g(q) = gs sin q + gc cos q [N m] (``swings``' reading of the nominal model) and
    its armature [kg m^2]."""
    m = ds.compiled(tr.model)
    d = mujoco.MjData(m)
    jid = m.joint(tr.joints[0]).id
    dof, adr = int(m.jnt_dofadr[jid]), int(m.jnt_qposadr[jid])
    tau = []
    for q in (0.5 * np.pi, 0.0):
        d.qpos[:] = 0.0
        d.qpos[adr] = q
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        tau.append(-float(d.qfrc_bias[dof]))
    e, r = np.zeros(m.nv), np.zeros(m.nv)
    e[dof] = 1.0
    mujoco.mj_mulM(m, d, r, e)
    return float(r[dof]), tau[0], tau[1], float(m.dof_armature[dof])


def catalogue_release(ds: Dataset, logs: Sequence[int]) -> float:
    """The servo catalogue's release delay (``MotorSpec.release``) [s] of the BAM logs' motor
    among ``logs``; 0 when they name none."""
    from lowcostdex.gap.bam_logs import BAM_MOTORS, bam_motor
    from lowcostdex.motors import motor_spec

    for i in logs:
        meta = ds.trajectories[i].meta
        name = meta.get("motor") if meta.get("source") == "bam" else None
        bam = bam_motor(name) if isinstance(name, str) else None
        if bam is not None:
            return float(motor_spec(BAM_MOTORS[bam]).release)
    return 0.0


def release_plan(raw: Dataset, grid: Dataset, train: Sequence[int]) -> tuple[float, str]:
    """The release delay [s] a replay of these logs uses and where it comes from: measured on
    the training logs' torque-off swings (``release_delay``, held at 0 or more: a negative
    median is BAM's grid rule already, which lets go before the first torque-off sample),
    else the servo catalogue's (``catalogue_release``)."""
    r = release_delay(raw, grid, train)
    if r is not None:
        return max(r.delay, 0.0), f"fitted on {len(r.logs)} training swing(s)"
    return catalogue_release(raw, train), "catalogue"
