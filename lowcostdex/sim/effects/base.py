"""Effect base: parameters, the model fields and targets an effect acts on, and ``Effect``.

The catalogue of concrete effects is ``lowcostdex.sim.effects.catalogue``; the package docstring
(``lowcostdex.sim.effects``) explains the kinds and magnitudes.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar, Protocol

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_choice

Values = Mapping[str, np.ndarray]
def play_joint_name(joint: str) -> str:
    """Name of the play hinge a backlash adds for ``joint`` (``Backlash.prepare``)."""
    return f"{joint}__play"


DEFAULT_REFERENCE_TEMPERATURE = 25.0  # [deg C] winding reference when the model has none


@dataclass(frozen=True)
class Param:
    """A named effect parameter.

    Attributes:
      name: parameter name, unique within its effect.
      null: value at which the effect is absent.
      low, high: bounds for fitting [unit].
      unit: SI unit string.
      dr: plausible range for domain randomization on a D'Claw [unit].
      start: initial guess for fitting (default: ``null`` moved inside the bounds).
      doc: one-line meaning.
      limit: physical hard limits [unit]: a fit that lands on ``low`` or ``high`` may widen its
        search range up to these, never beyond (default: ``(low, high)``, no widening).
      on: the actuators the parameter acts on: "any", "dcmotor" (dcmotor servos only) or
        "other" (every other actuator); a fit frees it only where the model has such actuators.
      ends: both bounds are the physical ends of the parameter (a share between two limiting
        behaviours): a fit there is a value, not a sign that the range is too narrow.
    """

    name: str
    null: float
    low: float
    high: float
    unit: str
    dr: tuple[float, float]
    start: float | None = None
    doc: str = ""
    limit: tuple[float, float] | None = None
    on: str = "any"
    ends: bool = False

    def __post_init__(self) -> None:
        if not self.low < self.high:
            raise ConfigError(f"param {self.name}: low must be < high")
        if not (self.low <= self.dr[0] <= self.dr[1] <= self.high):
            raise ConfigError(f"param {self.name}: dr range {self.dr} outside bounds")
        if self.limit is not None and not self.limit[0] <= self.low < self.high <= self.limit[1]:
            raise ConfigError(f"param {self.name}: hard limit {self.limit} inside the bounds")
        check_choice(f"param {self.name} actuators", self.on, ("any", "dcmotor", "other"))

    def acts(self, dcmotor: np.ndarray) -> bool:
        """Whether it acts on some of these actuators ((n,) bool: which are dcmotor servos,
        e.g. those with a finite stall torque); a fit frees only parameters that act."""
        dc = np.asarray(dcmotor, bool)
        return self.on == "any" or bool(np.any(dc if self.on == "dcmotor" else ~dc))

    @property
    def hard(self) -> tuple[float, float]:
        """Physical hard limits of the parameter (``limit``, or the fit bounds)."""
        return self.limit if self.limit is not None else (self.low, self.high)

    @property
    def initial(self) -> float:
        """Fit start value, strictly inside the bounds."""
        if self.start is not None:
            return self.start
        return float(np.clip(self.null, self.low + 1e-6 * (self.high - self.low),
                             self.high - 1e-6 * (self.high - self.low)))


class Fields(Protocol):
    """Access to model fields, single (n, ...) or batched (nsim, n, ...)."""

    def array(self, name: str) -> np.ndarray:
        """Live array of a model field."""

    def nominal(self, name: str) -> np.ndarray:
        """The field's value in the nominal model, shape (n, ...)."""


# ``np.clip``'s ufunc, called without its Python wrappers (np.clip on arrays ends in this very
# ufunc: the same values; a replay clips a few small arrays every physics step)
try:
    from numpy._core.umath import clip as clip
except ImportError:  # pragma: no cover - numpy < 2
    from numpy.core.umath import clip as clip


@dataclass(frozen=True)
class Targets:
    """Where an effect acts: actuated joints and their indices in a compiled model.

    Attributes:
      joints: joint names.
      actuators: actuator index per joint (the servo driving it).
      dofs: dof address per joint.
      qpos: qpos address per joint.
      bodies: the body each joint moves.
      play: per joint, the id of its backlash play hinge (``Backlash.prepare``), -1 when the
        model has none; ``play_qpos`` / ``play_dofs`` its qpos and dof addresses (-1: none).
    """

    joints: tuple[str, ...]
    actuators: np.ndarray
    dofs: np.ndarray
    qpos: np.ndarray
    bodies: np.ndarray
    play: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    play_qpos: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    play_dofs: np.ndarray = field(default_factory=lambda: np.zeros(0, int))

    @functools.cached_property
    def has_play(self) -> np.ndarray:
        """(n,) whether each joint has a play hinge (read-only: computed once, a replay reads
        it every physics step)."""
        out = (self.play >= 0) if len(self.play) == len(self.joints) else np.zeros(
            len(self.joints), bool)
        out.setflags(write=False)
        return out

    @functools.cached_property
    def play_index(self) -> tuple[bool, bool, np.ndarray, np.ndarray]:
        """(any joint has a play hinge, every joint has one, play qpos and play dof addresses
        with 0 where a joint has none): ``Backlash.command``'s per-step reads, computed once."""
        has = self.has_play
        if not np.any(has):
            return False, False, np.zeros(len(has), int), np.zeros(len(has), int)
        return (True, bool(np.all(has)), np.where(has, self.play_qpos, 0),
                np.where(has, self.play_dofs, 0))

    @functools.cached_property
    def owners(self) -> np.ndarray | None:
        """Indices of the targets whose actuator no earlier target shares (a tendon's servo
        driving several joints is written once, from its first joint's values); None when
        every target has an actuator of its own (joint actuators: the effects as before)."""
        _, first = np.unique(self.actuators, return_index=True)
        return None if len(first) == len(self.actuators) else np.sort(first)

    def servos(self, lead: tuple[int, ...], *values: np.ndarray
               ) -> tuple[Targets, list[np.ndarray]]:
        """These targets and per-target ``values`` (..., n) restricted to one target per
        actuator (``owners``; unchanged when none is shared): servo-side effects write each
        actuator once."""
        own = self.owners
        if own is None:
            return self, list(values)
        vals = [np.broadcast_to(np.asarray(v, float), lead + (len(self.actuators),))[..., own]
                for v in values]
        sub = Targets(tuple(self.joints[i] for i in own), self.actuators[own], self.dofs[own],
                      self.qpos[own], self.bodies[own])
        return sub, vals

    @classmethod
    def resolve(cls, model: mujoco.MjModel, joints: tuple[str, ...] | list[str]) -> Targets:
        """Resolve joint names; each must be a hinge/slide driven by exactly one actuator: one
        on the joint, or (none there) one on a fixed tendon over it (``driving_actuator``)."""
        names = [model.joint(i).name for i in range(model.njnt)]
        acts, dofs, qpos, bodies, play = [], [], [], [], []
        for jn in joints:
            check_choice("joint", jn, names)
            jid = model.joint(jn).id
            acts.append(driving_actuator(model, jn))
            dofs.append(int(model.jnt_dofadr[jid]))
            qpos.append(int(model.jnt_qposadr[jid]))
            bodies.append(int(model.jnt_bodyid[jid]))
            pn = play_joint_name(jn)
            play.append(int(model.joint(pn).id) if pn in names else -1)
        play_a = np.array(play, int)
        has = play_a >= 0
        pq = np.where(has, model.jnt_qposadr[np.maximum(play_a, 0)], -1) if len(play_a) else play_a
        pd = np.where(has, model.jnt_dofadr[np.maximum(play_a, 0)], -1) if len(play_a) else play_a
        return cls(tuple(joints), np.array(acts, int), np.array(dofs, int), np.array(qpos, int),
                   np.array(bodies, int), play_a, np.asarray(pq, int), np.asarray(pd, int))


def tendon_actuators(model: mujoco.MjModel, jid: int) -> list[int]:
    """Actuators on a tendon that wraps joint ``jid`` (a fixed tendon's joint term)."""
    out = []
    for a in np.flatnonzero(model.actuator_trntype == mujoco.mjtTrn.mjTRN_TENDON):
        t = int(model.actuator_trnid[a, 0])
        wraps = range(model.tendon_adr[t], model.tendon_adr[t] + model.tendon_num[t])
        if any(model.wrap_type[w] == mujoco.mjtWrap.mjWRAP_JOINT and model.wrap_objid[w] == jid
               for w in wraps):
            out.append(int(a))
    return out


def driving_actuator(model: mujoco.MjModel, joint: str) -> int:
    """The one actuator driving ``joint``: an actuator on the joint itself, or where there is
    none, the one actuator on a tendon over it (a tendon-driven finger's servo, shared by the
    joints its cable crosses: it acts on the actuator's own coordinate, gear x tendon length)."""
    jid = model.joint(joint).id
    driving = np.flatnonzero((model.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT)
                             & (model.actuator_trnid[:, 0] == jid))
    if len(driving) == 0:
        driving = tendon_actuators(model, jid)
        if len(driving) == 1:
            return int(driving[0])
        raise ConfigError(f"joint {joint!r} must be driven by exactly one actuator (on it, or "
                          f"on a tendon over it), found {len(driving)} on tendons")
    if len(driving) != 1:
        raise ConfigError(f"joint {joint!r} must be driven by exactly one actuator, "
                          f"found {len(driving)}")
    return int(driving[0])


class Effect:
    """Base class: a named, parameterized extension of a servo-driven model."""

    name: ClassVar[str]
    kind: ClassVar[str]  # model | friction | command | observation | calibration | exogenous
    params: ClassVar[tuple[Param, ...]]
    requires: ClassVar[tuple[str, ...]] = ()  # measured channels needed (e.g. "temperature")
    optional: ClassVar[tuple[str, ...]] = ()  # channels used when given (e.g. "supply")
    # prepare() adds degrees of freedom (only with hidden_dofs; the qpos layout changes), and
    # apply() writes their fields whatever the kind
    structural: ClassVar[bool] = False
    # model effects whose fields depend on the state: ``live_apply`` every physics step
    live: ClassVar[bool] = False
    fields: ClassVar[tuple[str, ...]] = ()  # model fields written by ``apply``
    # kind friction: ``friction`` acts only where the servo's torque is off (back-driven), and
    # the level of the friction effect named ``SCALED`` is kept there by the share ``gear``
    torque_off: ClassVar[bool] = False
    SCALED: ClassVar[str] = ""
    doc: ClassVar[str] = ""

    # ---- parameters -----------------------------------------------------------------------
    @classmethod
    def param(cls, name: str) -> Param:
        for p in cls.params:
            if p.name == name:
                return p
        check_choice(f"{cls.name} parameter", name, [p.name for p in cls.params])
        raise AssertionError

    @classmethod
    def null_values(cls, n: int) -> dict[str, np.ndarray]:
        return {p.name: np.full(n, p.null) for p in cls.params}

    @classmethod
    def sample(cls, rng: np.random.Generator, shape: tuple[int, ...]) -> dict[str, np.ndarray]:
        """Draw parameters uniformly from their domain-randomization ranges."""
        return {p.name: rng.uniform(p.dr[0], p.dr[1], size=shape) for p in cls.params}

    @classmethod
    def is_null(cls, values: Values) -> bool:
        return all(np.allclose(values[p.name], p.null) for p in cls.params)

    # ---- structural edits before compile ----------------------------------------------------
    @classmethod
    def prepare(cls, spec: mujoco.MjSpec, joints: tuple[str, ...]) -> None:
        """Edit the spec so the compiled model can host any value in the bounds (default: none)."""

    @classmethod
    def written_fields(cls, t: Targets) -> tuple[str, ...]:
        """Model fields ``apply`` writes on these targets (reset to nominal before applying)."""
        return cls.fields

    @classmethod
    def moves_constants(cls, t: Targets, v: Values) -> np.ndarray | None:
        """Per simulation (lead shape), whether ``apply`` moves what ``mj_setConst`` derives
        from the model (masses, armature: the constraints' regularisation, dof_invweight0), so
        that the plant recomputes them; None: never."""
        return None

    # ---- hooks (overridden per kind) -----------------------------------------------------
    @classmethod
    def apply(cls, f: Fields, t: Targets, v: Values) -> None:
        """kind model: write model fields from their nominal values."""

    @classmethod
    def live_apply(cls, f: Fields, t: Targets, v: Values, qvel: np.ndarray,
                   forcerange: np.ndarray) -> None:
        """live model effects: rewrite the (..., nu, 2) actuator force range in place from the
        dof velocities [rad/s] (..., nv), every physics step."""

    @classmethod
    def live_on(cls, f: Fields, t: Targets, v: Values) -> bool:
        """Whether ``live_apply`` has work on these targets and values (default ``live``): a
        live effect makes a plant step one physics step at a time."""
        return cls.live

    @classmethod
    def substep(cls, v: Values) -> bool:
        """Whether ``friction`` sets a state-dependent level every physics step for these
        values (kind friction: always; a model effect may add one, e.g. a direction-dependent
        Coulomb level)."""
        return cls.kind == "friction"

    @classmethod
    def friction(cls, t: Targets, v: Values, qvel: np.ndarray, force: np.ndarray,
                 external: np.ndarray | None = None) -> np.ndarray:
        """kind friction: extra dry friction [N m] per target, from dof velocities [rad/s]
        (..., nv), actuator forces [N m] (..., nu) and the external generalized force on each
        dof [N m] (..., nv): gravity and velocity-product terms, ``-qfrc_bias`` (None: zero)."""
        raise NotImplementedError

    @classmethod
    def command(cls, t: Targets, v: Values, goal: np.ndarray, state: dict[str, np.ndarray],
                rng: np.random.Generator) -> np.ndarray:
        """kind command: map goals [rad] (..., n_targets) to what the servo receives.

        ``state`` persists across steps within a rollout (NaN entries mean "restarted"); its key
        "setpoint" is always the setpoint the servo held before this command.
        """
        raise NotImplementedError

    @classmethod
    def observe(cls, t: Targets, v: Values, q: np.ndarray,
                rng: np.random.Generator) -> np.ndarray:
        """kind observation: map true joint angles [rad] (..., n_targets) to encoder readings."""
        raise NotImplementedError

    @classmethod
    def exogenous(cls, f: Fields, t: Targets, v: Values, channels: Mapping[str, np.ndarray],
                  gain: np.ndarray, drive: np.ndarray | None = None) -> None:
        """kind exogenous: from the measured channels (..., n_targets), rescale in place the
        (..., nu, mjNGAIN) gain copy of the targets' dcmotor servos (their own motor model) and
        multiply the (..., nu) drive scale of the other targets (motor, position, velocity,
        general: the plant scales their torque per command, gainprm[0:3] and biasprm[0:3], and
        their force range by it; None: the plant has no such target)."""
        raise NotImplementedError


def dcmotor_targets(f: Fields, t: Targets) -> np.ndarray:
    """(n_targets,) whether each target's actuator is a dcmotor servo."""
    return f.nominal("actuator_gaintype")[t.actuators] == int(mujoco.mjtGain.mjGAIN_DCMOTOR)
