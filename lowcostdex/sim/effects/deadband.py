"""``deadband``: the servo puts out nothing while its position error is inside a band (a Feetech
STS/SCS's CW/CCW dead zone, registers 26/27 in steps; a hobby servo's specified deadband; the
PWM deadband of an H-bridge drive seen through the P gain), on every actuator kind that takes a
position goal, and on a torque-driven drive's command.

Its own module (the catalogue, ``catalogue``, lists it in ``EFFECTS``).

The law (one physical thing on every kind): the position loop's proportional term acts on the
error with the band taken out, e' = sign(e) max(|e| - width, 0), e = goal - q (the error beyond
the band, not the plain error: the output is continuous at the band's edge, as a PWM deadband
subtracted from the drive is; sim6's ``deadband_torque`` writes |c| - value). A firmware that
gates the plain error (nothing inside, the whole error beyond: the hidden robots'
``FirmwareImperfection``) holds the same band; it differs by at most kp x width of force at the
band's edge, and we offer one form until data tells them apart. What damps (kv, a firmware D,
back-EMF) is kept. Statics written out: a joint held under a constant load L rests at an error
width + L / kp from its goal (a servo without the band: L / kp); unloaded it stays wherever it is
left inside the band.

Per actuator kind (the targets' actuators; others are left as they were):

* ``position`` and ``general`` with a position bias (fixed gain, affine bias with biasprm[1] =
  -kp): each physics step the bias constant biasprm[0] takes back kp x clip(e, -width, width)
  (``live_apply``), so MuJoCo still integrates kv implicitly, clips at the force range and
  delays the goal (a latency's band is around the goal as sent: a small error at a few ms);
* ``motor`` (fixed gain, no bias: the goal is the drive's torque command, a host PD's): the
  command c becomes sign(c) max(|c| - width, 0) before it reaches the drive (``command``; width
  in the command's units, N m of torque for a gear-1 motor);
* ``dcmotor`` servos (``lowcostdex.sim.servo``): each physics step the drive torque with the P
  path on e' (D path, back-EMF, Vmax clip and the integrator's ki x state kept; the goal slewed
  where the firmware slews it) pinned as the force range (``live_apply``; the ``ServoClock``'s
  way of holding a force).

Confusable family (documented in docs/gap_analysis.md): ``coulomb_friction`` (a moving joint's
error keeps the sign of its speed, so the band takes kp x width off the drive as a dry friction
would; under a static load they part: friction shortens the offset, the band lengthens it),
``backlash`` (a play read on the link side with the loop on the motor side is a band of half its
width) and ``gain_error`` (a softer servo near its goal).
"""

from __future__ import annotations

import mujoco
import numpy as np

from lowcostdex.sim import servo
from lowcostdex.sim.effects.base import Effect, Fields, Param, Targets, Values, dcmotor_targets


def dead_zone(x: np.ndarray, width: np.ndarray) -> np.ndarray:
    """sign(x) max(|x| - width, 0): ``x`` with the band +-``width`` taken out (same units)."""
    return np.sign(x) * np.maximum(np.abs(x) - width, 0.0)



def torque_motor(gaintype, biastype, dyntype) -> np.ndarray:
    """Which actuators (by their MuJoCo gain, bias and dynamics types, arrays or scalars) are
    torque-driven motors: fixed gain, no bias, no activation (their goal is a command)."""
    return ((np.asarray(gaintype) == int(mujoco.mjtGain.mjGAIN_FIXED))
            & (np.asarray(biastype) == int(mujoco.mjtBias.mjBIAS_NONE))
            & (np.asarray(dyntype) == int(mujoco.mjtDyn.mjDYN_NONE)))

class Deadband(Effect):
    name = "deadband"
    kind = "command"  # a motor's torque command; position-goal servos: ``live_apply``
    live = True
    doc = ("position-loop deadband: the servo's P term acts on the error with a band of "
           "+-width taken out (sign(e) max(|e| - width, 0): nothing while |goal - q| < width, D "
           "kept; position, general with a position bias, dcmotor servos); a torque-driven "
           "motor's command c becomes sign(c) max(|c| - width, 0) (width in N m there)")
    params = (Param("width", 0.0, 0.0, 0.1, "rad", (0.0, 0.005), start=0.005,
                    limit=(0.0, 0.3), doc="half-width of the band around the goal [rad] (a "
                    "motor actuator's: of its command, N m); a Feetech dead zone of n steps is "
                    "n x 2 pi / 4096"),)

    @classmethod
    def command(cls, t: Targets, v: Values, goal: np.ndarray, state: dict[str, np.ndarray],
                rng: np.random.Generator) -> np.ndarray:
        """Motors' commands with the band taken out (``motors``, from the model's fields the
        plant passes as ``state["fields"]``); position goals pass."""
        w = np.asarray(v["width"], float)
        f = state.get("fields")
        if f is None or not np.any(w > 0):
            return goal
        motor = cls._statics(f, t)[-1]
        return np.where(motor, dead_zone(goal, w), goal) if np.any(motor) else goal

    @staticmethod
    def motors(f: Fields, t: Targets) -> np.ndarray:
        """(n,) which targets' actuators are torque-driven motors (fixed gain, no bias, no
        activation): their command is the band's input."""
        a = t.actuators
        return torque_motor(f.nominal("actuator_gaintype")[a], f.nominal("actuator_biastype")[a],
                            f.nominal("actuator_dyntype")[a])

    @staticmethod
    def position_biased(f: Fields, t: Targets) -> np.ndarray:
        """(n,) which targets' actuators hold a position bias (fixed gain, affine bias with
        biasprm[1] = -kp != 0, no activation; dcmotor servos excluded): ``live_apply`` moves
        their biasprm[0]."""
        a = t.actuators
        return (~dcmotor_targets(f, t)
                & (f.nominal("actuator_gaintype")[a] == int(mujoco.mjtGain.mjGAIN_FIXED))
                & (f.nominal("actuator_biastype")[a] == int(mujoco.mjtBias.mjBIAS_AFFINE))
                & (f.nominal("actuator_dyntype")[a] == int(mujoco.mjtDyn.mjDYN_NONE))
                & (f.nominal("actuator_biasprm")[a, 1] != 0))

    @classmethod
    def live_on(cls, f: Fields, t: Targets, v: Values) -> bool:
        """A band on a position-biased or dcmotor servo is live; on a torque-driven motor it acts
        on the command alone (``command``), so a replay of the motor steps its physics in
        stretches as without the band (session 22: the per-step hook made every sim6 torque-rig
        replay with a deadband column ~2x dearer for nothing)."""
        n = len(t.actuators)
        w = np.asarray(v["width"], float)
        on = np.any(np.broadcast_to(w, np.broadcast_shapes(w.shape, (n,))).reshape(-1, n) > 0,
                    axis=0)
        f.__dict__.setdefault("_deadband", {}).pop(id(t), None)  # (the nominal may have moved)
        return bool(np.any(on & (cls.position_biased(f, t) | dcmotor_targets(f, t))))

    @classmethod
    def _statics(cls, f: Fields, t: Targets) -> tuple:
        """What ``live_apply`` reads from the nominal model, once per plant and targets (``live_on``,
        called whenever the plant re-applies its effects, forgets it): gear, ctrl range, whether
        it is limited, the dcmotor and position-biased masks, the position-biased actuators,
        their nominal biasprm[0], the motor mask (``motors``)."""
        cache = f.__dict__.setdefault("_deadband", {})
        hit = cache.get(id(t))
        if hit is None or hit[0] is not t:
            a = t.actuators
            pos = cls.position_biased(f, t)
            hit = cache[id(t)] = (t, (
                f.nominal("actuator_gear")[a, 0], f.nominal("actuator_ctrlrange")[a],
                f.nominal("actuator_ctrllimited")[a] > 0, dcmotor_targets(f, t), pos, a[pos],
                f.nominal("actuator_biasprm")[a[pos], 0], cls.motors(f, t)))
        return hit[1]

    @classmethod
    def live_apply(cls, f: Fields, t: Targets, v: Values, qvel: np.ndarray,
                   forcerange: np.ndarray) -> None:
        """Each physics step: position-biased servos' biasprm[0] = nominal - kp x clip(e,
        -width, width); dcmotor servos' force range pinned at their drive torque with the P path
        on the error beyond the band (module docstring). A null (0) width leaves both as they
        were."""
        a = t.actuators
        w = np.broadcast_to(np.asarray(v["width"], float), qvel.shape[:-1] + (len(a),))
        if not np.any(w > 0):
            return
        gear, cr, limited, dc, pos, ap, nb0, _ = cls._statics(f, t)
        q = gear * np.asarray(f.qpos)[..., t.qpos]
        ctrl = np.asarray(f.ctrl)[..., a]
        ctrl = np.where(limited, np.clip(ctrl, cr[:, 0], cr[:, 1]), ctrl)
        if len(ap):
            bias = f.array("actuator_biasprm")
            b1 = bias[..., ap, 1]  # -kp (as the effects and the drive scale left it)
            kp = -b1
            e = np.where(kp != 0, (f.array("actuator_gainprm")[..., ap, 0] * ctrl[..., pos]
                                   + b1 * q[..., pos]) / np.where(kp != 0, kp, 1.0), 0.0)
            bias[..., ap, 0] = nb0 - kp * np.clip(e, -w[..., pos], w[..., pos])
        if np.any(dc):
            cls._pin_dcmotor(f, t, w, q, ctrl, qvel, forcerange, dc)

    @staticmethod
    def _pin_dcmotor(f: Fields, t: Targets, w: np.ndarray, q: np.ndarray, ctrl: np.ndarray,
                     qvel: np.ndarray, forcerange: np.ndarray, dc: np.ndarray) -> None:
        """dcmotor servos ``dc``: the force range (..., nu, 2) pinned at the drive torque with
        the P path on the error beyond the band (the supply's voltage law as
        ``supply_resistance`` writes it: v = R / K (kp e' + ki s - kd w) + K w, clipped at
        Vmax; torque K (v - K w) / R), inside the range in force; width 0 left as it was."""
        a, dofs = t.actuators[dc], t.dofs[dc]
        g = f.array("actuator_gainprm")[..., a, :]
        res, k = g[..., servo.GAIN_R], g[..., servo.GAIN_K]
        gear = f.nominal("actuator_gear")[a, 0]
        speed = gear * qvel[..., dofs]
        goal = ctrl[..., dc]
        dyn = f.nominal("actuator_dynprm")[a]
        adr = np.maximum(f.nominal("actuator_actadr")[a], 0)
        if np.any(dyn[:, servo.DYN_SLEWMAX] > 0):  # the firmware's slewed goal
            goal = np.where(dyn[:, servo.DYN_SLEWMAX] > 0, np.asarray(f.act)[..., adr], goal)
        drive = g[..., servo.GAIN_KP] * dead_zone(goal - q[..., dc], w[..., dc])
        layout = servo.dcmotor_act_layout(f.model)[a, servo.ACT_INTEGRATOR]
        if np.any(layout >= 0):
            state = np.asarray(f.act)[..., np.maximum(layout, 0)]
            drive = drive + np.where(layout >= 0, g[..., servo.GAIN_KI] * state, 0.0)
        vmax = g[..., servo.GAIN_VMAX]
        volts = np.clip(res / k * (drive - g[..., servo.GAIN_KD] * speed) + k * speed,
                        -vmax, vmax)
        tau = k * (volts - k * speed) / res
        lo, hi = forcerange[..., a, 0], forcerange[..., a, 1]
        lim = f.array("actuator_forcelimited")[..., a] > 0
        tau = np.where(lim, np.clip(tau, lo, hi), tau)
        on = w[..., dc] > 0
        forcerange[..., a, 0] = np.where(on, tau, lo)
        forcerange[..., a, 1] = np.where(on, tau, hi)
        f.array("actuator_forcelimited")[..., a] = np.where(on, 1, lim)
