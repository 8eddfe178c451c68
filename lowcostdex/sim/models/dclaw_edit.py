"""An edit of the D'Claw MJCF that a fit from measured data names (issue 14): finger bases mounted
slightly rotated, each finger's link lengths scaled, the valve hinge's dry friction, damping and
inertia changed. A task built with ``model_edit=`` (``DClawEdit`` or its ``to_dict()``: it is
JSON, so a training run's config carries it) applies it to its spec before compiling, on every
backend that compiles the task's model.

This is the model side's edit (what a user's fit says); the emulated hidden robots' own
perturbations (``hardware.emulated.hidden_robots.ModelPerturbation``) are written separately on
purpose: the truth of a transfer test must not be this code.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

FINGERS = ("ff", "mf", "th")


def tilt_quat(angles: Sequence[float]) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of the rotation vector (ax, ay, 0) [rad]."""
    v = np.array([float(angles[0]), float(angles[1]), 0.0])
    angle = float(np.linalg.norm(v))
    if angle == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.array([np.cos(angle / 2), *(np.sin(angle / 2) * v / angle)])


def tilt_body(spec: Any, body: str, angles: Sequence[float]) -> None:
    """Multiply the tilt into ``body``'s quat in a ``mujoco.MjSpec`` (before compiling):
    the rotation acts in the body's own frame, as a base mounted slightly rotated."""
    import mujoco

    b = spec.body(body)
    if b is None:
        raise ValueError(f"no body {body!r} in the model")
    quat = np.zeros(4)
    mujoco.mju_mulQuat(quat, np.asarray(b.quat, float), tilt_quat(angles))
    b.quat = quat


@dataclass(frozen=True)
class DClawEdit:
    """A fitted D'Claw geometry / valve edit.

    Attributes:
      base_tilt: finger -> rotation vector (ax, ay) [rad] of its base about the base frame's x
        and y axes (``tilt_body``).
      link_length: finger -> factor on its joint-to-joint and joint-to-tip distances.
      valve_frictionloss: dry friction added to the valve hinge [N m] (>= 0).
      valve_damping: factor on the valve hinge's damping (> 0).
      valve_inertia: factor on the valve's geom masses and its hinge armature (> 0).
    """

    base_tilt: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    link_length: Mapping[str, float] = field(default_factory=dict)
    valve_frictionloss: float = 0.0
    valve_damping: float = 1.0
    valve_inertia: float = 1.0

    def __post_init__(self) -> None:
        from lowcostdex.errors import ConfigError, check_choice

        for finger, angles in self.base_tilt.items():
            check_choice("base_tilt finger", finger, FINGERS)
            a = np.asarray(angles, float)
            if a.shape != (2,) or not np.all(np.isfinite(a)) or np.max(np.abs(a)) > 0.5:
                raise ConfigError(f"base_tilt[{finger!r}] must be 2 finite angles within "
                                  f"+-0.5 rad (ax, ay), got {angles!r:.80}")
        for finger, factor in self.link_length.items():
            check_choice("link_length finger", finger, FINGERS)
            if not (math.isfinite(factor) and 0.5 <= factor <= 2.0):
                raise ConfigError(f"link_length[{finger!r}] must be a factor in [0.5, 2], "
                                  f"got {factor!r}")
        if not (math.isfinite(self.valve_frictionloss) and self.valve_frictionloss >= 0):
            raise ConfigError(f"valve_frictionloss must be >= 0 [N m], got "
                              f"{self.valve_frictionloss!r}")
        for name in ("valve_damping", "valve_inertia"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{name} must be a factor > 0, got {v!r}")

    def apply(self, spec: Any) -> None:
        """Edit a D'Claw spec (``build_dclaw``) in place; parts the spec lacks (fingers not
        built, no valve) are skipped."""
        import mujoco

        bodies = {b.name: b for b in spec.worldbody.find_all(mujoco.mjtObj.mjOBJ_BODY)}
        for finger, angles in self.base_tilt.items():
            if f"{finger}_base" in bodies:
                tilt_body(spec, f"{finger}_base", angles)
        for finger, factor in self.link_length.items():
            for link in (f"{finger}_link1", f"{finger}_link2"):
                if link in bodies:
                    bodies[link].pos = np.asarray(bodies[link].pos) * float(factor)
            tip = bodies.get(f"{finger}_link2")
            if tip is not None:
                for item in (*tip.geoms, *tip.sites):
                    item.pos = np.asarray(item.pos) * float(factor)
        if "valve_body" in bodies:
            joint = spec.joint("valve")
            joint.frictionloss = joint.frictionloss + float(self.valve_frictionloss)
            joint.damping[0] = joint.damping[0] * float(self.valve_damping)
            joint.armature = joint.armature * float(self.valve_inertia)
            for g in bodies["valve_body"].geoms:
                g.mass = g.mass * float(self.valve_inertia)

    def to_dict(self) -> dict[str, Any]:
        return {"base_tilt": {f: [float(a) for a in v] for f, v in self.base_tilt.items()},
                "link_length": {f: float(v) for f, v in self.link_length.items()},
                "valve_frictionloss": float(self.valve_frictionloss),
                "valve_damping": float(self.valve_damping),
                "valve_inertia": float(self.valve_inertia)}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> DClawEdit:
        from lowcostdex.errors import ConfigError

        unknown = sorted(set(d) - {"base_tilt", "link_length", "valve_frictionloss",
                                   "valve_damping", "valve_inertia"})
        if unknown:
            raise ConfigError(f"model_edit: unknown keys {unknown}; valid: base_tilt, "
                              "link_length, valve_frictionloss, valve_damping, valve_inertia")
        return cls(base_tilt={f: tuple(float(a) for a in v)
                              for f, v in dict(d.get("base_tilt", {})).items()},
                   link_length={f: float(v) for f, v in dict(d.get("link_length", {})).items()},
                   valve_frictionloss=float(d.get("valve_frictionloss", 0.0)),
                   valve_damping=float(d.get("valve_damping", 1.0)),
                   valve_inertia=float(d.get("valve_inertia", 1.0)))


def as_edit(edit: DClawEdit | Mapping[str, Any] | None) -> DClawEdit | None:
    """``model_edit=`` as given to a task: an edit, its ``to_dict()``, or None."""
    from lowcostdex.errors import ConfigError

    if edit is None or isinstance(edit, DClawEdit):
        return edit
    if isinstance(edit, Mapping):
        return DClawEdit.from_dict(edit)
    raise ConfigError(f"model_edit must be a DClawEdit or its to_dict() mapping, not "
                      f"{type(edit).__name__}")
