"""Which candidates an analysis fits (``available_candidates``): the causes whose channels are
logged, and an opt-in one (``effects.OPT_IN``) or a gated one (``goal_profile``: a firmware's
motion profile, its gate in ``gap.ramps``) only where the data show its signature (a cheap test
on the logs and the nominal model, before any replay; ``GATES``).

``deadband`` (``band_shown``): a servo that puts out nothing while its error is inside a band
leaves its joint at rest off the pose the nominal model holds. At each rest of a joint (it stays
within ``STILL`` noise floors, and its position goal is unchanged, for ``SETTLE`` s) the nominal
model's generalized force on it at the measured pose, velocity 0, goals as logged (qfrc_actuator
+ qfrc_passive - qfrc_bias: kp (goal - q) - G for a position servo, command - G for a torque
motor; G the gravity load) should be 0. The statics written out, per effect (e = goal - q):

* a band of width w: kp sign(e) max(|e| - w, 0) = G, so the imbalance is +kp w sign(G) on a
  loaded rest, whichever side the joint came from (gravity carries it through the band to the
  load's edge), and +kp w times the approach's sign s where unloaded (it stops on entering);
* Coulomb friction f: it stops where the drive falls below f: +f s, the approach's side always
  (loaded or not);
* a reading offset d: kp d through the joint's stiffness k = -d(imbalance)/dq (constant); a gain,
  mass or strength error: proportional to G; a reading scale: to k q;
* a backlash read on the link with the loop on the motor: +kp (b / 2) sign(G), as a band (the
  confusable family, ``docs/gap_analysis.md``: offered alike, the fit chooses).

Per joint, the rests' imbalances (weighted by their noise: the reading noise through k, or a host
loop's command spread over the rest) are fitted by k, G, k q, the band's term (sign(G) where the
load exceeds the noise, s elsewhere) and Coulomb's (s); the band is shown when its coefficient
is over ``BAND_Z`` standard errors (``band_scores``). Measured (session 22, gap-dead17): a band of
5-20 mrad on a kp 3 arm 17-81 (tests/test_gap_offer.py's truth, written in plain MuJoCo); clean,
offset, gain, Coulomb and the project generator's friction family at most 3.2, its backlash 5.8;
sim6 (torque rig: its loaded rests all lean one way, so a band there is a reading offset to the
statics), sim3, sim7, sim8, the independent bench and finger and the README run's logs nothing
(most have under ``MIN_RESTS`` rests per joint): the default analysis as before.

The moves (``gap.band_motion``, torque-commanded joints only): where the rests cannot tell a
band from an offset, a force lost on the command's side while the joint moves (session 24,
gap-sig19): sim6 deadband_torque 56-134 standard errors, width 0.0093-0.0100 N m for 0.01;
every other torque rig of sim4/sim6 and tests/test_gap_offer.py's torque arm (clean, Coulomb,
offset, gain, read delay, supply sag, encoder error, centre-of-mass, viscous, mass, torque limit)
at most 5.0 (sim4's Coulomb at 60 % of the command range); offered above ``MOTION_Z``.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.gap import band_motion, ramps
from lowcostdex.gap.band_motion import blocked_dofs as _blocked
from lowcostdex.gap.band_motion import is_motor as _is_motor
from lowcostdex.gap.band_motion import set_pose
from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.diagnostics import noise_floor
from lowcostdex.gap.logs import rate_goal_actuators
from lowcostdex.sim.effects import CAUSES, OPT_IN, effect
from lowcostdex.sim.effects.base import driving_actuator

SETTLE = 0.3  # [s] a rest: joints still and position goals held this long
STILL = 6.0  # joints "still": within this many noise floors (RMS) over SETTLE
MIN_ROWS = 5  # rows a rest needs (a host loop's command averaged over them)
MIN_RESTS = 8  # rests per joint for the five-term fit to judge
BAND_Z = 8.0  # the band's gate: its term over this many standard errors on some joint
MOTION_Z = 20.0  # the moves' band term (torque-commanded joints) over this many SE


def available_candidates(ds: Dataset, requested: Sequence[str] | None) -> list[str]:
    """Candidates whose required channels are logged (by default the causes, one with a gate in
    ``GATES``, opt-in or not, only where its gate shows it: ``offered``).

    Servos that integrate a velocity goal (``intvelocity``) have no position offsets: their
    setpoint is anchored to the measured reading (``Replayer``), so a reading offset moves the
    replay with the data and cannot be seen (on clean data a 1 mrad read error of each log's
    first sample was named one), and a mounting offset on a velocity goal means nothing."""
    chans = ds.channels()
    tendon = tendon_driven(ds)
    names = list(requested) if requested is not None else [
        c for c in CAUSES if (tendon is None or c in ON_TENDON)
        and (offered(ds, c) if c in GATES else c not in OPT_IN)]
    if tendon is not None and (out := [n for n in names if n not in ON_TENDON]):
        raise ConfigError(f"{', '.join(out)}: not analysed on a model whose joints are driven "
                          f"through a tendon ({', '.join(tendon)}); the effects analysed there: "
                          f"{', '.join(ON_TENDON)} ({TENDON_WHY})")
    if set(ds.actuators) <= rate_goal_actuators(ds.compiled(ds.trajectories[0].model)):
        names = [n for n in names if n not in ("position_offset", "mounting_offset")]
    return [n for n in names if all(c in chans for c in effect(n).requires)]


# The causes analysed where an effect joint is driven through a tendon's servo: the servo's
# own (its actuator's delay, kp and force range: ``spaces.SERVO_SIDE``) and the joints' (their
# friction, damping, links' mass, readings). Not yet, and why (TENDON_WHY):
ON_TENDON = ("latency", "coulomb_friction", "stribeck_friction", "viscous_damping", "gain_error",
             "torque_limit", "position_offset", "mass_error", "sensor_scale")
TENDON_WHY = ("a play at the horn needs a joint between the servo and the tendon; the gear "
              "friction, a speed limit, a mounting offset, a deadband and a goal profile act on "
              "the actuator's coordinate, which no log reads; the rotor's inertia is the "
              "tendon's armature, not a joint's")


def tendon_driven(ds: Dataset) -> list[str] | None:
    """The effect joints driven through a tendon's servo, None when there is none."""
    m = ds.compiled(ds.trajectories[0].model)
    out = [j for j in ds.effect_joints if m.actuator_trntype[driving_actuator(m, j)]
           != mujoco.mjtTrn.mjTRN_JOINT]
    return out or None


def offered(ds: Dataset, name: str) -> bool:
    """Whether the gated cause ``name`` is offered by default on these data (its gate)."""
    gate = GATES.get(name)
    return bool(gate is not None and gate(ds))


def rests(ds: Dataset) -> dict[str, list[tuple[int, int, int]]]:
    """Per effect joint, (trajectory, first row, last row + 1) of each of its rests: the joint
    within ``STILL`` noise floors of its reading ``SETTLE`` s before, its actuator's goal
    unchanged (a position goal; a torque motor's command may vary: a host loop's noise) and
    its torque on throughout (where a ``torque_enable`` channel is logged)."""
    floor = noise_floor(ds.trajectories)
    out: dict[str, list[tuple[int, int, int]]] = {j: [] for j in ds.effect_joints}
    for ti, tr in enumerate(ds.trajectories):
        m = ds.compiled(tr.model)
        t = tr.time
        back = np.searchsorted(t, t - SETTLE)  # the row SETTLE s before each row
        base = (back < np.arange(len(t))) & (t - t[0] >= SETTLE)
        for j in out:
            c = tr.joints.index(j)
            ok = base & (_window_range(tr.qpos[:, c], back) <= STILL * max(floor[c], 1e-9))
            a = driving_actuator(m, j)
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a)
            if name in tr.actuators:
                i = tr.actuators.index(name)
                if not _is_motor(m, a):
                    ok &= _window_range(tr.goal[:, i], back) == 0
                on = tr.channels.get("torque_enable")
                if on is not None:  # (a joint at rest with its torque off is held by nothing)
                    ok &= (on[:, i] > 0.5) & (_window_range(on[:, i], back) == 0)
            edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(int), [0]])))
            out[j] += [(ti, int(a0), int(b0)) for a0, b0 in zip(edges[::2], edges[1::2],
                                                                strict=True)]
    return out


def _window_range(x: np.ndarray, back: np.ndarray) -> np.ndarray:
    """max - min of x over rows [back[i], i] for each row i (prefix extremes over sorted
    windows: O(T log T) via a sparse table)."""
    n = len(x)
    lo, hi = [x.copy()], [x.copy()]
    k = 1
    while 2 * k <= n:
        lo.append(np.minimum(lo[-1][:-k], lo[-1][k:]))
        hi.append(np.maximum(hi[-1][:-k], hi[-1][k:]))
        k *= 2
    idx = np.arange(n)
    length = idx - back + 1
    lev = np.floor(np.log2(np.maximum(length, 1))).astype(int)
    span = 1 << lev
    out = np.empty(n)
    for level in np.unique(lev):
        r = lev == level
        a, b = back[r], idx[r] - span[r] + 1
        out[r] = (np.maximum(hi[level][a], hi[level][b]) - np.minimum(lo[level][a], lo[level][b]))
    return out


def rest_imbalance(ds: Dataset) -> dict[str, np.ndarray]:
    """Per effect joint, one row per rest of at least ``MIN_ROWS`` rows (contacts and joint
    limits left out): [imbalance (N m), its noise (N m), gravity load G (N m), position (rad),
    nominal frictionloss (N m), stiffness k (N m/rad), approach's sign s (+1, -1; 0 without
    a move in the ``SETTLE`` s before)] (module docstring), at the rest's mean reading and goal.
    The noise: the reading noise through k (a quantised reading does not average out), or the
    imbalance's spread over the rest's rows (a host loop's command) over their root, whichever
    is larger."""
    floor = noise_floor(ds.trajectories)
    out = {}
    for j, spans in rests(ds).items():
        rows = []
        for ti, a, b in spans:
            tr = ds.trajectories[ti]
            m = ds.compiled(tr.model)
            d = mujoco.MjData(m)
            adr = [int(m.jnt_qposadr[m.joint(n).id]) for n in tr.joints]
            act = [m.actuator(n).id for n in tr.actuators]
            v, c = int(m.jnt_dofadr[m.joint(j).id]), tr.joints.index(j)
            if b - a < MIN_ROWS:
                continue
            taus = np.array([_imbalance(m, d, adr, act, tr.qpos[k], tr.goal[k])[v]
                             for k in range(a, b)])
            q, goal = np.mean(tr.qpos[a:b], axis=0), np.mean(tr.goal[a:b], axis=0)
            tau = _imbalance(m, d, adr, act, q, goal)[v]
            if _blocked(m, d)[v]:
                continue
            grav = float(d.qfrc_bias[v])
            h = max(float(floor[c]), 1e-6)  # the joint's stiffness d(imbalance)/dq
            step = q.copy()
            step[c] += h
            stiff = (tau - _imbalance(m, d, adr, act, step, goal)[v]) / h
            noise = max(abs(stiff) * float(floor[c]),
                        1.25 * float(np.std(taus)) / np.sqrt(len(taus)), 1e-12)
            t, x = tr.time, tr.qpos[:, c]  # the approach: the move before the rest began
            r0 = int(np.searchsorted(t, t[a] - SETTLE))
            r1 = int(np.searchsorted(t, t[r0] - SETTLE))
            move = x[r0] - x[r1]
            came = float(np.sign(move)) if abs(move) > STILL * floor[c] else 0.0
            rows.append((tau, noise, grav, q[c], float(m.dof_frictionloss[v]), stiff, came))
        out[j] = np.array(rows, float).reshape(-1, 7)
    return out


def _imbalance(m: mujoco.MjModel, d: mujoco.MjData, adr: list[int], act: list[int],
               q: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """(nv,) the generalized force the nominal model leaves at pose q, at rest, goals held."""
    set_pose(m, d, adr, act, q, goal)
    return d.qfrc_actuator + d.qfrc_passive - d.qfrc_bias


def band_scores(ds: Dataset) -> dict[str, tuple[float, float]]:
    """Per effect joint: (band, friction) signatures of its rests in standard errors (module
    docstring); NaN with fewer than ``MIN_RESTS`` rests or a fit that cannot tell them apart."""
    out = {}
    for j, r in rest_imbalance(ds).items():
        out[j] = (float("nan"), float("nan"))
        if len(r) < MIN_RESTS:
            continue
        tau, noise, grav, q, fl, stiff, came = r.T
        band = np.where(np.abs(grav) > noise, np.sign(grav), came)  # where a band holds it
        x = np.column_stack([stiff, grav, stiff * q, band, came]) / noise[:, None]
        y = tau / noise
        coef, *_ = np.linalg.lstsq(x, y, rcond=None)
        dof = len(y) - x.shape[1]
        if np.linalg.matrix_rank(x) < x.shape[1] or dof < 2:
            continue
        chi2 = float(np.sum((y - x @ coef) ** 2)) / dof
        se = np.sqrt(np.diag(np.linalg.inv(x.T @ x)) * max(chi2, 1.0))
        out[j] = (float(coef[3] / se[3]), float(coef[4] / se[4]))
    return out


def band_shown(ds: Dataset) -> bool:
    """``deadband``'s gate: on some joint the rests stand off by a band on the load's side (on
    the approach's side where unloaded) by over ``BAND_Z`` standard errors, beside what an
    offset, a gain, a scale and a Coulomb friction (the approach's side always) explain; or, on
    a torque-commanded joint, its moves lose a force on the command's side by over ``MOTION_Z``
    standard errors (``band_motion.motion_band_scores``: where the rests all lean one way)."""
    if any(z > BAND_Z for z, _ in band_scores(ds).values()):
        return True
    return any(z > MOTION_Z for z in band_motion.motion_band_scores(ds).values())


# a cause's gate: offered by default only where it is true (``goal_profile``, a default cause,
# too: its ramps after goal steps, ``ramps.shows_profile``)
GATES = {"deadband": band_shown, "goal_profile": ramps.shows_profile}
