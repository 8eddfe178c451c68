"""The TVLG trainer's settings (``TVLGTrainConfig``) and its task cost's (``TaskCostConfig``),
validated at construction."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos.configs import check_env_kwargs
from lowcostdex.algos.local_models.costs import RAMP_KINDS
from lowcostdex.algos.local_models.dynamics import DynamicsConfig
from lowcostdex.algos.local_models.traj_opt import TrajOptConfig
from lowcostdex.algos.local_models.tvlg import TVLGConfig
from lowcostdex.errors import (
    ConfigError,
    check_at_most,
    check_bool,
    check_choice,
    check_fields,
    check_keys,
    check_number,
    keyword_hints,
)

Array = NDArray[np.float64]
BACKENDS = ("sim", "emulated", "hardware")
INITS = ("pd", "demos", "teacher")
SUCCESS_MODES = ("final", "any")
HAND_REFERENCES = ("start", "demo")
COST_PRESETS = ("task", "tracking")
TRACKING_KL_STEP = 0.5
"""KL step the CLI uses with ``--cost tracking`` (bench/RESULTS.md measured it at 0.5)."""
MAX_ROLLOUTS = 1000
"""Most episodes per iteration (and teacher / noisy evaluation episodes)."""
MUTABLE_ON_RESUME = ("n_iter", "progress")
"""Config keys a resumed run may change."""


@keyword_hints
@dataclass(frozen=True)
class TaskCostConfig:
    """Quadratic cost of a goal-angle task (valve turning, screw), in state units.

    Two presets (``preset``): ``task()`` (the defaults) pulls the object angle to the goal at every
    step and keeps the hand near its start pose; ``tracking()`` keeps the hand joints near the
    demonstrated joint targets and pays for the object angle only over the last ``final_steps``
    steps (bench/RESULTS.md: from the PD-hold start the task cost has no gradient before contact,
    and around a demonstration it pulls the valve ahead of the demonstrated gait at every step).

    Attributes:
      object_weight: weight of the squared object-angle error [1/rad^2].
      object_l1: weight of a smooth |error| term on the object angle (keeps pulling near the goal).
      pose_weight: squared deviation of the hand joints from their reference [1/rad^2].
      velocity_weight: squared hand and object joint velocities [s^2/rad^2].
      action_weight: squared deviation of the normalised action from the one holding the start
        pose.
      final_multiplier: extra weight of the final step's state terms.
      ramp: growth of the object term over the episode, one of RAMP_KINDS.
      final_steps: steps at the end weighted by the ``final_only`` ramp (reach the goal and hold
        it).
      hand_reference: the hand joints' reference, one of HAND_REFERENCES: "start" (the start
        pose) or "demo" (the joint targets of the demonstration the controller starts from; needs
        init "teacher" or "demos").
    """

    object_weight: float = 1.0
    object_l1: float = 0.0
    pose_weight: float = 0.01
    velocity_weight: float = 1e-3
    action_weight: float = 1e-3
    final_multiplier: float = 10.0
    ramp: str = "constant"
    final_steps: int = 1
    hand_reference: str = "start"

    def __post_init__(self) -> None:
        check_fields(self)  # types, NaN and inf first
        check_choice("ramp", self.ramp, RAMP_KINDS)
        check_choice("hand reference", self.hand_reference, HAND_REFERENCES)
        for name in (
            "object_weight",
            "object_l1",
            "pose_weight",
            "velocity_weight",
            "action_weight",
        ):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name}={getattr(self, name)} must be >= 0")
        if self.final_multiplier <= 0:
            raise ConfigError(f"final_multiplier={self.final_multiplier} must be > 0")
        if self.final_steps < 1:
            raise ConfigError(f"final_steps={self.final_steps} must be >= 1")

    @classmethod
    def task(cls) -> TaskCostConfig:
        """The goal at every step, the hand near its start pose (the defaults)."""
        return cls()

    @classmethod
    def tracking(cls) -> TaskCostConfig:
        """Hand joints near the demonstrated joint targets (weight 0.1 / rad^2), the object at
        the goal over the last 5 steps (weight 10 / rad^2): the configuration measured in
        bench/RESULTS.md."""
        return cls(
            object_weight=10.0, pose_weight=0.1, final_multiplier=1.0, ramp="final_only",
            final_steps=5, hand_reference="demo",
        )  # fmt: skip

    @classmethod
    def preset(cls, name: str) -> TaskCostConfig:
        """One of COST_PRESETS by name."""
        check_choice("cost preset", name, COST_PRESETS)
        return getattr(cls, name)()


@keyword_hints
@dataclass(frozen=True)
class TVLGTrainConfig:
    """One learned-local-model run on a fixed start state.

    Attributes:
      env_id: registered gymnasium id with a goal angle (valve and screw tasks).
      backend: one of BACKENDS.
      env_kwargs: extra ``gym.make`` keyword arguments (e.g. ``{"port": "/dev/ttyUSB0"}``).
      seed: the run's seed; every random draw derives from it.
      n_iter: iterations.
      n_rollouts: episodes per iteration (5 in Kumar et al. 2016 and the GPS examples).
      include_last_action: append the last applied action to the state.
      start_hand_qpos: hand joint angles [rad, action order] of the fixed start instead of the
        task's reset pose (e.g. fingertips already behind the valve's spokes); None: the task's.
      init: initial controller, one of INITS: "pd" holds the start pose (plus ``pd_gain``
        feedback) with exploration noise; "demos" replays the mean action of the demonstrations
        in ``demos`` (the DAPG demo format) with the same noise; "teacher" first runs the
        scripted teacher (``lowcostdex.teachers.valve``) ``teacher_episodes`` times from the fixed
        start (saved as ``teacher_demo.h5``) and replays its mean action like "demos".
      teacher_episodes: teacher episodes for init "teacher" (logged as ``teacher_episodes``,
        counted in robot time, not in ``rollouts``).
      demos: demonstration dataset (HDF5, :mod:`lowcostdex.demonstrations.file`).
      init_noise: std of the initial controller's exploration noise [normalised action].
      pd_gain: position feedback of the initial controller [normalised action / rad].
      smooth_noise: Gaussian smoothing of the exploration noise over time [steps]; 0 = white.
      success: episode success from ``info["success"]`` at the final step or at any step.
      eval_every: noise-free evaluation episode every this many iterations (0: last only).
      eval_noisy_episodes: held-out episodes of the controller with its exploration noise at
        every evaluation (not used for learning; counted in robot time, not in ``rollouts``);
        logged as ``eval_noisy_success_rate``.
      solve_rate: an evaluated iteration is ``solved`` when its noise-free episode succeeds and,
        if ``eval_noisy_episodes`` > 0, at least this fraction of the noisy ones do.
      checkpoint_every: checkpoint period [iterations] (the last iteration always saves).
      cost: the task cost.
      algo: the optimiser (dynamics fit, KL trust region).
      progress: show a progress bar.
    """

    env_id: str = "lowcostdex/DClawTurnValve-v0"
    backend: str = "sim"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    n_iter: int = 12
    n_rollouts: int = 5
    include_last_action: bool = True
    start_hand_qpos: tuple[float, ...] | None = None
    init: str = "pd"
    demos: str | None = None
    teacher_episodes: int = 1
    init_noise: float = 0.3
    pd_gain: float = 0.0
    smooth_noise: float = 0.0
    success: str = "final"
    eval_every: int = 1
    eval_noisy_episodes: int = 0
    solve_rate: float = 0.8
    checkpoint_every: int = 1
    cost: TaskCostConfig = field(default_factory=TaskCostConfig)
    algo: TVLGConfig = field(default_factory=TVLGConfig)
    progress: bool = True

    def __post_init__(self) -> None:
        for name in ("include_last_action", "progress"):  # its numbers are checked below
            check_bool(name, getattr(self, name))
        check_choice("backend", self.backend, BACKENDS)
        check_env_kwargs(self.env_kwargs)
        check_choice("initial controller", self.init, INITS)
        check_choice("success mode", self.success, SUCCESS_MODES)
        if self.init == "demos" and not self.demos:
            raise ConfigError("init 'demos' needs a demonstration file (--demos PATH)")
        for name in ("n_iter", "n_rollouts", "checkpoint_every", "teacher_episodes"):
            check_number(name, getattr(self, name), 1, integer=True)
        for name in ("eval_every", "eval_noisy_episodes", "seed"):
            check_number(name, getattr(self, name), 0, integer=True)
        for name in ("n_rollouts", "teacher_episodes", "eval_noisy_episodes"):
            check_at_most(name, getattr(self, name), MAX_ROLLOUTS, "episodes per iteration are "
                          "held in memory at once (Kumar et al. 2016 use 5)")
        check_number("solve_rate", self.solve_rate, 0, 1, low_open=True)
        check_number("init_noise", self.init_noise, 0, low_open=True)
        check_number("smooth_noise", self.smooth_noise, 0)
        check_at_most("smooth_noise", self.smooth_noise, 1000.0, "steps of smoothing wider than "
                      "any episode; its Gaussian kernel (8 x smooth_noise + 1 taps) is held in "
                      "memory (1e9 asked for 60 GB)")
        check_number("pd_gain", self.pd_gain, 0)
        if self.cost.hand_reference == "demo" and self.init not in ("teacher", "demos"):
            raise ConfigError(
                "cost hand_reference 'demo' (--cost tracking) needs a demonstration: "
                "init 'teacher' or 'demos'"
            )

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> TVLGTrainConfig:
        """Inverse of ``dataclasses.asdict`` (e.g. a run's config.json). A misspelt key, at any
        level, is refused listing the valid ones (not a TypeError from a constructor)."""
        d = _known(cls, d)
        if d.get("start_hand_qpos") is not None:
            d["start_hand_qpos"] = tuple(d["start_hand_qpos"])
        if isinstance(d.get("cost"), Mapping):
            d["cost"] = TaskCostConfig(**_known(TaskCostConfig, d["cost"]))
        if isinstance(d.get("algo"), Mapping):
            a = _known(TVLGConfig, d["algo"])
            a["dynamics"] = DynamicsConfig(**_known(DynamicsConfig, a.get("dynamics", {})))
            a["traj_opt"] = TrajOptConfig(**_known(TrajOptConfig, a.get("traj_opt", {})))
            d["algo"] = TVLGConfig(**a)
        return cls(**d)


def _known(cls: type, d: Any) -> dict[str, Any]:
    """A copy of the mapping ``d`` whose keys are all fields of the dataclass ``cls``."""
    import dataclasses

    if not isinstance(d, Mapping):
        raise ConfigError(f"{cls.__name__} settings must be a dict, got {d!r:.80}")
    check_keys(f"{cls.__name__} setting", d, [f.name for f in dataclasses.fields(cls)])
    return dict(d)
