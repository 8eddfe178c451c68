"""The joints' dry-friction level every physics step, from the friction effects bound to a plant.

Each friction effect adds its level (``Effect.friction``) to the model's own frictionloss; an
effect that acts only with the torque off (``Effect.torque_off``: the back-driven gear train's own
law, ``backdriven_friction``) adds its level only on joints whose servo's torque is off, and there
keeps the share ``gear`` of the level of the effect it names (``Effect.SCALED``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def friction_level(static: np.ndarray, bound: Sequence, qvel: np.ndarray, force: np.ndarray,
                   external: np.ndarray | None, torque_on: np.ndarray) -> np.ndarray:
    """(..., nv) dry-friction level [N m]: ``static`` (the model's frictionloss, (..., nv)) plus
    each bound friction effect's (objects with ``cls``, ``targets``, ``values``, in the plant's
    order: a scaled effect before the torque-off law scaling it), from dof velocities [rad/s]
    (..., nv), actuator forces [N m] (..., nu), the external generalized force (..., nv) or None,
    and the servos' torque state (..., nu) bool."""
    level = np.array(static, copy=True)
    scaled = {b.cls.SCALED for b in bound if b.cls.torque_off}
    own: dict[str, np.ndarray] = {}  # the levels a torque-off law scales
    for b in bound:
        d = b.targets.dofs
        lv = b.cls.friction(b.targets, b.values, qvel, force, external)
        if b.cls.name in scaled:
            own[b.cls.name] = np.zeros(level.shape)
            own[b.cls.name][..., d] = lv
        if b.cls.torque_off:  # back-driven: only where the servo's torque is off
            kept = own.get(b.cls.SCALED, np.zeros(level.shape))[..., d]
            lv = np.where(torque_on[..., b.targets.actuators], 0.0,
                          lv - (1.0 - b.values["gear"]) * kept)
        level[..., d] = level[..., d] + lv
    return level



# The joint's own friction fields (``coulomb_friction``, ``viscous_damping``) a torque-off law can
# drop where the torque is off (``torque_off_joint``).
JOINT_FRICTION = ("dof_frictionloss", "dof_damping")


def torque_off_joint(fields, bound: Sequence, applied: dict[str, np.ndarray],
                     torque_on: np.ndarray) -> np.ndarray:
    """Keep only the share ``joint`` of the joint's own extra friction where a torque-off law
    acts and the servo's torque is off: nominal + joint x (applied - nominal) there, ``applied``
    (the model effects' values, (..., nv) per ``JOINT_FRICTION`` field) elsewhere. Writes the
    damping into ``fields`` (the plant) and returns the frictionloss (..., nv) the friction
    level starts from (``applied``'s when every bound law keeps it whole, ``joint`` 1).
    ``torque_on``: (..., nu) bool."""
    laws = [b for b in bound if b.cls.torque_off
            and np.any(np.asarray(b.values.get("joint", 1.0), float) != 1.0)]
    out = {k: np.array(v, copy=True) for k, v in applied.items()}
    for b in laws:
        d, a = b.targets.dofs, b.targets.actuators
        share = np.asarray(b.values["joint"], float)
        for k, v in applied.items():
            base = np.broadcast_to(fields.nominal(k), v.shape)[..., d]
            out[k][..., d] = np.where(torque_on[..., a], v[..., d], base + share * (v[..., d] - base))
    if laws:
        fields.array("dof_damping")[...] = out["dof_damping"]
    return out["dof_frictionloss"]
