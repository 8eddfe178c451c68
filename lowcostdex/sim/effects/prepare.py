"""Structural room for effects in a model, made on its spec before compiling.

Latency needs actuator history buffers, backlash (in a model with hidden dofs) a play hinge per
joint: ``prepare_spec`` adds them for a list of applied effects, ``compile_with_effects`` for
(name, joints) pairs. The ``Plant`` (``lowcostdex.sim.plant``, which re-exports both) then writes
the effects' values into the compiled model's fields.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco

from lowcostdex.errors import ConfigError
from lowcostdex.sim.effects import EFFECTS, AppliedEffect


def prepare_spec(spec: mujoco.MjSpec, effects: Sequence[AppliedEffect],
                 hidden_dofs: bool = False) -> mujoco.MjSpec:
    """Make structural room for ``effects`` (e.g. actuator history buffers for latency).

    ``hidden_dofs``: also add the degrees of freedom of structural effects (backlash's play
    hinge between a servo and its link). They change the qpos layout, so models that share
    their state with a task's model (the emulated robot, env backends) leave them out (backlash
    is then the massless-motor play operator); the gap analysis's replays use them.
    """
    for e in [effects] if isinstance(effects, (str, AppliedEffect)) else effects:
        if not isinstance(e, AppliedEffect):  # (a str: "'str' object has no attribute 'cls'")
            raise ConfigError(f"effects are a list of AppliedEffect, e.g. [AppliedEffect("
                              f"'latency', ('ff_top',), {{'delay': 0.02}})]; got {e!r}")
        if hidden_dofs or not e.cls.structural:
            e.cls.prepare(spec, e.joints)
    return spec


def compile_with_effects(spec: mujoco.MjSpec, effect_names_joints: Sequence[tuple[str, Sequence[str]]]
                         ) -> mujoco.MjModel:
    """Compile ``spec`` with room for effects given as (name, joints) pairs."""
    for name, joints in effect_names_joints:
        EFFECTS[name].prepare(spec, tuple(joints))
    return spec.compile()

