"""The catalogue of concrete effects (latency, frictions, gains, limits, backlash, offsets, noise,
thermal and voltage), ``EFFECTS``, ``CAUSES`` and ``effect(name)``.

See the package docstring (``lowcostdex.sim.effects``) for the kinds and magnitudes.

Why one module (over 600 lines since the direction-dependent Coulomb level): the catalogue is one
ordered table of effects (``EFFECTS``: the order the Plant applies them in, ``CAUSES``: the order
a tie is named in); split by kind, that order would live in no one place.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_choice
from lowcostdex.sim import servo
from lowcostdex.sim.effects.backlash import Backlash
from lowcostdex.sim.effects.base import (
    Effect,
    Fields,
    Param,
    Targets,
    Values,
)
from lowcostdex.sim.effects.base import (
    dcmotor_targets as _dcmotor,
)
from lowcostdex.sim.effects.deadband import Deadband
from lowcostdex.sim.effects.exogenous import ThermalDerating, VoltageSag
from lowcostdex.sim.effects.exogenous import scale_resistance as _scale_resistance
from lowcostdex.sim.effects.profile import GoalProfile
from lowcostdex.sim.effects.sensor_scale import SensorScale
from lowcostdex.sim.effects.supply import SupplyResistance

# ------------------------------------------------------------------------------------------------
# model-field effects


class Latency(Effect):
    name = "latency"
    kind = "model"
    doc = "command latency: the servo sees the goal `delay` seconds late (native actuator delay)"
    params = (Param("delay", 0.0, 0.0, 0.1, "s", (0.0, 0.03), start=0.01,
                    doc="goal-to-servo delay", limit=(0.0, 0.25)),)
    fields = ("actuator_delay",)

    @classmethod
    def prepare(cls, spec: mujoco.MjSpec, joints: tuple[str, ...]) -> None:
        dt = spec.option.timestep
        need = int(math.ceil(cls.params[0].hard[1] / dt)) + 2
        for act in spec.actuators:  # (a tendon's servo may drive the joints: room for it)
            if act.target in joints or act.trntype == mujoco.mjtTrn.mjTRN_TENDON:
                act.nsample = max(act.nsample, need)
                act.interp = 1  # linear: fractional delays between timesteps

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        arr = f.array("actuator_delay")
        t, (delay,) = t.servos(arr.shape[:-1], v["delay"])  # a shared servo once
        arr[..., t.actuators] = delay


# The stiffest friction constraint the step allows (time constant clamped up to 2 physics steps by
# MuJoCo's refsafe, critical damping, impedance 0.999): a joint held below its level sticks.
STIFF_FRICTION_REF, STIFF_FRICTION_IMP = (1e-6, 1.0), (0.999, 0.9999, 0.001, 0.5, 2.0)


class CoulombFriction(Effect):
    name = "coulomb_friction"
    kind = "model"
    doc = ("extra dry (Coulomb) friction in the joint, with stiction (MuJoCo frictionloss); creep "
           "1 keeps the model's own (MuJoCo-soft) friction constraint, under which a held joint "
           "creeps (~F R / b; near stall, hundreds of mrad), 0 makes it stiff (it sticks); "
           "asymmetry a makes the level direction-dependent: F (1 + a s), s the sign of the "
           "joint's speed, at rest of the torque pushing it (F+ = F (1 + a), F- = F (1 - a))")
    params = (Param("frictionloss", 0.0, 0.0, 0.5, "N m", (0.0, 0.1), start=0.02, limit=(0.0, 5.0)),
              Param("creep", 1.0, 0.0, 1.0, "1", (1.0, 1.0), start=1.0, ends=True,
                    doc="share of the model's own friction solref/solimp (the rest stiff)"),
              Param("asymmetry", 0.0, -1.0, 1.0, "1", (0.0, 0.0), start=0.0, ends=True,
                    doc="(F+ - F-) / (F+ + F-): positive motion meets more friction when > 0"))
    fields = ("dof_frictionloss", "dof_solref", "dof_solimp")
    REST_SPEED = 1e-3  # rad/s: slower than this the joint is at rest (direction from the push)

    @classmethod
    def sample(cls, rng: np.random.Generator, shape: tuple[int, ...]) -> dict[str, np.ndarray]:
        """As every effect, but the asymmetry (its DR range is its null) takes no draw: a seed
        gives the same randomized robots as before the parameter existed."""
        vals = {p.name: rng.uniform(p.dr[0], p.dr[1], size=shape) for p in cls.params[:2]}
        return {**vals, "asymmetry": np.zeros(shape)}

    @classmethod
    def substep(cls, v: Values) -> bool:
        """A direction-dependent level (asymmetry != 0) is set every physics step."""
        return bool(np.any(np.asarray(v["asymmetry"]) != 0)
                    and np.any(np.asarray(v["frictionloss"]) != 0))

    @classmethod
    def friction(cls, t: Targets, v: Values, qvel: np.ndarray, force: np.ndarray,
                 external: np.ndarray | None = None) -> np.ndarray:
        """The direction-dependent part F a s [N m] on top of the level F that ``apply`` writes:
        s = sign(qvel) when |qvel| > REST_SPEED, else the sign of the torque pushing the joint
        (actuator force + external force, -qfrc_bias); the level stays >= 0 for |a| <= 1."""
        vel = qvel[..., t.dofs]
        push = force[..., t.actuators] + (0.0 if external is None else external[..., t.dofs])
        s = np.where(np.abs(vel) > cls.REST_SPEED, np.sign(vel), np.sign(push))
        return v["frictionloss"] * np.clip(v["asymmetry"], -1.0, 1.0) * s

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        d, arr = t.dofs, f.array("dof_frictionloss")
        arr[..., d] = arr[..., d] + v["frictionloss"]
        if np.all(np.asarray(v["creep"]) >= 1.0):
            return
        ref, imp = f.array("dof_solref"), f.array("dof_solimp")
        w = np.broadcast_to(np.clip(v["creep"], 0.0, 1.0), ref.shape[:-2] + (len(d),))[..., None]
        ref[..., d, :] = w * ref[..., d, :] + (1 - w) * np.asarray(STIFF_FRICTION_REF)
        imp[..., d, :] = w * imp[..., d, :] + (1 - w) * np.asarray(STIFF_FRICTION_IMP)


class ViscousDamping(Effect):
    name = "viscous_damping"
    kind = "model"
    doc = "extra viscous damping in the joint (negative: less than nominal)"
    params = (Param("damping", 0.0, -0.5, 2.0, "N m s/rad", (0.0, 0.3), start=0.05,
                    limit=(-0.5, 10.0)),)
    fields = ("dof_damping",)

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        arr = f.array("dof_damping")
        arr[..., t.dofs] = np.maximum(arr[..., t.dofs] + v["damping"], 0.0)


class GainError(Effect):
    name = "gain_error"
    kind = "model"
    doc = ("the position loop's proportional gain off by a factor, its D and I terms kept: a "
           "position actuator's kp (kv kept), a general servo's gain with its -kp bias, a "
           "dcmotor's controller kp (the firmware P: ki and kd kept); on a velocity actuator "
           "its loop gain kv (its proportional gain: the velocity loop has no other), on a "
           "motor its torque per command")
    # One physical thing on every kind: the torque per rad of position error (the P term)
    # scales; what damps (kv, a firmware D, back-EMF) and what integrates (ki) does not.
    # Why ki is kept on a dcmotor: the I gain is its own register (Dynamixel Position I Gain
    # 82, MuJoCo's controller ki), set and wrong independently of P, and BAM's
    # error_gain_ratio, the fit this matches on real servos, scales the P path (duty =
    # error_gain kp (goal - q), 08-bam-reference-errors.md); a drive whose whole output per
    # volt is off (P, I, D and the stall torque together) is ``motor_strength``, a supply
    # off ``voltage_sag``. sim4's gain05_dcmotor (kp x0.5, kd kept): P, I and D scaled together
    # fitted 0.708 + a mass error 1.41; P alone 0.5 (bench/RESULTS.md gap-dc11).
    params = (Param("scale", 1.0, 0.2, 4.0, "1", (0.7, 1.4), limit=(0.05, 20.0)),)
    fields = ("actuator_gainprm", "actuator_biasprm")

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        g = f.array("actuator_gainprm")
        bias, nom_bias = f.array("actuator_biasprm"), f.nominal("actuator_biasprm")
        s = np.asarray(v["scale"], dtype=float)
        s = np.broadcast_to(s, g.shape[:-2] + (len(t.actuators),))
        t, (s,) = t.servos(g.shape[:-2], s)  # a tendon's servo shared by joints: once
        dc = _dcmotor(f, t)
        gaintype = f.nominal("actuator_gaintype")[t.actuators]
        other = ~dc & (gaintype != int(mujoco.mjtGain.mjGAIN_FIXED))
        if np.any(other) and np.any(s[..., other] != 1.0):
            kinds = sorted({mujoco.mjtGain(int(k)).name.removeprefix("mjGAIN_").lower()
                            for k in gaintype[other]})
            raise ConfigError(
                f"gain_error scales a proportional gain; the actuators of joints "
                f"{[t.joints[i] for i in np.flatnonzero(other)]} have gain type "
                f"{', '.join(kinds)}, with no proportional gain it could scale (it applies to "
                "position, general with a fixed gain, velocity, motor and dcmotor actuators)")
        if np.any(dc):
            a = t.actuators[dc]
            g[..., a, servo.GAIN_KP] = g[..., a, servo.GAIN_KP] * s[..., dc]
        if np.any(~dc & ~other):
            # fixed gain: force = gain * ctrl + b0 + b1 * length + b2 * velocity. A position
            # servo (b1 = -kp) is stiffer or softer: gain and b1 scale together so it still
            # holds its goal, b2 (-kv) kept; a velocity servo (b1 = 0, b2 = -kv) scales kv; a
            # motor its gain.
            fx = ~dc & ~other
            a, sf = t.actuators[fx], s[..., fx]
            g[..., a, 0] = g[..., a, 0] * sf
            pos = nom_bias[a, 1] != 0
            vel = ~pos & (nom_bias[a, 2] != 0)
            bias[..., a[pos], 1] = bias[..., a[pos], 1] * sf[..., pos]
            bias[..., a[vel], 2] = bias[..., a[vel], 2] * sf[..., vel]


class TorqueLimit(Effect):
    name = "torque_limit"
    kind = "model"
    doc = ("the servo delivers at most `torque` at the joint (current limit, weak supply, worn "
           "motor); an actuator with a gear clips its own force at torque / |gear|")
    params = (Param("torque", math.inf, 0.02, 10.0, "N m", (1.5, 4.0), start=1.0,
                    limit=(0.002, 10.0)),)
    fields = ("actuator_forcerange", "actuator_forcelimited")

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        # the force range becomes +-torque, never wider than the nominal range; the null (inf)
        # keeps the nominal range and limit flag (a force-limited actuator stays as it was)
        t, (torque,) = t.servos(f.array("actuator_forcerange").shape[:-2], v["torque"])
        a = t.actuators
        # joint torque -> actuator force (a gear's force range is in actuator units); on a
        # tendon's servo the torque is already the actuator's own (N m at its horn)
        gear = np.where(f.nominal("actuator_trntype")[a] == int(mujoco.mjtTrn.mjTRN_JOINT),
                        np.abs(f.nominal("actuator_gear")[a, 0]), 1.0)
        tau = np.asarray(torque, dtype=float) / gear
        nom_rng = f.nominal("actuator_forcerange")[a]
        nom_lim = f.nominal("actuator_forcelimited")[a] > 0
        lo_nom = np.where(nom_lim, nom_rng[:, 0], -np.inf)
        hi_nom = np.where(nom_lim, nom_rng[:, 1], np.inf)
        finite = np.isfinite(tau)
        bound = np.where(finite, tau, 0.0)
        rng_ = f.array("actuator_forcerange")
        rng_[..., a, 0] = np.where(finite, np.maximum(-bound, lo_nom), nom_rng[:, 0])
        rng_[..., a, 1] = np.where(finite, np.minimum(bound, hi_nom), nom_rng[:, 1])
        f.array("actuator_forcelimited")[..., a] = np.where(finite | nom_lim, 1, 0)


class VelocityLimit(Effect):
    name = "velocity_limit"
    kind = "model"
    live = True
    doc = ("the servo runs out of torque with speed: a dcmotor servo's no-load speed off by a "
           "factor (`scale`: back-EMF constant, stall torque kept); any force-limited actuator "
           "(position, motor, general) on a motor's torque-speed line with no-load speed "
           "`speed` (the force limit falls linearly from the stall torque at rest to 0 at "
           "`speed`, brakes beyond: a saturated motor near its no-load speed, a Feetech speed "
           "register or Dynamixel Velocity Limit held by the voltage)")
    # A real servo's speed plateau is its motor's torque-speed line: at full PWM the drive
    # voltage V gives torque (V - K w) K / R = stall (1 - w / w0) (04-sysid.md section 3.2:
    # "larger steps run voltage-limited at about the no-load speed"; W210 8.1 rad/s, W350 4.8
    # rad/s at 12 V). A dcmotor carries K and R (``scale``); a position actuator has only a
    # force range, so the line is its force range shrinking with speed (``speed``).
    params = (Param("scale", 1.0, 0.2, 3.0, "1", (0.8, 1.2), limit=(0.05, 10.0),
                    on="dcmotor", doc="no-load speed / the dcmotor's nominal one"),
              Param("speed", math.inf, 0.5, 10.0, "rad/s", (4.8, 8.1), start=3.0,
                    limit=(0.1, 50.0), on="other",
                    doc="no-load speed of a force-limited actuator's torque-speed line"))
    fields = ("actuator_gainprm",)

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        # the no-load speed of a dcmotor servo (K, R); other actuators have no back-EMF model
        dc = _dcmotor(f, t)
        g = f.array("actuator_gainprm")
        a = t.actuators[dc]
        s = np.broadcast_to(np.asarray(v["scale"], float), g.shape[:-2] + (len(dc),))[..., dc]
        k, r = g[..., a, servo.GAIN_K], g[..., a, servo.GAIN_R]
        backemf = k * k / r
        g[..., a, servo.GAIN_KD] = g[..., a, servo.GAIN_KD] - backemf + backemf / s
        g[..., a, servo.GAIN_K] = k / s
        g[..., a, servo.GAIN_R] = r / s

    @classmethod
    def live_apply(cls, f: Fields, t: Targets, v: Values, qvel: np.ndarray,
                   forcerange: np.ndarray) -> None:
        """Each physics step: the force range ``forcerange`` (..., nu, 2) of the targets'
        force-limited actuators (as the model effects and torque enable left it) shrunk to the
        torque-speed line at the joints' speeds ``qvel`` (..., nv) [rad/s], in place: upper
        limit hi (1 - w / speed), lower lo (1 + w / speed), each kept inside [lo, hi] (w the
        speed in the actuator's direction); a null (inf) speed leaves the range as it was."""
        a = t.actuators
        lim = f.array("actuator_forcelimited")[..., a] > 0
        speed = np.asarray(v["speed"], float)
        sign = np.sign(f.nominal("actuator_gear")[a, 0])
        with np.errstate(invalid="ignore"):
            w = np.where(np.isfinite(speed), sign * qvel[..., t.dofs] / speed, 0.0)
        lo, hi = forcerange[..., a, 0], forcerange[..., a, 1]
        new_hi = np.clip(hi * (1.0 - w), lo, hi)
        new_lo = np.clip(lo * (1.0 + w), lo, hi)
        forcerange[..., a, 0] = np.where(lim, new_lo, lo)
        forcerange[..., a, 1] = np.where(lim, new_hi, hi)


class GoalSlew(Effect):
    name = "goal_slew"
    kind = "model"
    doc = ("the firmware moves its internal goal toward a written goal at a speed off by a "
           "factor: a dcmotor servo compiled with a goal slew (``MotorSpec.goal_speed``, a "
           "Feetech STS at its Running Speed; a Dynamixel Profile Velocity), its slewmax x "
           "`scale`; no effect on a servo without one (the slewed goal is a compiled state)")
    # BAM's STS3215 model fits its target-velocity clamp between 0.1 and 10 x 3400 steps/s
    # (Rhoban/bam bam/feetech/actuator.py max_velocity); its STS3032 fits put it at 3.2-5.7 x
    # (08-bam-reference-errors.md section 4). The hard limit lets a fit at 10 x widen to 50 x
    # (261 rad/s: no slew a 6 s log can tell).
    params = (Param("scale", 1.0, 0.1, 10.0, "1", (0.8, 1.25), limit=(0.02, 50.0),
                    on="dcmotor", doc="slew speed / the servo's nominal one"),)
    fields = ("actuator_dynprm",)

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        dyn, nom = f.array("actuator_dynprm"), f.nominal("actuator_dynprm")
        a = t.actuators
        s = np.broadcast_to(np.asarray(v["scale"], float), dyn.shape[:-2] + (len(a),))
        slewed = _dcmotor(f, t) & (nom[a, servo.DYN_SLEWMAX] > 0)
        dyn[..., a, servo.DYN_SLEWMAX] = np.where(slewed, nom[a, servo.DYN_SLEWMAX] * s,
                                                  dyn[..., a, servo.DYN_SLEWMAX])


class MotorStrength(Effect):
    name = "motor_strength"
    kind = "model"
    doc = ("torque per volt (K/R) off by a factor: stall torque and the firmware's torque per "
           "position error scale with it, the no-load speed is kept (winding resistance R / scale)")
    params = (Param("scale", 1.0, 0.2, 5.0, "1", (0.8, 1.25), limit=(0.05, 20.0)),)
    fields = ("actuator_gainprm",)

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        g = f.array("actuator_gainprm")
        dc = _dcmotor(f, t)
        s = np.broadcast_to(np.asarray(v["scale"], float), g.shape[:-2] + (len(dc),))[..., dc]
        _scale_resistance(g, t.actuators[dc], 1.0 / s)


class InertiaError(Effect):
    name = "inertia_error"
    kind = "model"
    doc = "reflected rotor inertia (armature) off by a factor"
    params = (Param("scale", 1.0, 0.1, 10.0, "1", (0.7, 1.5), limit=(0.02, 50.0)),)
    fields = ("dof_armature",)

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        arr = f.array("dof_armature")
        arr[..., t.dofs] = arr[..., t.dofs] * v["scale"]


class MassError(Effect):
    name = "mass_error"
    kind = "model"
    doc = "mass (and inertia) of the body the joint moves off by a factor"
    params = (Param("scale", 1.0, 0.3, 3.0, "1", (0.8, 1.25), limit=(0.1, 10.0)),)
    fields = ("body_mass", "body_inertia")

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        m, inertia = f.array("body_mass"), f.array("body_inertia")
        s = np.asarray(v["scale"], dtype=float)
        m[..., t.bodies] = m[..., t.bodies] * s
        inertia[..., t.bodies, :] = inertia[..., t.bodies, :] * s[..., None]

    @classmethod
    def moves_constants(cls, t: Targets, v: Values) -> np.ndarray:
        return np.any(np.asarray(v["scale"], float) != 1.0, axis=-1)


# ------------------------------------------------------------------------------------------------
# substep friction effects


class StribeckFriction(Effect):
    name = "stribeck_friction"
    kind = "friction"
    doc = ("dry friction with true stiction and a breakaway above the sliding level at low "
           "speed: level = coulomb + static * exp(-(v / velocity)^2) (on top of the model's own "
           "frictionloss); its joints' friction constraint is made stiff (a joint held below "
           "the level sticks, it does not creep)")
    # MuJoCo's frictionloss is a soft constraint: at the default solref/solimp a joint held
    # below its level creeps at ~F R / b (~0.04 rad/s on a servo bench), as fast as a real
    # Stribeck velocity, so the breakaway never holds (redteam3 srv_stribeck: the true
    # parameters replayed at 15.5 mrad against Coulomb alone 16.0; with a stiff friction
    # constraint 3.2; STIFF_FRICTION_REF / _IMP).
    params = (
        Param("static", 0.0, 0.0, 0.5, "N m", (0.0, 0.08), start=0.03, limit=(0.0, 5.0),
              doc="breakaway friction at rest above the sliding level"),
        Param("velocity", 0.2, 0.01, 2.0, "rad/s", (0.05, 0.5), start=0.2,
              limit=(0.002, 20.0), doc="Stribeck velocity of the breakaway share"),
        Param("coulomb", 0.0, 0.0, 0.5, "N m", (0.0, 0.05), start=0.02, limit=(0.0, 5.0),
              doc="sliding (Coulomb) level"),
    )
    fields = ("dof_solref", "dof_solimp")
    STIFF_REF, STIFF_IMP = STIFF_FRICTION_REF, STIFF_FRICTION_IMP

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        """The friction constraint of the joints where the effect is not null made stiff."""
        on = (np.asarray(v["static"], float) > 0) | (np.asarray(v["coulomb"], float) > 0)
        ref, imp = f.array("dof_solref"), f.array("dof_solimp")
        d = t.dofs
        on = np.broadcast_to(on, ref.shape[:-2] + (len(d),))
        ref[..., d, :] = np.where(on[..., None], np.asarray(cls.STIFF_REF), ref[..., d, :])
        imp[..., d, :] = np.where(on[..., None], np.asarray(cls.STIFF_IMP), imp[..., d, :])

    @classmethod
    def friction(cls, t: Targets, v: Values, qvel: np.ndarray, force: np.ndarray,
                 external: np.ndarray | None = None) -> np.ndarray:
        w = qvel[..., t.dofs] / v["velocity"]
        return v["coulomb"] + v["static"] * np.exp(-w * w)


class LoadDependentFriction(Effect):
    name = "load_dependent_friction"
    kind = "friction"
    doc = "gearbox friction growing with the motor's torque: extra = mu * |tau_motor|"
    params = (Param("mu", 0.0, 0.0, 0.5, "1", (0.0, 0.15), start=0.05, limit=(0.0, 0.95)),)

    @classmethod
    def friction(cls, t: Targets, v: Values, qvel: np.ndarray, force: np.ndarray,
                 external: np.ndarray | None = None) -> np.ndarray:
        return v["mu"] * np.abs(force[..., t.actuators])


class GearboxFriction(Effect):
    name = "gearbox_friction"
    kind = "friction"
    doc = ("gear-train friction growing with the torque the gears carry: extra = |tau_motor - "
           "backdrive tau_ext| (mu + static exp(-|v / velocity|^alpha)), tau_ext the external "
           "(gravity) torque on the joint; unlike load_dependent_friction it acts when the load "
           "back-drives the servo with the torque off (BAM's load-dependent models M3, with "
           "Stribeck M4; backdrive != 1: a load-side torque loads the gears differently from a "
           "motor-side one, BAM's directional M5)")
    # Rhoban/bam docs (theory) and bam/model.py: friction budget shares of the "gearbox torque"
    # |tau_ext - tau_motor|, sliding and (Stribeck) at rest; directional (M5/M6):
    # |lfe tau_ext - lfm tau_motor|, here mu = lfm and backdrive = lfe / lfm; the Stribeck
    # curvature alpha (bam: exp(-|dtheta / dtheta_stribeck|^alpha)).
    params = (
        Param("mu", 0.0, 0.0, 0.5, "1", (0.0, 0.15), start=0.05,
              doc="sliding friction per N m carried by the gears", limit=(0.0, 0.95)),
        Param("static", 0.0, 0.0, 1.0, "1", (0.0, 0.15),
              doc="extra friction per N m carried at rest (breakaway)", limit=(0.0, 2.0)),
        Param("velocity", 0.5, 0.02, 5.0, "rad/s", (0.1, 1.0), start=0.5,
              doc="Stribeck velocity of the breakaway share", limit=(0.005, 20.0)),
        Param("backdrive", 1.0, 0.05, 3.0, "1", (0.2, 1.0), limit=(0.01, 10.0),
              doc="friction per N m of external torque relative to per N m of motor torque"),
        Param("alpha", 2.0, 1.0, 10.0, "1", (2.0, 2.0), limit=(0.5, 20.0),
              doc="Stribeck exponent: the breakaway share falls as exp(-|v / velocity|^alpha)"),
    )

    @classmethod
    def friction(cls, t: Targets, v: Values, qvel: np.ndarray, force: np.ndarray,
                 external: np.ndarray | None = None) -> np.ndarray:
        gear = force[..., t.actuators]
        if external is not None:
            gear = gear - v["backdrive"] * external[..., t.dofs]
        w = np.abs(qvel[..., t.dofs] / v["velocity"])
        return np.abs(gear) * (v["mu"] + v["static"] * np.exp(-(w ** v["alpha"])))


class BackdrivenFriction(Effect):
    name = "backdriven_friction"
    kind = "friction"
    doc = ("the gear train's friction while the load back-drives the servo with its torque off "
           "(no current): extra = coulomb + viscous |v| on a joint whose servo is off, and the "
           "gear friction's own load-dependent level (gearbox_friction) kept there by the share "
           "``gear`` (1: as with the torque on, BAM's gearbox; 0: the back-driven gears have "
           "only this Coulomb + viscous law); nothing while the torque is on")
    # Its own law, not gearbox_friction's back-driven share: that share also sets how the gear
    # friction grows with the motor torque (|tau_motor - backdrive tau_ext|), so a share fitted
    # to the torque-off swings moves the torque-on fit (Rhoban lift_and_drop fold 64.0 -> 176.1
    # mrad, bench/RESULTS.md gap-real13). The Rhoban XL330's swings alone: Coulomb 0.0053 N m,
    # viscous 0.0095 N m s/rad, a load share 0.034 (gap.torque_off.swing_fit).
    params = (
        Param("coulomb", 0.0, 0.0, 0.5, "N m", (0.0, 0.02), start=0.005, limit=(0.0, 5.0),
              doc="sliding friction of the back-driven gears, torque off"),
        Param("viscous", 0.0, 0.0, 0.5, "N m s/rad", (0.0, 0.02), start=0.005,
              limit=(0.0, 5.0), doc="viscous friction of the back-driven gears, torque off"),
        Param("gear", 1.0, 0.0, 1.0, "1", (0.0, 1.0), start=0.5, ends=True,
              doc="share of gearbox_friction's level kept while the torque is off"),
        Param("joint", 1.0, 0.0, 1.0, "1", (1.0, 1.0), start=1.0, ends=True,
              doc="share of the joint's own extra friction (coulomb_friction's level and "
                  "viscous_damping's damping beyond the nominal model's) kept while the torque "
                  "is off"),
    )
    # ``joint`` 0: the law is the back-driven joint's whole friction. A joint damping fitted on
    # torque-on logs can be the drive's (a firmware D term, a back-EMF the model misses), which
    # goes with the current: STS3032's lift_and_drop fold fits 0.010 N m s/rad with the torque on,
    # its real swings 0.0017 (bench/RESULTS.md gap-real17). Its DR range is its null (no draw).
    torque_off = True  # the plant applies ``friction`` only where the servo's torque is off
    SCALED = "gearbox_friction"  # whose level ``gear`` scales while the torque is off
    fields = ("dof_damping",)  # ``joint`` < 1 rewrites it where the torque is off (the plant)

    @classmethod
    def sample(cls, rng: np.random.Generator, shape: tuple[int, ...]) -> dict[str, np.ndarray]:
        """As every effect, but ``joint`` (its DR range is its null) takes no draw: a seed gives
        the same randomized robots as before the parameter existed."""
        vals = {p.name: rng.uniform(p.dr[0], p.dr[1], size=shape) for p in cls.params[:3]}
        return {**vals, "joint": np.ones(shape)}

    @classmethod
    def substep(cls, v: Values) -> bool:
        """At its null (no Coulomb, no viscous, the gear friction kept whole) it changes
        nothing: not stepped."""
        return not cls.is_null(v)

    @classmethod
    def friction(cls, t: Targets, v: Values, qvel: np.ndarray, force: np.ndarray,
                 external: np.ndarray | None = None) -> np.ndarray:
        return v["coulomb"] + v["viscous"] * np.abs(qvel[..., t.dofs])


# ------------------------------------------------------------------------------------------------
# command and observation effects


class ActionNoise(Effect):
    name = "action_noise"
    kind = "command"
    doc = "Gaussian noise on each goal position"
    params = (Param("std", 0.0, 0.0, 0.1, "rad", (0.0, 0.02)),)

    @classmethod
    def command(cls, t: Targets, v: Values, goal: np.ndarray, state: dict[str, np.ndarray],
                rng: np.random.Generator) -> np.ndarray:
        return goal + rng.normal(size=goal.shape) * v["std"]


class MountingOffset(Effect):
    name = "mounting_offset"
    kind = "calibration"
    doc = ("the servo's encoder zero is off the model's joint zero: the servo reads and holds "
           "q + offset (a horn mounted off by that angle, a tilted bench; BAM's q_offset)")
    params = (Param("offset", 0.0, -0.3, 0.3, "rad", (-0.03, 0.03), limit=(-0.8, 0.8)),)

    @classmethod
    def command(cls, t: Targets, v: Values, goal: np.ndarray, state: dict[str, np.ndarray],
                rng: np.random.Generator) -> np.ndarray:
        return goal - v["offset"]

    @classmethod
    def observe(cls, t: Targets, v: Values, q: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
        return q + v["offset"]


class PositionOffset(Effect):
    name = "position_offset"
    kind = "observation"
    doc = "calibration offset: the encoder reading is off by a constant"
    params = (Param("offset", 0.0, -0.2, 0.2, "rad", (-0.03, 0.03), limit=(-0.8, 0.8)),)

    @classmethod
    def observe(cls, t: Targets, v: Values, q: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
        return q + v["offset"]


class ObservationNoise(Effect):
    name = "observation_noise"
    kind = "observation"
    doc = "Gaussian noise on each joint reading"
    params = (Param("std", 0.0, 0.0, 0.05, "rad", (0.0, 0.01)),)

    @classmethod
    def observe(cls, t: Targets, v: Values, q: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
        return q + rng.normal(size=q.shape) * v["std"]


class Quantization(Effect):
    name = "quantization"
    kind = "observation"
    doc = "encoder quantization to `ticks` per revolution (0: continuous)"
    params = (Param("ticks", 0.0, 0.0, 65536.0, "1/rev", (4096.0, 4096.0)),)

    @classmethod
    def observe(cls, t: Targets, v: Values, q: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
        ticks = np.asarray(v["ticks"], dtype=float)
        step = np.where(ticks > 0, 2 * math.pi / np.where(ticks > 0, ticks, 1.0), 0.0)
        return np.where(step > 0, np.round(q / np.where(step > 0, step, 1.0)) * step, q)


# ------------------------------------------------------------------------------------------------
# exogenous effects (need measured channels)


EFFECTS: dict[str, type[Effect]] = {
    e.name: e
    for e in (
        Latency, Backlash, CoulombFriction, StribeckFriction, LoadDependentFriction,
        GearboxFriction, BackdrivenFriction,
        ViscousDamping, GainError, TorqueLimit, VelocityLimit, GoalSlew, MotorStrength,
        SensorScale, PositionOffset, MountingOffset, InertiaError, MassError, ThermalDerating,
        VoltageSag, SupplyResistance, Deadband, ObservationNoise,
        ActionNoise, GoalProfile, Quantization,
    )
}

# The canonical causes the gap analysis may name (report uses exactly these names).
CAUSES: tuple[str, ...] = (
    "latency", "backlash", "coulomb_friction", "stribeck_friction", "load_dependent_friction",
    "viscous_damping", "gain_error", "torque_limit", "velocity_limit", "position_offset",
    "inertia_error", "mass_error", "thermal_derating", "voltage_sag",
    "gearbox_friction", "mounting_offset", "motor_strength",
    "deadband", "sensor_scale", "goal_profile",
)
# Causes an analysis fits when asked (``GapConfig.candidates``, ``--candidates``) or where the
# data show their signature (``gap.offer``'s gates): the deadband where rests stand off by a band.
# (``goal_profile`` is a default cause with a gate there too: offered where goal steps ramp.)
OPT_IN: tuple[str, ...] = ("deadband",)


def effect(name: str) -> type[Effect]:
    """Look up an effect class by canonical name; the error lists the catalogue."""
    check_choice("effect", name, EFFECTS)
    return EFFECTS[name]
