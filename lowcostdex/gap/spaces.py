"""Bounded search spaces of the catalogue's effect parameters, made model-aware (for ``gap.fit``).

The effect catalogue gives each parameter its fit bounds, start and physical hard limits
(``Param.low/high/start/hard``); a fit needs them for this model and data (``Context``): the
latency bound starts at one physics step (the native delay is quantized below it, sysid trap 8),
torque limits below and dry friction up to the peak force the baseline model uses, scale factors
and Stribeck velocities are searched in log space, non-convex parameters get extra starts, and a
range widened by ``fit.widen`` (or held at a value by a gate: ``gap.gates``, ``gap.play_side``)
replaces the catalogue's. Split out of ``gap.fit`` (module size, session 17); ``fit`` re-exports
these names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from lowcostdex.sim.effects import effect

# Extra starts for non-convex parameters, as fractions of (value at start) or absolute values.
_EXTRA_STARTS: dict[tuple[str, str], tuple[float, ...]] = {
    ("latency", "delay"): (0.03, 0.06),
    ("backlash", "width"): (0.004, 0.03), ("backlash", "sensor"): (0.0, 1.0),  # read across
    ("stribeck_friction", "velocity"): (0.05,), ("torque_limit", "torque"): (0.25,),  # x peak
    ("inertia_error", "scale"): (3.0,), ("velocity_limit", "speed"): (1.0, 6.0),
    ("gain_error", "scale"): (0.5, 2.0),  # a 2.5x gain from 1.0 crept to 1.33 (LM, 2 ms step)
}

# Effects of the servo itself (written on its actuator): a servo that drives several joints
# through a tendon has one value, on its first joint (``Context.shared``).
SERVO_SIDE = ("latency", "gain_error", "torque_limit")


@dataclass(frozen=True)
class Context:
    """What parameter spaces need to know about the model and data.

    Attributes:
      dt: physics timestep [s].
      peak_force: (nj,) peak |actuator force| of the current model on the training data [N m].
      stall: (nj,) stall torque of each servo at its supply [N m] (inf: no drive limit).
      damping: (nj,) nominal joint damping [N m s/rad].
      widened: search ranges widened beyond the catalogue's, (effect, param, joint index) ->
        (low, high) in parameter units (``widen``).
      dcmotor: (nj,) which servos are dcmotors (None: those with a finite stall torque).
      slide: (nj,) which joints are slides (forces in N: the catalogue's N m hard limits on a
        dry friction or a torque limit do not bound them; None: none).
      shared: (nj,) which joints share an earlier joint's servo (a tendon's actuator over
        both): the servo's parameters (``SERVO_SIDE``) are free on its first joint only and
        held at their null here (None: every joint has its own).
    """

    dt: float
    peak_force: np.ndarray
    stall: np.ndarray
    damping: np.ndarray
    widened: dict[tuple[str, str, int], tuple[float, float]] = field(default_factory=dict)
    dcmotor: np.ndarray | None = None
    slide: np.ndarray | None = None
    shared: np.ndarray | None = None

    @property
    def is_dcmotor(self) -> np.ndarray:  # (nj,) bool: where a ``Param.on`` "dcmotor" acts
        return np.isfinite(self.stall) if self.dcmotor is None else np.asarray(self.dcmotor, bool)

    def force_cap(self, j: int, hard: float) -> float:
        """A catalogue hard limit ``hard`` [N m] on a force of joint ``j``; on a slide [N] the
        model's own peak force instead, when larger (a rail's 5-20 N beside a 5 N m cap)."""
        if self.slide is None or not self.slide[j]:
            return hard
        return max(hard, float(self.peak_force[j]))

    def with_ranges(self, ranges: dict[tuple[str, str, int], tuple[float, float]]) -> Context:
        """A copy with these widened ranges added."""
        return replace(self, widened={**self.widened, **ranges})


@dataclass(frozen=True)
class Free:
    """One free scalar: parameter ``param`` of effect ``effect`` on joint index ``joint``.

    Optimizer coordinate u = log(value) when ``log`` else value; bounds/fd in u.
    """

    effect: str
    param: str
    joint: int
    lo: float
    hi: float
    start: float
    log: bool
    fd: float
    extra: tuple[float, ...] = ()
    floor_null: bool = False  # the lower bound is replayed as the null (a delay: 04 trap 8)

    def at_floor(self, v: float) -> bool:  # the null that the lower bound stands for
        return self.floor_null and v <= self.lo * (1 + 1e-9)

    def to_u(self, v: float) -> float:
        return math.log(v) if self.log else v

    def from_u(self, u: float) -> float:
        return math.exp(u) if self.log else u

    @property
    def u_bounds(self) -> tuple[float, float]:
        return self.to_u(self.lo), self.to_u(self.hi)


def hard_limits(name: str, param: str, j: int, ctx: Context) -> tuple[float, float]:
    """Physical hard limits of one effect parameter on joint ``j``: the catalogue's
    ``Param.hard`` made model-aware (dry friction below the servo's stall torque, a torque limit
    below the peak force the model uses, total damping not negative, a delay of a step or more)."""
    p = effect(name).param(param)
    lo, hi = p.hard
    if (name, param) == ("latency", "delay"):
        lo = max(lo, ctx.dt)
    elif (name, param) == ("viscous_damping", "damping"):
        lo = max(lo, -float(ctx.damping[j]))
    elif name in ("coulomb_friction", "stribeck_friction") and param != "velocity":
        hi = min(ctx.force_cap(j, hi), float(ctx.stall[j]))
    elif (name, param) == ("torque_limit", "torque"):
        hi = min(ctx.force_cap(j, hi), float(max(ctx.peak_force[j], 2 * p.low)))
    return lo, hi


def space(name: str, param: str, j: int, ctx: Context) -> Free:
    """The bounded search space of one effect parameter on joint ``j`` (a range widened by
    ``widen`` replaces the catalogue's)."""
    p = effect(name).param(param)
    lo, hi, start = p.low, p.high, p.initial
    log = lo > 0 and hi / lo >= 8.0
    fd = 1e-3 * (hi - lo)
    extra = _EXTRA_STARTS.get((name, param), ())
    if (name, param) == ("latency", "delay"):
        lo = max(lo, ctx.dt)
        start = max(start, 2 * ctx.dt)
        fd = 0.25 * ctx.dt
    elif (name, param) == ("backlash", "width"):
        fd = 2e-4
    elif (name, param) == ("viscous_damping", "damping"):
        lo = max(lo, -float(ctx.damping[j]))
    elif (name, param) == ("coulomb_friction", "frictionloss"):
        hi = min(max(hi, float(ctx.peak_force[j])), float(ctx.stall[j]),
                 ctx.force_cap(j, p.hard[1]))  # to its force
        extra = (0.5 * hi,)  # a near-stall level: its probe and start are far from the small start
    elif (name, param) == ("backlash", "read"):
        lo = hi = p.null  # the link, or held at the motor side: a side chosen (gap.play_side)
    elif name == "coulomb_friction" and param in ("creep", "asymmetry"):
        lo = hi = p.null  # held (soft, symmetric) unless widened: a level at the force, creep
    elif name == "load_dependent_friction":
        hi = 0.9  # plastic gear trains reach ~0.46 (BAM's XL330 fit); friction < torque
    elif (name, param) == ("torque_limit", "torque"):
        peak = float(max(ctx.peak_force[j], 2 * lo))
        hi = min(ctx.force_cap(j, hi), peak)  # on a slide [N]: up to its peak force
        start = 0.5 * peak
        extra = tuple(f * peak for f in extra)
        log = True
    elif param == "offset":
        fd = 1e-4
    if log:
        fd = 1e-3
    if (name, param, j) in ctx.widened:
        lo, hi = ctx.widened[(name, param, j)]
    if name in SERVO_SIDE and ctx.shared is not None and ctx.shared[j]:
        lo = hi = p.null  # a servo shared with an earlier joint: fitted there, once
    start = float(np.clip(start, lo, hi))
    extra = tuple(float(np.clip(e, lo, hi)) for e in extra)
    floor_null = (name, param) == ("latency", "delay") and lo > p.null
    return Free(name, param, j, lo, hi, start, log, fd, extra, floor_null)
