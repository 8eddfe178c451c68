"""Backlash: gear or horn play between a servo and the link it drives, and which side of it the
log's encoder reads.

Its own module (moved out of ``catalogue``, which lists it in ``EFFECTS`` / ``CAUSES``): the one
structural effect (a play hinge added to the model), with the play operator of its massless-motor
limit and the two reading sides.

Which side the log reads (``read``): 1 the link (an encoder on the output shaft behind the play,
a camera or a link encoder), 0 the motor side (the servo's own encoder on its rotor or before a
gearbox stage, read through a horn, belt or tendon beyond it). Many low-cost servos read the motor
side (the third truth simulator's finger: ``tests/gap_truth_sim3.py``); there the play is seen
only through the link's load on the motor: the reading jumps when the link slams a stop, sags
when its weight changes sides. A model read on the wrong side replays such a play worse than
none at every width (gap-sim3-11, session 16: 1.22 floors nominal, 4.06 at width 0.01).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError
from lowcostdex.sim.effects.base import Effect, Fields, Param, Targets, Values, play_joint_name
from lowcostdex.sim.effects.base import clip as _clip


class Backlash(Effect):
    name = "backlash"
    kind = "command"
    structural = True
    doc = ("gear/horn play of total `width` between the servo and the link it drives: a play "
           "hinge in a model prepared with hidden dofs (the servo moves the motor side: rotor "
           "inertia, friction, its own sensor; the link swings inside the play until it meets "
           "a stop); else the massless-motor limit, a play operator on the goal")
    params = (Param("width", 0.0, 0.0, 0.1, "rad", (0.0, 0.017), start=0.01,
                    limit=(0.0, 0.3)),
              Param("sensor", 0.0, 0.0, 1.25, "1", (0.0, 0.0), limit=(0.0, 1.5),
                    doc="where the servo's position loop reads across the play hinge: 0 the "
                        "motor side (a rotor-side encoder; a horn's play beyond the servo), 1 "
                        "the output shaft (the loop closed across the play, Dynamixel's "
                        "output encoder behind its gearbox; its D term, the actuator's kv or, "
                        "with kp only, the joint's nominal damping, reads there too)"),
              Param("read", 1.0, 0.0, 1.0, "1", (1.0, 1.0), ends=True,
                    doc="where the log's encoder reads across the play: 1 the link (null: an "
                        "output-shaft or link encoder), 0 the motor side (the servo's own "
                        "encoder before the play: a rotor-side encoder, a horn, belt or tendon "
                        "beyond the servo); the reading is motor + read x play"))
    LOCK = 1e4  # [kg m^2] armature of a closed (null) play hinge (``apply``)

    @classmethod
    def sample(cls, rng: np.random.Generator, shape: tuple[int, ...]) -> dict[str, np.ndarray]:
        """As every effect, but the reading side (its DR range is its null, the link) takes no
        draw: a seed gives the same randomized robots as before the parameter existed."""
        vals = {p.name: rng.uniform(p.dr[0], p.dr[1], size=shape) for p in cls.params[:2]}
        return {**vals, "read": np.ones(shape)}

    @staticmethod
    def play_joint(joint: str) -> str:
        """Name of the play hinge ``prepare`` adds for ``joint``."""
        return play_joint_name(joint)

    @classmethod
    def prepare(cls, spec: mujoco.MjSpec, joints: tuple[str, ...]) -> None:
        """Add a play hinge to each joint's body: same anchor and axis, limited to the play.

        Only with ``prepare_spec(..., hidden_dofs=True)``: it changes the qpos layout. The two
        hinges of one body compose (same axis: their angles add), so the body (the link and
        everything it carries) sits at ``q + q_play`` while the servo's joint ``q`` keeps the
        actuator, the rotor's armature, damping and friction: the motor side. The play hinge
        has no inertia, damping or friction of its own; its limit (range +-width/2, set by
        ``apply``; locked at the null) is a stiff contact (time constant 2 physics steps,
        critical damping, MuJoCo's stiffest recommended). Joint ``q`` is the motor angle; the
        link angle, what ``Plant.measured_qpos`` reads, is ``q + q_play``.
        """
        tc = 2.0 * spec.option.timestep
        for jn in joints:
            if spec.joint(cls.play_joint(jn)) is not None:
                continue
            j = spec.joint(jn)
            if j is None or j.type not in (mujoco.mjtJoint.mjJNT_HINGE,
                                           mujoco.mjtJoint.mjJNT_SLIDE):
                raise ConfigError(f"backlash: {jn!r} must be a hinge or slide joint of the model")
            # the compiled range is set per simulation by apply(); compile needs lo < hi. A
            # slide's play is a slide (a rack's, in m): two slides of one body along one axis add
            j.parent.add_joint(name=cls.play_joint(jn), type=j.type,
                               pos=j.pos, axis=j.axis, limited=mujoco.mjtLimited.mjLIMITED_TRUE,
                               range=[-1e-9, 1e-9], solref_limit=[tc, 1.0])

    @classmethod
    def written_fields(cls, t: Targets) -> tuple[str, ...]:
        return ("jnt_range", "dof_armature") if np.any(t.has_play) else ()

    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        """Play hinges: range +-width/2; a null play is locked (armature ``LOCK``: it cannot
        move, the model is the nominal one to ~1e-9 rad, not the contact's ~1e-4 rad of
        compliance). The lock was 1e12 kg m^2 until gap-rotor12 (session 17): beside a model's
        1e-4 kg m^2 that is past double precision, and a 0.08 rad play on a finger's distal
        joint beside locked plays on its other two replayed its middle joint 2.39 mrad RMS off
        a plain-MuJoCo truth at 0.25 ms (0.49 with no locked hinges, as at 1e3-1e8; 0.51 at
        1e10). Since gap-sim9 (session 22) 1e4, and the plant recomputes the model's constants
        (``moves_constants``): compiled with the play hinge free, each servo joint's
        dof_invweight0 left out the link it carries, so the friction and limit rows were
        regularised as for the rotor alone; on the ninth truth simulator's 4-joint arm
        (frictionloss on every joint) null plays on all four replayed them 0.90 / 1.77 / 2.02 /
        2.53 mrad RMS off the nominal model at 0.25 ms (1e7-1e9 alike; 0.2 mrad at 1e1-1e5
        without the constants; with them 0.001 at 1e3, 0.001-0.003 at 1e4, 0.03-1.2 at 1e8;
        1e3 left a one-joint arm's null play 2e-9 rad off, tests/test_effects.py)."""
        has = t.has_play
        if not np.any(has):
            return
        rng_ = f.array("jnt_range")
        half = 0.5 * np.asarray(v["width"], dtype=float)
        half = np.broadcast_to(half, rng_.shape[:-2] + (len(t.joints),))[..., has]
        play, dofs = t.play[has], t.play_dofs[has]
        rng_[..., play, 0] = -half
        rng_[..., play, 1] = half
        arm = f.array("dof_armature")
        arm[..., dofs] = np.where(half > 0, f.nominal("dof_armature")[dofs], cls.LOCK)

    @classmethod
    def moves_constants(cls, t: Targets, v: Values) -> np.ndarray | None:
        """A null play on a joint with a hinge is locked by its armature (``apply``)."""
        if not np.any(t.has_play):
            return None
        return np.any((np.asarray(v["width"], float) <= 0) & t.has_play, axis=-1)

    @classmethod
    def reading(cls, v: Values, joint: np.ndarray, play: np.ndarray) -> np.ndarray:
        """What the log's encoder reads [rad]: the motor side ``joint`` plus ``read`` x the
        play hinge's angle ``play`` (values ``v`` and both angles (..., n) over the same
        joints, rates alike)."""
        return joint + v["read"] * play

    @classmethod
    def rest(cls, v: Values, joint: np.ndarray, play: np.ndarray, load: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
        """Where a play rests for a state set from a reading (``Plant.rest_play``): the link
        leans on the stop its static load ``load`` [N m] (on the play hinge) pushes it to, in
        the middle when unloaded (below 1e-9 N m); the reading (``reading`` of ``joint`` and
        ``play``) is kept. Returns the new (motor side, play) angles [rad], (..., n) each."""
        new = np.where(np.abs(load) > 1e-9, np.sign(load), 0.0) * 0.5 * v["width"]
        return cls.reading(v, joint, play) - v["read"] * new, new

    @classmethod
    def command(cls, t: Targets, v: Values, goal: np.ndarray, state: dict[str, np.ndarray],
                rng: np.random.Generator) -> np.ndarray:
        """Joints without a play hinge: the massless-motor limit, a play operator between goal
        and setpoint (the setpoint moves only once the goal is half the play away). Joints
        with one: a loop read across the play (``sensor`` s > 0) is the servo's own law on
        motor + s x play; a position servo is linear in its goal, so it is the goal less s x
        the play angle (``state["qpos"]``, the plant's positions) and, for its ``kv`` (inside
        the force range, as the actuator's), less s x kv / kp x the play rate.

        The nominal joint damping of a servo with no D of its own (``state["damping"]``, N m
        s/rad: a position-like actuator with kp only; 0 where it has a kv, whose joint damping
        is then a rotor loss, or is a dcmotor) reads where the loop reads as well: it is that
        servo's D term, and a servo with its encoder on the output shaft damps the output's
        rate, not the rotor's. The motor joint keeps its
        damping on its own rate (implicit); ``state["torque"]`` gets the rest, -s x damping x
        the play rate on the motor dof, outside the force range as a joint's damping is (the
        plant adds it as an applied force). Damping a hidden effect adds (``viscous_damping``)
        stays on the motor side: a gearbox loss. Measured on the second truth simulator's
        ``backlash_output_pendulum`` (width 2.5 deg, loop and D on the output): replayed at
        the true width with the D on the rotor, 14.5 / 9.7 mrad RMS per log at 0.25 ms; inside
        the force range 12.1 / 6.8; read on the output outside it, 0.75 / 0.74 (the noise). On the third truth simulator's ``srv_backlash_output`` (firmware D in kv,
        joint damping 0.01 on the rotor) reading that damping on the output too replayed worse
        at the true width (5.73 vs 4.52 mrad mean per episode at 0.5 ms): hence kp only."""
        has = t.has_play
        any_play, all_play, pq, pd = t.play_index
        inside = goal
        if any_play and "qpos" in state:
            s = np.asarray(v["sensor"], float)
            # (every joint with a hinge: the gathered angles as they are, the same values)
            p = state["qpos"][..., pq] if all_play else np.where(has, state["qpos"][..., pq], 0.0)
            if "qvel" in state:  # the damping terms read across the play too
                rate = state["qvel"][..., pd]
                rate = _finite(rate if all_play else np.where(has, rate, 0.0))
                p = p + state["kv_kp"] * rate  # the actuator's kv: kv / kp x rate in the goal
                if "damping" in state:
                    state["torque"] = -s * state["damping"] * rate
            inside = goal - s * _finite(p)
            if all_play:  # no joint on the play operator: ``out`` is ``inside``, the play the goal
                state["play"] = np.array(goal, dtype=float, copy=True)
                return inside
        half = 0.5 * np.asarray(v["width"])
        prev = state.get("play")
        prev = state["setpoint"] if prev is None else np.where(np.isnan(prev), state["setpoint"],
                                                                prev)
        op = _clip(prev, goal - half, goal + half)
        # read on the motor side, the massless motor is where the servo puts it: the goal
        if not any_play:  # every joint on the play operator (``np.where`` would pick these)
            state["play"] = op
            return goal + v["read"] * (op - goal)
        out = np.where(has, inside, goal + v["read"] * (op - goal))
        state["play"] = np.where(has, goal, op)
        return out


def _finite(x: np.ndarray) -> np.ndarray:
    """``np.nan_to_num(x)``, skipped when every value is finite (as every step of a replay but a
    start from a log with missing velocities: the per-step call cost ~7 % of a small replay)."""
    # (a finite sum: every value is finite; an overflowing one falls through to the full check)
    return x if math.isfinite(x.sum()) or np.isfinite(x).all() else np.nan_to_num(x)
