"""Registered gymnasium ids (``lowcostdex/...``) and their factories.

Every factory accepts ``backend`` ("sim", "emulated", "hardware"), ``motor`` (servo model of the
hand, e.g. "XM430-W350"), ``randomize`` (effect names to randomize per episode, or a
``DomainRandomization`` / its ``to_dict()``; sim only), the D'Claw's ``model_edit`` (a fitted
geometry / valve edit, ``sim.models.dclaw_edit.DClawEdit`` or its ``to_dict()``) and
backend keyword arguments (e.g. ``port``). ``ENVS`` lists the ids; tests iterate it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import gymnasium as gym

from lowcostdex.hands import dclaw_spec
from lowcostdex.sim.effects import DEFAULT_DR_EFFECTS
from lowcostdex.sim.envs.dclaw_tasks import (
    FlipBlock,
    FlipConfig,
    Screw,
    ScrewConfig,
    TurnConfig,
    TurnValve,
)
from lowcostdex.sim.envs.hand_env import HandEnv, make_hand_env
from lowcostdex.sim.envs.task import Task

NAMESPACE = "lowcostdex"


def _dclaw(task_cls: Callable[..., Task], config: Any, **task_kw: Any) -> Callable[..., HandEnv]:
    def make(backend: str = "sim", motor: str | None = None,
             randomize: Sequence[str] | Mapping[str, Any] | None = None,
             render_mode: str | None = None,
             model_edit: Mapping[str, Any] | None = None,
             **kwargs: Any) -> HandEnv:
        hand = dclaw_spec() if motor is None else dclaw_spec(motor)
        cfg_overrides = {k: kwargs.pop(k) for k in list(kwargs) if hasattr(config, k)}
        cfg = type(config)(**{**config.__dict__, **cfg_overrides})
        task = task_cls(cfg, hand=hand, model_edit=model_edit, **task_kw)
        return make_hand_env(task, backend=backend, randomize=randomize,
                             render_mode=render_mode, **kwargs)

    return make


_TURN_RANDOM = TurnConfig(init_range=math.pi / 3, goal_range=math.pi / 3)

# id -> (factory, max_episode_steps, default kwargs)
ENVS: dict[str, tuple[Callable[..., HandEnv], int, dict[str, Any]]] = {
    "DClawTurnValve-v0": (_dclaw(TurnValve, TurnConfig()), 40, {}),
    "DClawTurnValveRandom-v0": (_dclaw(TurnValve, _TURN_RANDOM), 40, {}),
    "DClawTurnValveRandomDynamics-v0": (_dclaw(TurnValve, TurnConfig()), 40,
                                        {"randomize": DEFAULT_DR_EFFECTS}),
    "DClawTurnFoamValve-v0": (_dclaw(TurnValve, TurnConfig(), foam=True), 40, {}),
    "DClawScrew-v0": (_dclaw(Screw, ScrewConfig()), 80, {}),
    "DClawScrewRandom-v0": (_dclaw(Screw, ScrewConfig(speed=0.75, random=True)), 80, {}),
    "DClawFlipBlock-v0": (_dclaw(FlipBlock, FlipConfig()), 80, {}),
    "DClawFlipBlockQuaternion-v0": (_dclaw(FlipBlock, FlipConfig(representation="quaternion")),
                                    80, {}),
}


def add_env(name: str, factory: Callable[..., HandEnv], max_episode_steps: int,
            defaults: dict[str, Any] | None = None) -> None:
    """Add an id to ``ENVS`` (a user's own task; ``register_envs`` then registers it)."""
    ENVS[name] = (factory, max_episode_steps, defaults or {})


def register_envs() -> None:
    """Register every id in ``ENVS`` with gymnasium (idempotent)."""
    _load_optional_tasks()
    for name, (factory, steps, defaults) in ENVS.items():
        env_id = f"{NAMESPACE}/{name}"
        if env_id in gym.registry:
            continue
        gym.register(env_id, entry_point=factory, max_episode_steps=steps, kwargs=dict(defaults),
                     disable_env_checker=True)


def env_ids() -> list[str]:
    _load_optional_tasks()
    return [f"{NAMESPACE}/{name}" for name in ENVS]


def _load_optional_tasks() -> None:
    """Add the ids of the task modules in ``TASK_MODULES`` (each lists its own in ``ENVS``;
    imported on first use, e.g. the Allegro's)."""
    import importlib

    for module in TASK_MODULES:
        for name, entry in importlib.import_module(module).ENVS.items():
            ENVS.setdefault(name, entry)


TASK_MODULES: tuple[str, ...] = ("lowcostdex.sim.envs.allegro_tasks",)
