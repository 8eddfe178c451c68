"""Sim subcommands: ``lowcostdex envs`` lists the registered environments."""

from __future__ import annotations

import argparse


def add_commands(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("envs", help="list the registered gymnasium environments")
    p.set_defaults(func=_list_envs)


def _list_envs(args: argparse.Namespace) -> int:
    import gymnasium as gym

    import lowcostdex  # noqa: F401  (registers the ids)
    from lowcostdex.sim.registry import env_ids

    for env_id in env_ids():
        spec = gym.spec(env_id)
        print(f"{env_id:45s} max_episode_steps={spec.max_episode_steps}")
    return 0
