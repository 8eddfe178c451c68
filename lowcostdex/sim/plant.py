"""The plant: a servo-driven MuJoCo model with effects applied, stepped at control rate.

One engine for every layer: the gymnasium envs (``sim`` backend), the emulated Dynamixel bus (the
physics behind the wire), domain randomization (per-episode effect values, per simulation in a
batch) and the gap analysis (replaying measured commands). ``Plant`` runs one ``MjData``;
``BatchPlant`` runs ``nsim`` simulations on ``mujoco.batch.Batch`` with per-simulation model
fields. Both share the same code through a leading "sim" axis: arrays are (nu,) for ``Plant`` and
(nsim, nu) for ``BatchPlant``.

Order inside one control step (``step``):
  1. command effects map the goal (action noise, mounting offset, backlash's play operator
     where the model has no play hinge) -> ``ctrl``;
  2. exogenous effects rescale the drives from measured channels (temperature, voltage):
     a dcmotor servo's gains, any other actuator's torque per command and force range;
  3. physics advances ``nstep`` substeps: natively (``mj_step(nstep)``) unless a friction effect
     needs its state-dependent level written every substep.
A servo update period (``servo_period``, default 0: the law acts continuously) samples the law
of each fixed-gain affine actuator (``position``, a ``general`` written so) every period and
holds its force until the next update, as a servo's firmware loop does (Dynamixel and Feetech
servos run theirs at ~1 kHz): ``servo.ServoClock``.
Observation effects (offset, noise, quantization) apply in ``measured_qpos``; calibration effects
(the servo's encoder frame shifted from the joint's) map the goal in step 1 and the reading there.
In a model prepared with hidden dofs (``prepare_spec(..., hidden_dofs=True)``) backlash is physics:
a play hinge between the servo's joint (motor side) and its link; ``measured_qpos`` reads joint +
read x play (the link; the motor side at ``read`` 0), ``reset`` rests the play (``rest_play``).

Why one module (over ~600 lines; issue 16 asks for the reason here): ``Plant`` and ``BatchPlant``
share every step through the leading sim axis, so the effect hooks are called from one place for
the envs, the emulator, domain randomization and the gap analysis; the effects themselves live in
``sim.effects``.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence

import mujoco
import numpy as np
from mujoco import batch as mjbatch

from lowcostdex import errors
from lowcostdex.errors import ConfigError, PhysicsError, check_count, check_finite_array, check_rng
from lowcostdex.sim import servo
from lowcostdex.sim.effects import EFFECTS, AppliedEffect, Effect, Targets
from lowcostdex.sim.effects import exogenous as exo
from lowcostdex.sim.effects.friction_level import JOINT_FRICTION, friction_level, torque_off_joint
from lowcostdex.sim.effects.prepare import compile_with_effects as compile_with_effects
from lowcostdex.sim.effects.prepare import prepare_spec as prepare_spec
from lowcostdex.sim.reset_state import actuated_positions, rest_play
from lowcostdex.sim.reset_state import fill_ctrl_history as _fill_ctrl_history

_ORDER = {name: i for i, name in enumerate(EFFECTS)}
_CONTROLLER_GAINS = [servo.GAIN_KP, servo.GAIN_KI, servo.GAIN_KD]
# the model constants mj_setConst derives (invweight0, acc0, subtree masses, ...)
_CONST_OUT = tuple(n for n in mujoco.MjModel._setconst_outputs if n in mjbatch.MODEL_FIELDS)


class _Bound:
    """An effect resolved against a model: class, targets, values (arrays)."""

    def __init__(self, cls: type[Effect], targets: Targets, values: dict[str, np.ndarray]):
        self.cls, self.targets, self.values = cls, targets, values


class _PlantBase:
    """Shared logic; subclasses provide the arrays and the stepping."""

    model: mujoco.MjModel
    rng: np.random.Generator

    def _init_effects(self) -> None:
        self._nominal: dict[str, np.ndarray] = {}
        self._bound: list[_Bound] = []
        self._state: dict[str, np.ndarray] = {}
        self._static_gain: np.ndarray | None = None
        self._static_friction: np.ndarray | None = None
        self._torque_on = np.ones(self._lead + (self.model.nu,), dtype=bool)
        self._goal_shapes = ((self.model.nu,), self._lead + (self.model.nu,))  # (step checks)
        self._static_forcerange: np.ndarray | None = None
        self._static_forcelimited: np.ndarray | None = None
        self._drive_forcerange: np.ndarray | None = None  # static, scaled by exogenous effects
        self._runtime_fields: set[str] = set()
        self._const_moved = False  # constants set from moved masses (``_set_const``)
        self._is_dcmotor = self.model.actuator_gaintype == mujoco.mjtGain.mjGAIN_DCMOTOR
        # dcmotors compiled with an integrator state need ki > 0 at every step
        has_int = servo.dcmotor_act_layout(self.model)[:, servo.ACT_INTEGRATOR] >= 0
        self._off_gains = np.zeros((self.model.nu, len(_CONTROLLER_GAINS)))
        self._off_gains[has_int, 1] = servo.KI_MIN
        self.servo_clock = servo.ServoClock(self.model)  # the servos' update period
        # servos whose firmware slews its goal: a reset puts the slewed goal at the held ctrl
        self._slew_act, self._slew_adr = servo.goal_slew_states(self.model)

    # -- servo update period ----------------------------------------------------------------------
    @property
    def servo_period(self) -> float:
        """The servos' update period [s] as stepped (0: the actuator law acts continuously)."""
        return self.servo_clock.every * float(self.model.opt.timestep)

    def set_servo_period(self, period: float) -> None:
        """Sample the law of each fixed-gain affine actuator every ``period`` [s] and hold its
        force until the next update (``servo.ServoClock``; 0: continuous, the default)."""
        self.servo_clock.set_period(period, float(self.model.opt.timestep))
        self._apply_torque_mask()

    # -- Fields protocol ------------------------------------------------------------------------
    @property
    def _lead(self) -> tuple[int, ...]:
        raise NotImplementedError

    def array(self, name: str) -> np.ndarray:
        raise NotImplementedError

    def nominal(self, name: str) -> np.ndarray:
        if name not in self._nominal:
            self._nominal[name] = np.array(getattr(self._base_model, name), copy=True)
        return self._nominal[name]

    def set_nominal(self, name: str, index: object, value: object) -> None:
        """Change a model field's nominal value at run time and re-apply the effects on top.

        Used by emulated firmware writing servo gains from its control table
        (``actuator_gainprm`` / ``actuator_dynprm`` columns, see ``lowcostdex.sim.servo``):
        effects that scale a field (e.g. ``gain_error``) keep acting relative to the new value.

        Args:
          name: MjModel field, e.g. "actuator_gainprm".
          index: numpy index into the (unbatched) field, e.g. ``(actuator, servo.GAIN_KP)``.
          value: new nominal value(s).
        """
        self.nominal(name)[index] = value
        self._runtime_fields.add(name)
        self._apply_model_effects()

    # -- effects ----------------------------------------------------------------------------------
    @property
    def effects(self) -> list[AppliedEffect]:
        """The applied effects (values of the first simulation in a batch)."""
        out = []
        for b in self._bound:
            vals = {k: np.asarray(v)[0] if np.ndim(v) == 2 else np.asarray(v)
                    for k, v in b.values.items()}
            out.append(AppliedEffect(b.cls.name, b.targets.joints, vals))
        return out

    def set_effects(self, effects: Sequence[AppliedEffect] | Sequence[Sequence[AppliedEffect]]
                    ) -> None:
        """Replace the applied effects; model fields are recomputed from the nominal model.

        For a ``BatchPlant`` pass either one list (same values in every sim) or one list per
        simulation with the same effect names and joints in the same order (values differ).
        """
        per_sim = self._split_per_sim(effects)
        first = per_sim[0]
        bound = []
        for k, e in enumerate(first):
            if e.cls.requires and e.cls.kind != "exogenous":
                raise ConfigError(f"effect {e.name} requires {e.cls.requires}")
            targets = Targets.resolve(self._base_model, e.joints)
            if self._lead and len(per_sim) > 1:
                vals = {p: np.stack([np.asarray(s[k].values[p], float) for s in per_sim])
                        for p in e.values}
            else:
                vals = {p: np.asarray(v, float) for p, v in e.values.items()}
            for p, v in vals.items():  # NaN/inf diverged later, unnamed ('off': a non-finite null)
                if not np.all(np.isfinite(v) | (v == e.cls.param(p).null)):
                    raise ConfigError(f"effect {e.name}: parameter {p!r} must be finite, got "
                                      f"{v.tolist()!r}")
            bound.append(_Bound(e.cls, targets, vals))
        bound.sort(key=lambda b: _ORDER[b.cls.name])
        self._check_structure(bound)
        self._bound = bound
        self._apply_model_effects()

    def _split_per_sim(self, effects) -> list[list[AppliedEffect]]:
        effects = [effects] if isinstance(effects, (str, AppliedEffect)) else list(effects)
        if effects and not isinstance(effects[0], AppliedEffect):
            per_sim = [list(x) for x in effects]
            if not self._lead or len(per_sim) != self._lead[0]:
                per = " (or one such list per simulation)" if self._lead else ""
                raise ConfigError(f"effects are a list of AppliedEffect{per}; got {effects[0]!r}")
            sig = [(e.name, e.joints) for e in per_sim[0]]
            for s in per_sim[1:]:
                if [(e.name, e.joints) for e in s] != sig:
                    raise ConfigError("per-simulation effect lists must share names and joints")
            return per_sim
        return [effects]

    def _check_structure(self, bound: list[_Bound]) -> None:
        for b in bound:
            if b.cls.name == "latency":
                hist = self._base_model.actuator_history[b.targets.actuators, 0]
                dt = self._base_model.opt.timestep
                need = np.max(np.asarray(b.values["delay"])) / dt + 1
                if np.any(hist < need):
                    raise ConfigError(
                        "latency needs actuator history buffers: build the model with "
                        "plant.prepare_spec(spec, effects) before compiling")

    def _apply_model_effects(self) -> None:
        touched = {"actuator_gainprm", "dof_frictionloss", "actuator_forcerange", "actuator_biasprm",
                   "actuator_forcelimited", "actuator_delay"}  # (a replay zeroes the delay)
        for b in self._bound:
            touched.update(b.cls.written_fields(b.targets))
        touched |= self._runtime_fields
        for name in touched:
            self.array(name)[...] = self.nominal(name)
        for b in self._bound:
            if b.cls.kind == "model" or b.cls.structural or b.cls.fields:
                b.cls.apply(self, b.targets, b.values)
        # constants (mj_setConst's) follow a simulation's own masses and locked plays: set where
        # its mass_error or a null backlash (``Effect.moves_constants``)
        # moved them, the compiled model's elsewhere (they were set in every simulation of a batch
        # holding one mass_error, from its armature too: a replay depended on its batch companions,
        # 2.8e-5 rad on an inertia_error column, and a reused plant kept earlier constants)
        moved = [np.broadcast_to(m, self._lead) for b in self._bound
                 if (m := b.cls.moves_constants(b.targets, b.values)) is not None]
        self._set_const(np.any(moved, axis=0) if moved else None)
        self._static_gain = np.array(self.array("actuator_gainprm"), copy=True)
        self._ctrl_gain = self._static_gain[..., _CONTROLLER_GAINS]  # (..., nu, 3), unmasked
        self._joint_applied = {k: np.array(self.array(k), copy=True) for k in JOINT_FRICTION}
        self._static_forcerange = np.array(self.array("actuator_forcerange"), copy=True)
        self._static_forcelimited = np.array(self.array("actuator_forcelimited"), copy=True)
        self._static_bias = np.array(self.array("actuator_biasprm"), copy=True)
        self._drive_forcerange = self._static_forcerange
        self._drive = exo.drive_targets(self._base_model, [
            b.targets.actuators for b in self._bound if b.cls.kind == "exogenous"])
        self._apply_torque_mask()
        self._friction = [b for b in self._bound if b.cls.substep(b.values)]
        self._has_friction = bool(self._friction)
        self._live = [b for b in self._bound if b.cls.live_on(self, b.targets, b.values)]
        self._has_exo = any(b.cls.kind == "exogenous" for b in self._bound)
        self._commands = [b for b in self._bound if b.cls.kind in ("command", "calibration")]
        for b in self._commands:  # constants of ``command``'s every step (nominal: set_nominal
            # re-applies the effects)
            if b.cls.structural:
                b.damping = (self.nominal("dof_damping")[b.targets.dofs],
                             ~self._is_dcmotor[b.targets.actuators])
        self._observed = [b for b in self._bound if b.cls.kind in ("observation", "calibration")]
        self._plays = [(b, b.targets.has_play) for b in self._bound
                       if b.cls.name == "backlash" and np.any(b.targets.has_play)]
        # ``measured_qpos``'s per-step reads: (read values, joint and play qpos addresses)
        self._play_reads = [(b.cls, {"read": np.asarray(b.values["read"], float)[..., h]},
                             b.targets.qpos[h], b.targets.play_qpos[h]) for b, h in self._plays]

    live = property(lambda self: bool(self._live))  # live effects rewrite fields every step

    @property
    def required_channels(self) -> tuple[str, ...]:
        """Measured channels the applied exogenous effects need in ``step(channels=...)``."""
        return tuple(sorted({c for b in self._bound for c in b.cls.requires}))

    # -- torque enable ----------------------------------------------------------------------------
    def set_torque_enabled(self, actuators: Sequence[int] | np.ndarray, enabled: bool,
                           sims: np.ndarray | None = None) -> None:
        """Servo torque on/off (off = free-wheeling bridge: zero actuator force)."""
        idx, enabled = errors.check_indices("actuators", actuators, self.model.nu, "actuators"), (
            errors.flag("enabled", enabled))  # ('no' turned torque ON; a mask was indices 0/1)
        if self._lead:
            rows = np.arange(self._lead[0]) if sims is None else np.asarray(sims)
            self._torque_on[np.ix_(rows, idx)] = enabled
        else:
            self._torque_on[idx] = enabled
        self._apply_torque_mask()

    def torque_enabled(self) -> np.ndarray:
        return self._torque_on.copy()

    def _apply_torque_mask(self) -> None:
        self._readings = exo.Readings()  # (the drives change: rescaled at the next step)
        if self._static_forcerange is None:
            return
        self._range_in_force()
        self._static_friction = torque_off_joint(self, self._bound, self._joint_applied, self._torque_on)
        self.servo_clock.release()  # a held force is recomputed at the next step

    def _range_in_force(self) -> None:
        """Force ranges from the model effects and torque enable (no held force)."""
        fr, fl = self.array("actuator_forcerange"), self.array("actuator_forcelimited")
        fr[...] = np.where(self._torque_on[..., None], self._drive_forcerange, 0.0)
        fl[...] = np.where(self._torque_on, self._static_forcelimited, 1)
        gain = self.array("actuator_gainprm")
        gain[..., _CONTROLLER_GAINS] = self._ctrl_gain  # as the exogenous effects left them
        self._mask_controller(gain)

    def _mask_controller(self, gain: np.ndarray) -> None:
        """Zero the controller gains of servos with torque off, in place.

        A free-wheeling bridge drives no current: with kp = ki = kd = 0 the dcmotor's drive voltage
        equals the back-EMF, so the winding current (and its heating) is zero, not just the
        output torque that the force clamp removes. (A servo compiled with an integrator state
        keeps ki at ``servo.KI_MIN``: MuJoCo requires ki > 0 while that state exists.)
        """
        off = ~self._torque_on & self._is_dcmotor
        if np.any(off):
            gain[..., _CONTROLLER_GAINS] = np.where(off[..., None], self._off_gains,
                                                    gain[..., _CONTROLLER_GAINS])

    # -- stepping ---------------------------------------------------------------------------------
    def command(self, goal: np.ndarray, dt: float = 0.0) -> np.ndarray:
        """Apply command effects to a full goal vector (..., nu) [rad] held ``dt`` s; returns
        ctrl. Each effect's state has "setpoint" (the ctrl held now), "dt", "qpos", "qvel"."""
        ctrl = np.array(goal, dtype=float, copy=True)
        for b in self._commands:
            a = b.targets.actuators
            prefix = b.cls.name + ":"
            key_state = {k[len(prefix):]: v for k, v in self._state.items()
                         if k.startswith(prefix)}
            key_state["setpoint"] = self.ctrl[..., a]  # what the servo holds now (a copy)
            key_state["fields"] = self  # the model's fields (which actuators a law acts on)
            key_state["dt"], key_state["qpos"], key_state["qvel"] = dt, self.qpos, self.qvel
            # its hidden dofs' state (a play read by the servo), where the model has them (the
            # play hinges of backlash, the one structural effect; without them it reads none)
            if b.cls.structural and b.targets.play_index[0]:
                g = self.array("actuator_gainprm")[..., a, 0]
                key_state["kv_kp"] = np.divide(-self.array("actuator_biasprm")[..., a, 2], g,
                                               out=np.zeros(g.shape), where=g > 0)
                # the D of a servo without kv (nominal damping, non-dcmotor: set with the effects)
                d, not_dc = b.damping
                key_state["damping"] = np.where((key_state["kv_kp"] == 0) & not_dc, d, 0.0)
            sub = b.cls.command(b.targets, b.values, ctrl[..., a], key_state, self.rng)
            if (tq := key_state.pop("torque", None)) is not None:  # outside the force range
                h = b.targets.has_play
                self.qfrc_applied[..., b.targets.dofs[h]] = tq[..., h]
            for k in ("setpoint", "dt", "qpos", "qvel", "kv_kp", "damping", "fields"):
                key_state.pop(k, None)
            for k, v in key_state.items():
                self._state[f"{b.cls.name}:{k}"] = v
            ctrl[..., a] = sub
        return ctrl

    def _exogenous(self, channels: Mapping[str, np.ndarray] | None) -> None:
        if not self._has_exo or self._readings.same(channels):
            return  # (the last step's readings: the drives are as its rescale left them)
        gain, drive = exo.rescale(self, self._bound, channels, self._static_gain, self._drive)
        # a servo update (``_range_in_force``) restores these, not the static gains: a sagging
        # supply or a hot winding lasts the whole control period under a servo period too
        self._ctrl_gain = gain[..., _CONTROLLER_GAINS]
        if drive is not None:  # other actuators: torque per command and force range
            self._drive_forcerange = exo.scale_drive(self, gain, drive, self._drive,
                                                     self._static_bias, self._static_forcerange)
            if not self.servo_clock.every:  # (a held force keeps its range to the next update)
                self._range_in_force()
        self._mask_controller(gain)
        self.array("actuator_gainprm")[...] = gain
        # nothing else rewrites the drives between steps without live effects or servo updates
        self._readings.keep(channels, not self._live and not self.servo_clock.every)

    def _friction_level(self, qvel: np.ndarray, force: np.ndarray,
                        external: np.ndarray | None = None) -> np.ndarray:
        return friction_level(self._static_friction, self._friction, qvel, force, external,
                              self._torque_on)

    def measured_qpos(self, qpos: np.ndarray | None = None) -> np.ndarray:
        """qpos as the encoders report it: observation effects applied (..., nq)."""
        q = np.array(self.qpos if qpos is None else qpos, dtype=float, copy=True)
        for cls, v, jq, pq in self._play_reads:  # motor + read x play
            q[..., jq] = cls.reading(v, q[..., jq], q[..., pq])
        for b in self._observed:
            ad = b.targets.qpos
            q[..., ad] = b.cls.observe(b.targets, b.values, q[..., ad], self.rng)
        return q

    def step(self, goal: np.ndarray, nstep: int,
             channels: Mapping[str, np.ndarray] | None = None,
             sims: np.ndarray | None = None) -> None:
        """Advance one control period: goals (..., nu) [rad] held for ``nstep`` substeps.

        Args:
          goal: goal position of every actuator [rad], shape (nu,) or (nsim, nu).
          nstep: physics substeps (an integer >= 1).
          channels: measured per-actuator channels for exogenous effects, e.g.
            {"temperature": (..., nu) [deg C], "voltage": (..., nu) [V]}.
          sims: (batch) sorted int32 ids of the simulations whose physics advances (None:
            all); the others keep their state (their effects still see the goal, as the
            simulations of a batch are independent, the advanced ones step as with ``None``).
        Raises:
          ConfigError: a goal of another shape (never broadcast) or not finite, or a bad nstep.
        """
        check_count("nstep (physics substeps)", nstep)
        check_finite_array("goal", goal, self._goal_shapes, lambda: (
            f"goals of the {self.model.nu} actuators{' (per simulation)' if self._lead else ''}"
            ": positions [rad] (a velocity actuator's rad/s, a motor's torque N m)"))
        self.step_unchecked(goal, nstep, channels, sims)

    def step_unchecked(self, goal: np.ndarray, nstep: int,
                       channels: Mapping[str, np.ndarray] | None = None,
                       sims: np.ndarray | None = None) -> None:
        """``step`` without its argument checks (2-4 us a call), for loops whose goals are
        checked where they come from: a replay of a loaded log, an env's clipped actions.
        Never a user's goal: a short one is broadcast, a NaN zeroes every control unsaid."""
        self.ctrl[...] = (self.command(goal, nstep * float(self.model.opt.timestep))
                          if self._commands else goal)  # (command copies the goal, then edits)
        self._exogenous(channels)
        clock = self.servo_clock
        if self._has_friction or self._live or clock.every:
            fl = self.array("dof_frictionloss")
            k = 0
            while k < nstep:
                if self._has_friction:
                    fl[...] = self._friction_level(self.qvel, self.actuator_force,
                                                   -self.qfrc_bias)
                if self._live:
                    self._live_forcerange()
                if clock.every and clock.phase == 0:
                    if not self._live:
                        self._range_in_force()
                    clock.hold(self)
                elif clock.every and self._live:
                    clock.keep(self)
                n = 1 if (self._has_friction or self._live or not clock.every) else min(
                    nstep - k, clock.every - clock.phase)
                self._advance(n, sims)
                k += n
                clock.tick(n)
        else:
            self._advance(nstep, sims)
        self._check_finite()

    def _live_forcerange(self) -> None:
        """Live model effects (a torque-speed line) rewrite the force range from the state:
        from the range the model effects and torque enable set, every physics step."""
        fr = self.array("actuator_forcerange")
        fr[...] = np.where(self._torque_on[..., None], self._drive_forcerange, 0.0)
        # the flags too: a live effect may limit an actuator that the model leaves unlimited
        self.array("actuator_forcelimited")[...] = np.where(self._torque_on,
                                                            self._static_forcelimited, 1)
        for b in self._live:
            b.cls.live_apply(self, b.targets, b.values, self.qvel, fr)

    def reset_effect_state(self) -> None:
        """Forget per-rollout effect state (the backlash play operator's setpoint)."""
        self._state.clear()

    def rest_play(self, sims: np.ndarray | None = None) -> None:
        """Put each backlash play where the static load pushes it, keeping the readings
        (``reset_state.rest_play``; ``sims``: BatchPlant rows, their state forward-computed)."""
        rest_play(self, sims)

    def forward(self, sims: np.ndarray | None = None) -> None:
        """Recompute derived quantities after an edit of the state (``sims``: BatchPlant rows)."""
        self._forward(sims)


class Plant(_PlantBase):
    """One simulation of a servo-driven model with effects.

    Args:
      model: a compiled model (its actuators drive the joints); it is copied, never mutated.
      effects: effects to apply.
      rng: generator for noise effects (seeded by the caller).
      servo_period: the servos' update period [s] (``set_servo_period``; 0: continuous).
    """

    def __init__(self, model: mujoco.MjModel, effects: Sequence[AppliedEffect] = (),
                 rng: np.random.Generator | None = None, servo_period: float = 0.0):
        self._base_model = model
        self.model = copy.copy(model)
        self.data = mujoco.MjData(self.model)
        self.rng = check_rng("rng", rng) or np.random.default_rng(0)
        self._init_effects()
        self.set_effects(effects)
        self.set_servo_period(servo_period)
        mujoco.mj_forward(self.model, self.data)

    @property
    def _lead(self) -> tuple[int, ...]:
        return ()

    def array(self, name: str) -> np.ndarray:
        return getattr(self.model, name)

    def _set_const(self, moved: np.ndarray | None) -> None:
        if self._const_moved:
            for name in _CONST_OUT:
                getattr(self.model, name)[...] = self.nominal(name)
        self._const_moved = bool(moved is not None and moved)
        if self._const_moved:
            mujoco.mj_setConst(self.model, self.data)

    @property
    def qpos(self) -> np.ndarray:
        return self.data.qpos

    @property
    def qvel(self) -> np.ndarray:
        return self.data.qvel

    @property
    def ctrl(self) -> np.ndarray:
        return self.data.ctrl

    @property
    def actuator_force(self) -> np.ndarray:
        return self.data.actuator_force

    @property
    def act(self) -> np.ndarray:
        return self.data.act

    @property
    def qfrc_bias(self) -> np.ndarray:
        return self.data.qfrc_bias

    qfrc_applied = property(lambda self: self.data.qfrc_applied)  # an (nv,) view

    @property
    def time(self) -> float:
        return float(self.data.time)

    def _advance(self, nstep: int, sims: np.ndarray | None = None) -> None:
        mujoco.mj_step(self.model, self.data, nstep=nstep)

    def _forward(self, sims: np.ndarray | None = None) -> None:
        mujoco.mj_forward(self.model, self.data)

    def _check_finite(self) -> None:
        if not (np.all(np.isfinite(self.data.qpos)) and np.all(np.isfinite(self.data.qvel))):
            raise PhysicsError(f"simulation diverged at t={self.data.time:.4f}s")
        if self.data.warning.number[mujoco.mjtWarning.mjWARN_BADQACC] > 0:
            raise PhysicsError(f"bad acceleration at t={self.data.time:.4f}s")

    def reset(self, qpos: np.ndarray | None = None, qvel: np.ndarray | None = None,
              ctrl: np.ndarray | None = None, act: np.ndarray | None = None,
              ctrl_history: np.ndarray | None = None) -> None:
        """Reset to the given state; servos hold ``ctrl`` (default: the joint positions they drive).

        Delay buffers are filled with ``ctrl`` so a delayed servo holds still instead of
        replaying zeros, or with ``ctrl_history`` (k, nu): the ctrl of the last k physics steps,
        oldest first, the last row at the reset time (a replay starting mid-log). With backlash,
        a joint's position in ``qpos`` (plus its play hinge's, usually 0) is its link's angle,
        and the play rests where the static load pushes it (``rest_play``).
        """
        m, d = self.model, self.data
        _check_state(m, (), qpos=qpos, qvel=qvel, ctrl=ctrl, act=act)
        mujoco.mj_resetData(m, d)
        if qpos is not None:
            d.qpos[:] = qpos
        if qvel is not None:
            d.qvel[:] = qvel
        d.ctrl[:] = actuated_positions(m, d.qpos) if ctrl is None else ctrl
        if act is not None:
            d.act[:] = act
        else:  # a servo at rest: its firmware's slewed goal is the goal it holds
            d.act[self._slew_adr] = d.ctrl[self._slew_act]
        self.reset_effect_state()
        _fill_ctrl_history(m, d, ctrl_history)
        self.servo_clock.phase = 0  # a servo updates at the first step
        mujoco.mj_forward(m, d)
        self.rest_play()


class BatchPlant(_PlantBase):
    """``nsim`` simulations of one model on ``mujoco.batch`` with per-simulation effect values.

    Args:
      model: compiled model (copied).
      nsim: number of simulations.
      effects: one list (shared) or one list per simulation.
      nthread: batch threads (0: all CPUs).
      rng: generator for noise effects.
      servo_period: the servos' update period [s] (``set_servo_period``; 0: continuous).
    """

    def __init__(self, model: mujoco.MjModel, nsim: int,
                 effects: Sequence[AppliedEffect] | Sequence[Sequence[AppliedEffect]] = (),
                 nthread: int = 0, rng: np.random.Generator | None = None,
                 servo_period: float = 0.0):
        errors.check_number("nsim (simulations)", nsim, 1, integer=True)  # 2.5: mujoco's TypeError
        self._base_model = model
        self.model = copy.copy(model)
        self.batch = mjbatch.Batch(self.model, nsim=nsim, nthread=nthread)
        self._scratch = mujoco.MjData(self.model)
        self.nsim = nsim
        self.rng = check_rng("rng", rng) or np.random.default_rng(0)
        self._views = {n: self.batch.bind(n) for n in ("qpos", "qvel", "ctrl", "act", "time",
                                                       "actuator_force", "qfrc_bias", "history",
                                                       "qfrc_applied")}
        self._init_effects()
        self.set_effects(effects)
        self.set_servo_period(servo_period)
        self.batch.forward()

    @property
    def _lead(self) -> tuple[int, ...]:
        return (self.nsim,)

    def array(self, name: str) -> np.ndarray:
        return self.batch.expand(name)

    def _set_const(self, moved: np.ndarray | None) -> None:
        """Constants of the simulations ``moved`` (nsim,) recomputed, the rest the model's."""
        if self._const_moved:
            for name in _CONST_OUT:
                if self.batch.expanded(name) is not None:
                    self.batch.expand(name)[...] = self.nominal(name)
        rows = np.flatnonzero(moved) if moved is not None else np.zeros(0, int)
        self._const_moved = len(rows) > 0
        if self._const_moved:
            self.batch.set_const(ids=rows)

    @property
    def qpos(self) -> np.ndarray:
        return self._views["qpos"]

    @property
    def qvel(self) -> np.ndarray:
        return self._views["qvel"]

    @property
    def ctrl(self) -> np.ndarray:
        return self._views["ctrl"]

    @property
    def actuator_force(self) -> np.ndarray:
        return self._views["actuator_force"]

    @property
    def qfrc_bias(self) -> np.ndarray:
        return self._views["qfrc_bias"]

    qfrc_applied = property(lambda self: self._views["qfrc_applied"])  # (nsim, nv)

    @property
    def act(self) -> np.ndarray:
        return self._views["act"]

    @property
    def time(self) -> np.ndarray:
        return self._views["time"]

    def _advance(self, nstep: int, sims: np.ndarray | None = None) -> None:
        self.batch.step(sims, nstep=nstep)

    def _forward(self, sims: np.ndarray | None = None) -> None:
        if sims is None:
            self.batch.forward()
        else:
            self.batch.forward(ids=np.asarray(sims, dtype=int))

    def _check_finite(self) -> None:
        # one finite sum means every value is finite (a non-finite value makes it inf or NaN;
        # an overflowing sum of finite values falls through to the full check)
        if math.isfinite(np.add.reduce(self.qpos, None) + np.add.reduce(self.qvel, None)):
            return
        if np.isfinite(self.qpos).all() and np.isfinite(self.qvel).all():
            return
        bad = ~(np.all(np.isfinite(self.qpos), axis=1) & np.all(np.isfinite(self.qvel), axis=1))
        if np.any(bad):
            raise PhysicsError(f"simulations {np.flatnonzero(bad).tolist()} diverged")

    def reset(self, qpos: np.ndarray | None = None, qvel: np.ndarray | None = None,
              ctrl: np.ndarray | None = None, sims: np.ndarray | None = None,
              ctrl_history: np.ndarray | None = None, act: np.ndarray | None = None) -> None:
        """Reset simulations ``sims`` (default all) to states given as (len(sims), n) arrays.

        ``ctrl_history`` (len(sims), k, nu) fills the delay buffers with past ctrl, oldest
        first (see ``Plant.reset``); by default they hold ``ctrl``. ``act`` (len(sims), na):
        actuator activations (an integrating servo's setpoint; default 0, a slewed goal at
        ``ctrl``). Backlash plays rest
        where the static load pushes them (``rest_play``).
        """
        rows = np.arange(self.nsim) if sims is None else np.asarray(sims, dtype=int)
        _check_state(self.model, (len(rows),), qpos=qpos, qvel=qvel, ctrl=ctrl, act=act)
        self.batch.reset(ids=rows)
        m, d = self.model, self._scratch
        for k, i in enumerate(rows):
            mujoco.mj_resetData(m, d)
            if qpos is not None:
                d.qpos[:] = qpos[k]
            if qvel is not None:
                d.qvel[:] = qvel[k]
            d.ctrl[:] = actuated_positions(m, d.qpos) if ctrl is None else ctrl[k]
            if act is not None:
                d.act[:] = act[k]
            else:  # a servo at rest: its firmware's slewed goal is the goal it holds
                d.act[self._slew_adr] = d.ctrl[self._slew_act]
            _fill_ctrl_history(m, d, None if ctrl_history is None else ctrl_history[k])
            self.qpos[i] = d.qpos
            self.qvel[i] = d.qvel
            self.ctrl[i] = d.ctrl
            if act is not None or len(self._slew_adr):
                self.act[i] = d.act
            if m.nhistory:
                self._views["history"][i] = d.history
        for value in self._state.values():
            value[rows] = np.nan  # per-rollout effect state restarts in these simulations
        self.servo_clock.phase = 0  # servos update at the first step (all simulations: one clock)
        self.batch.forward(ids=rows)
        self.rest_play(rows)


def _check_state(m: mujoco.MjModel, lead: tuple[int, ...], **given: np.ndarray | None) -> None:
    """A reset's state arrays: (*lead, n) finite numbers each (a short one was broadcast)."""
    for name, v in given.items():
        if v is not None:
            n = {"qpos": m.nq, "qvel": m.nv, "ctrl": m.nu, "act": m.na}[name]
            check_finite_array(name, v, (lead + (n,),), f"the model's {name} values (rad, m; "
                               "rad/s, m/s for qvel)")
