"""Gymnasium environments: tasks on hands, behind swappable backends (sim, emulated, hardware)."""

from lowcostdex.sim.envs.backend import BACKENDS, Backend, SimBackend, backend_class
from lowcostdex.sim.envs.hand_env import (
    HandEnv,
    action_to_goal,
    control_period,
    goal_to_action,
    make_hand_env,
)
from lowcostdex.sim.envs.task import Task, TaskSpec, wrap_angle

__all__ = ["BACKENDS", "Backend", "HandEnv", "SimBackend", "Task", "TaskSpec", "action_to_goal",
           "backend_class", "control_period", "goal_to_action", "make_hand_env", "wrap_angle"]
