"""Configurations of the NPG/DAPG stack: plain dataclasses, importable without torch.

Each algorithm module documents its algorithm and takes its config from here
(``PolicyConfig`` for :mod:`~lowcostdex.algos.policy`, ``BaselineConfig`` for
:mod:`~lowcostdex.algos.baseline`, ``NPGConfig``, ``DAPGConfig``, ``BCConfig``, and
``TrainConfig`` for a whole run of :mod:`~lowcostdex.algos.train`). They live apart from the
torch code so that the command line (``lowcostdex train npg|dapg``, whose defaults are these),
benchmarks and run configs can build and validate them without importing torch (~2.5 s). The
algorithm modules re-export their config, so ``from lowcostdex.algos.npg import NPGConfig``
works too.

Every config validates itself at construction and names the valid choices on error.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, fields
from typing import Any

from lowcostdex.algos.samplers import SAMPLERS
from lowcostdex.errors import (
    ConfigError,
    check_at_most,
    check_bool,
    check_choice,
    check_keys,
    check_number,
    check_sizes,
    keyword_hints,
)

ACTIVATIONS = ("tanh", "relu")
MAX_EPISODES = 10_000
"""Most trajectories per iteration / evaluation episodes a config accepts (mjrl's DAPG runs
use 200 per iteration)."""
MAX_WORKERS = 1024
"""Most sampler processes / simulator threads."""
MAX_BATCH_ENVS = 16_384
"""Most PPO copies stepped together (the bench uses 64)."""
MAX_LOG_STD = 3.0
"""Largest initial log std of the policy's exploration noise."""
MAX_STEP_SIZE = 100.0
"""Largest NPG step size delta [nats] (mjrl uses 0.05-0.2; the step's KL is about delta/2;
tests/test_train.py wrecks a clone on purpose with 20)."""


@keyword_hints
@dataclass(frozen=True)
class PolicyConfig:
    """Architecture and initialisation of :class:`~lowcostdex.algos.policy.GaussianMLPPolicy`.

    Attributes:
      hidden_sizes: widths of the hidden layers; ``()`` gives a linear policy. mjrl's default
        is (64, 64); the hand_dapg configs use (32, 32).
      activation: hidden-layer non-linearity, one of ACTIVATIONS.
      init_log_std: initial log standard deviation of the action noise (mjrl default 0,
        i.e. std 1 over a [-1, 1] action range; its example configs use -0.5).
      min_log_std: lower clamp of log_std applied after every update (mjrl: -3).
      last_layer_scale: factor applied to the last layer's initial weight and bias (mjrl: 1e-2).
      min_obs_std: floor of the observation standard deviation used for normalisation, so a
        feature that is constant in the data does not divide by ~0.
    """

    hidden_sizes: tuple[int, ...] = (64, 64)
    activation: str = "tanh"
    init_log_std: float = 0.0
    min_log_std: float = -3.0
    last_layer_scale: float = 1e-2
    min_obs_std: float = 1e-2

    def __post_init__(self) -> None:
        check_choice("activation", self.activation, ACTIVATIONS)
        check_sizes("hidden_sizes", self.hidden_sizes)
        check_number("min_log_std", self.min_log_std)
        check_number("init_log_std", self.init_log_std, low=self.min_log_std)  # >= min_log_std
        check_at_most("init_log_std", self.init_log_std, MAX_LOG_STD, "an exploration std of "
                      f"e^{MAX_LOG_STD:g} = {math.exp(MAX_LOG_STD):.0f} in actions bounded to "
                      "[-1, 1] (the default is 0: std 1)")
        check_number("last_layer_scale", self.last_layer_scale, 0, low_open=True)
        check_number("min_obs_std", self.min_obs_std, 0, low_open=True)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PolicyConfig:
        """Inverse of ``dataclasses.asdict`` (accepts lists read back from JSON)."""
        return cls(**_known(cls, d, tuples=("hidden_sizes",)))


@keyword_hints
@dataclass(frozen=True)
class BaselineConfig:
    """Value-function architecture and fit (:class:`~lowcostdex.algos.baseline.MLPBaseline`).

    Attributes:
      hidden_sizes: MLP hidden widths (mjrl: (128, 128)).
      activation: one of ACTIVATIONS (mjrl: relu).
      lr: Adam learning rate.
      weight_decay: Adam weight decay (mjrl's reg_coef, 1e-3 in its job scripts).
      epochs: passes over each batch per fit (hand_dapg configs: 2).
      batch_size: minibatch size.
    """

    hidden_sizes: tuple[int, ...] = (128, 128)
    activation: str = "relu"
    lr: float = 1e-3
    weight_decay: float = 1e-3
    epochs: int = 2
    batch_size: int = 64

    def __post_init__(self) -> None:
        check_choice("activation", self.activation, ACTIVATIONS)
        check_sizes("baseline hidden_sizes", self.hidden_sizes)
        check_number("baseline lr", self.lr, 0, low_open=True)
        check_number("baseline weight_decay", self.weight_decay, 0)
        check_number("baseline epochs", self.epochs, 1, integer=True)
        check_number("baseline batch_size", self.batch_size, 1, integer=True)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> BaselineConfig:
        return cls(**_known(cls, d, tuples=("hidden_sizes",)))


@keyword_hints
@dataclass(frozen=True)
class NPGConfig:
    """Natural-gradient step settings (:mod:`lowcostdex.algos.npg`; mjrl defaults unless noted).

    Attributes:
      step_size: delta, the normalised step size; the step's KL is about delta / 2.
        mjrl's class default is 0.01, the hand_dapg configs use 0.05.
      cg_iters: conjugate-gradient iterations (the truncation of truncated NPG).
      cg_residual_tol: CG stops early when r^T r falls below this.
      damping: added to F (F + damping I) in every Fisher-vector product.
      fvp_sample_frac: fraction of the samples used for the Fisher (drawn without replacement
        with the generator passed to the update); 1 uses all.
      normalize_advantages: whiten advantages over the batch before the gradient (mjrl does).
      max_kl: if set, backtrack the step until the measured mean KL <= max_kl; None keeps the
        plain NPG step (no check), as in mjrl's NPG.
      backtrack_ratio: step-length factor per backtracking trial, in (0, 1).
      max_backtracks: trials before the step is rejected (parameters restored).
    """

    step_size: float = 0.05
    cg_iters: int = 10
    cg_residual_tol: float = 1e-10
    damping: float = 1e-4
    fvp_sample_frac: float = 1.0
    normalize_advantages: bool = True
    max_kl: float | None = None
    backtrack_ratio: float = 0.8
    max_backtracks: int = 10

    def __post_init__(self) -> None:
        check_number("step_size", self.step_size, 0, low_open=True)
        check_at_most("step_size", self.step_size, MAX_STEP_SIZE, "a KL step of delta/2 nats "
                      "per iteration leaves no trust region (mjrl uses 0.05-0.2)")
        check_number("cg_iters", self.cg_iters, 1, integer=True)
        check_number("cg_residual_tol", self.cg_residual_tol, 0)
        check_number("damping", self.damping, 0)
        check_number("fvp_sample_frac", self.fvp_sample_frac, 0, 1, low_open=True)
        check_number("max_kl", self.max_kl, 0, low_open=True, none_ok=True)
        check_number("backtrack_ratio", self.backtrack_ratio, 0, 1, low_open=True,
                     high_open=True)
        check_number("max_backtracks", self.max_backtracks, 0, integer=True)
        check_bool("normalize_advantages", self.normalize_advantages)


DEMO_WEIGHTS = ("paper", "mjrl")


@keyword_hints
@dataclass(frozen=True)
class DAPGConfig:
    """DAPG settings (:mod:`lowcostdex.algos.dapg`).

    The natural-gradient step settings are an :class:`NPGConfig` passed
    next to this one (the same object NPG uses).

    Attributes:
      lam0: initial demo weight factor (paper: 0.1; hand_dapg's mjrl config: 0.01).
      lam1: per-iteration decay of the demo weight, in [0, 1] (both: 0.95).
      demo_weight: one of DEMO_WEIGHTS, see :mod:`lowcostdex.algos.dapg`.
    """

    lam0: float = 0.1
    lam1: float = 0.95
    demo_weight: str = "paper"

    def __post_init__(self) -> None:
        check_choice("DAPG demo weight", self.demo_weight, DEMO_WEIGHTS)
        check_number("lam0", self.lam0, 0)
        check_number("lam1", self.lam1, 0, 1)


BC_LOSSES = ("mse", "mle")
BC_LOG_STD = ("demo_spread", "residual", "keep")


@keyword_hints
@dataclass(frozen=True)
class BCConfig:
    """Behaviour-cloning settings (:mod:`lowcostdex.algos.bc`; hand_dapg: 5 epochs, batch 32,
    lr 1e-3, MSE).

    Attributes:
      epochs: passes over the demonstration transitions.
      batch_size: minibatch size.
      lr: Adam learning rate.
      loss: one of BC_LOSSES.
      set_obs_normalization: set the observation statistics from the demos.
      freeze_obs_normalization: keep them fixed afterwards (mjrl); False lets RL batches
        update them (the policy mean is preserved at each update).
      set_action_scaling: set act_shift/act_scale from the demo actions.
      log_std: initial exploration noise, one of BC_LOG_STD (see :mod:`lowcostdex.algos.bc`); mjrl
        uses "demo_spread". With loss "mle" the noise is trained and this sets its start.
      min_action_scale: floor of act_scale per action dimension.
    """

    epochs: int = 5
    batch_size: int = 32
    lr: float = 1e-3
    loss: str = "mse"
    set_obs_normalization: bool = True
    freeze_obs_normalization: bool = True
    set_action_scaling: bool = True
    log_std: str = "demo_spread"
    min_action_scale: float = 0.1

    def __post_init__(self) -> None:
        check_choice("BC loss", self.loss, BC_LOSSES)
        check_choice("BC log_std", self.log_std, BC_LOG_STD)
        check_number("BC epochs", self.epochs, 0, integer=True)
        check_number("BC batch_size", self.batch_size, 1, integer=True)
        check_number("BC lr", self.lr, 0, low_open=True)
        check_number("BC min_action_scale", self.min_action_scale, 0, low_open=True)
        for name in ("set_obs_normalization", "freeze_obs_normalization", "set_action_scaling"):
            check_bool(f"BC {name}", getattr(self, name))


ALGOS = ("npg", "dapg")
BACKENDS = ("sim", "emulated", "hardware")
OBS_NORMS = ("running", "frozen")
SUCCESS_MODES = ("final", "any")


@keyword_hints
@dataclass(frozen=True)
class TrainConfig:
    """One NPG or DAPG run (:func:`lowcostdex.algos.train.train`).

    Attributes:
      algo: one of ALGOS.
      env_id: registered gymnasium id, e.g. "lowcostdex/DClawTurnValve-v0".
      backend: one of BACKENDS; "emulated" and "hardware" sample serially on one robot.
      env_kwargs: extra ``gym.make`` keyword arguments (e.g. ``{"port": "/dev/ttyUSB0"}``).
      seed: the run's seed; every random draw derives from it.
      n_iter: number of iterations.
      n_traj: trajectories per iteration (hand_dapg: 200 of 200 steps).
      gamma: discount (mjrl/hand_dapg: 0.995).
      gae_lambda: GAE lambda (mjrl/hand_dapg: 0.97).
      bootstrap_truncated: bootstrap time-limit truncations with V(s_T) (mjrl does).
      sampler: one of SAMPLERS ("serial" on emulated/hardware backends).
      n_workers: workers of the process/ray samplers, envs of the vector sampler.
      obs_norm: "running" (update from each batch unless frozen, e.g. by BC) or "frozen".
      success: trajectory success from ``info["success"]``: at the final step or at any step.
      eval_every: evaluation period [iterations]; 0 evaluates only after the last iteration.
      eval_episodes: deterministic evaluation episodes per evaluation.
      eval_dense_from: from this iteration index on, evaluate after every iteration (besides
        every ``eval_every``); None: only every ``eval_every``. The run's policy is the best
        evaluated one, so late iterates, which differ by several successes in 100 episodes from
        one iteration to the next, all compete (bench/RESULTS.md, "The main job's DAPG
        validated at every late iterate").
      eval_env_kwargs: the evaluations' own ``gym.make`` keyword arguments (instead of
        ``env_kwargs``; ``backend`` "sim" only): the policy is chosen in another simulation
        than the one it trains in, e.g. one with the robot's identified effects
        (``lowcostdex.main_job.gapsim``); the clone's evaluation (``eval_bc``) runs there too.
        None: the training env.
      checkpoint_every: checkpoint period [iterations] (the last iteration always saves).
      demos: demonstration dataset (:mod:`lowcostdex.demonstrations.file`; its successful episodes are
        used), required for DAPG; for NPG, ``bc_init`` uses it.
      n_demos: use only the first n demo episodes (None: all).
      bc_init: behaviour-clone before RL (always on for DAPG; NPG + BC is "BCRL").
      eval_bc: evaluate the behaviour clone (``eval_episodes`` deterministic episodes) before
        the first iteration, into ``bc.json`` (``eval_success_rate``, ``eval_return_mean``,
        ``eval_final_goal_errors``: each episode's ``|info["goal_error"]|`` after its last step,
        when the env reports one); its robot time counts. The clone then competes for the
        run's policy as iteration -1 (``BestPolicy``): RL's iterates replace it only by beating
        it in their evaluations. Every run with demonstrations saves the clone
        (``bc_policy.pt``).
      bc_seed: the behaviour clone's seed (its network initialisation and minibatch order);
        None: ``seed``. From the same demonstrations the clone's seed alone moved the main
        job's clone from 1 to 16 of 40 held-out robot episodes at the same BC loss
        (bench/RESULTS.md, "Main job leftovers"), so a caller may fit several clones and start
        from the one that validates best (``lowcostdex.main_job``).
      eval_paired: every evaluation runs the same episodes (reset seeds of the evaluation
        stream's iteration 0), the clone's too with ``eval_bc``, so the run's policy is chosen
        by paired comparisons: two candidates differ by their policies, not by which episodes
        they drew. False (the default) draws new episodes for each evaluation (the evaluation
        stream at that iteration; the clone's from ``samplers.BC_EVAL_STREAM``), which tracks
        the learning curve over more distinct episodes but adds the episode draw's noise to
        the choice (with 20 episodes, several successes: bench/RESULTS.md, "The RL stage in
        the main job").
      policy, baseline, npg, dapg, bc: component configs. Defaults: the hand_dapg policy
        (32, 32) with init log-std -1.0 (std 0.37; hand_dapg: -0.5); the NPG step delta 0.1
        with damping 1e-2 rather than mjrl's 0.05 / 1e-4: on DClawTurnValve-v0 with 40
        trajectories per iteration, 0.05 / 1e-4 had no successful episode after 100
        iterations while 0.1 / 1e-2 reached 80 % training success in ~140 (bench/RESULTS.md);
        1e-4 damping also let single steps reach KL ~1 on small batches (second-order model
        off). Init log-std -1.0 because a fixed-KL step moves the mean by about
        std * sqrt(2 KL) per iteration: with std 0.6 the deterministic policy on the valve
        jumped across the success threshold between iterations (76-83 % of evaluations in
        iterations 150-250 succeeded, 3 seeds) and the training success stalled at 0.7; with
        std 0.37, 90-99 % and 0.88-0.96, reaching 80 % training success in 1.8x fewer samples
        (bench/RESULTS.md, "Learning that holds"). BC: 100 epochs (hand_dapg's 5 are ~1000
        Adam steps on 25 long demos; 5 epochs over 10 short ones are ~125) and the exploration
        noise from the clone's residual (mjrl: the demo actions' spread, std 0.3 on the flip,
        which fails a policy whose mean solves it): on the flip from 10 demos the mjrl settings
        reached 0-4 % training success in 120k samples, these 14-46 %; on the valve they need
        3.4x fewer samples to 80 % (bench/RESULTS.md).
      torch_threads: torch intra-op threads during training. The networks are small, so one
        thread is fastest (two threads on a busy 2-core machine measured ~70x slower per
        Fisher-vector product).
      progress: show a progress bar.
    """

    algo: str = "npg"
    env_id: str = "lowcostdex/DClawTurnValve-v0"
    backend: str = "sim"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    n_iter: int = 100
    n_traj: int = 50
    gamma: float = 0.995
    gae_lambda: float = 0.97
    bootstrap_truncated: bool = True
    sampler: str = "serial"
    n_workers: int = 1
    obs_norm: str = "running"
    success: str = "final"
    eval_every: int = 5
    eval_episodes: int = 10
    eval_dense_from: int | None = None
    eval_env_kwargs: dict[str, Any] | None = None
    checkpoint_every: int = 1
    demos: str | None = None
    n_demos: int | None = None
    bc_init: bool = False
    eval_bc: bool = False
    eval_paired: bool = False
    bc_seed: int | None = None
    policy: PolicyConfig = field(
        default_factory=lambda: PolicyConfig(hidden_sizes=(32, 32), init_log_std=-1.0)
    )
    baseline: BaselineConfig = field(default_factory=BaselineConfig)
    npg: NPGConfig = field(default_factory=lambda: NPGConfig(step_size=0.1, damping=1e-2))
    dapg: DAPGConfig = field(default_factory=DAPGConfig)
    bc: BCConfig = field(default_factory=lambda: BCConfig(epochs=100, log_std="residual"))
    torch_threads: int = 1
    progress: bool = True

    def __post_init__(self) -> None:
        check_choice("algorithm", self.algo, ALGOS)
        check_choice("backend", self.backend, BACKENDS)
        check_choice("sampler", self.sampler, SAMPLERS)
        check_choice("observation normalisation", self.obs_norm, OBS_NORMS)
        check_choice("success mode", self.success, SUCCESS_MODES)
        if self.backend != "sim" and self.sampler != "serial":
            raise ConfigError(
                f"backend {self.backend!r} runs one robot: use sampler 'serial', not {self.sampler!r}"
            )
        if self.algo == "dapg" and not self.demos:
            raise ConfigError("DAPG needs demonstrations: set demos (--demos PATH)")
        if self.bc_init and not self.demos:
            raise ConfigError("bc_init needs demonstrations: set demos (--demos PATH)")
        if self.eval_bc and not self.uses_demos:
            raise ConfigError("eval_bc needs a behaviour clone: algo 'dapg' or bc_init")
        for name in ("n_iter", "n_traj", "n_workers", "eval_episodes", "checkpoint_every",
                     "torch_threads"):
            check_number(name, getattr(self, name), 1, integer=True)
        check_number("seed", self.seed, 0, integer=True)
        check_number("eval_every", self.eval_every, 0, integer=True)
        check_number("eval_dense_from", self.eval_dense_from, 0, integer=True, none_ok=True)
        check_number("n_demos", self.n_demos, 1, integer=True, none_ok=True)
        check_number("bc_seed", self.bc_seed, 0, integer=True, none_ok=True)
        for name, cap, what in (("n_traj", MAX_EPISODES, "trajectories per iteration"),
                                ("eval_episodes", MAX_EPISODES, "evaluation episodes")):
            check_at_most(name, getattr(self, name), cap, f"more {what} than a run needs; "
                          "their samples are held in memory at once")
        check_at_most("n_workers", self.n_workers, MAX_WORKERS, "one process each, each with "
                      "its own simulator and policy")
        check_number("gamma", self.gamma, 0, 1)
        check_number("gae_lambda", self.gae_lambda, 0, 1)
        for name in ("bootstrap_truncated", "bc_init", "eval_bc", "eval_paired", "progress"):
            check_bool(name, getattr(self, name))
        _check_env(self.env_id, self.env_kwargs)
        if self.eval_env_kwargs is not None:
            _check_env(self.env_id, self.eval_env_kwargs, backend_field=False)  # said below
            if self.backend != "sim" or "backend" in self.eval_env_kwargs:
                raise ConfigError(f"eval_env_kwargs: evaluations in their own env need backend "
                                  f"'sim' (not {self.backend!r}) and take no 'backend' key")
        if self.demos is not None and not isinstance(self.demos, (str, os.PathLike)):
            raise ConfigError(f"demos={self.demos!r:.80} must be the path of a demonstration "
                              "file (.h5) or None")
        for name, cls in (("policy", PolicyConfig), ("baseline", BaselineConfig),
                          ("npg", NPGConfig), ("dapg", DAPGConfig), ("bc", BCConfig)):
            _check_part(name, getattr(self, name), cls)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """Inverse of ``dataclasses.asdict`` (e.g. a run's config.json)."""
        d = _known(cls, d)
        nested = {
            "policy": PolicyConfig.from_dict,
            "baseline": BaselineConfig.from_dict,
            "npg": lambda x: NPGConfig(**_known(NPGConfig, x)),
            "dapg": lambda x: DAPGConfig(**_known(DAPGConfig, x)),
            "bc": lambda x: BCConfig(**_known(BCConfig, x)),
        }
        for key, build in nested.items():
            if key in d and isinstance(d[key], dict):
                d[key] = build(d[key])
        return cls(**d)

    @property
    def uses_demos(self) -> bool:
        return self.algo == "dapg" or self.bc_init


@keyword_hints
@dataclass(frozen=True)
class PPOConfig:
    """One PPO run (:func:`lowcostdex.algos.ppo.train`) on the batched simulator.

    Defaults are cleanrl's ``ppo_continuous_action`` unless noted.

    Attributes:
      env_id: registered ``lowcostdex/...`` id (sim backend; batched by ``mujoco.batch``).
      env_kwargs: extra ``gym.make`` keyword arguments of the task.
      seed: the run's seed; every random draw derives from it.
      n_iter: iterations; each runs ``num_envs`` whole episodes.
      num_envs: copies stepped together (episodes per iteration).
      gamma, gae_lambda: discount and GAE lambda.
      lr: Adam learning rate (eps 1e-5); ``anneal_lr`` decays it linearly to 0 over n_iter.
        1e-3, not cleanrl's 3e-4 (tuned for 1M-step locomotion with 64-sample minibatches): on
        the D'Claw valve (40-step episodes, 160-sample minibatches), seeds 0-2, 1e-3 reached 80 %
        training success in 141-166k samples where 3e-4 took 333-387k (seeds 1-2) and NPG
        332-384k; 3e-3 was slower (clip fraction 0.8), as were 64 envs at 1e-3
        (bench/RESULTS.md, flip8's section, session 15).
      update_epochs: passes over each iteration's samples.
      num_minibatches: minibatches per pass.
      clip_coef: the ratio clip epsilon (also clips the value change when ``clip_vloss``).
      ent_coef, vf_coef: entropy bonus and value-loss weights.
      max_grad_norm: global gradient-norm clip.
      target_kl: stop an update's epochs once the approximate KL exceeds it (None: never).
      norm_adv: normalise advantages per minibatch.
      reward_norm: scale rewards by a running std of the discounted return.
      policy: the actor (a GaussianMLPPolicy); init log-std -1.0 (std 0.37), not cleanrl's 0:
        the D'Claw's actions are joint targets, and NPG on the valve measured that a noise of
        std 0.6 keeps the mean from settling (bench/RESULTS.md, "Learning that holds").
      critic_hidden: critic MLP widths.
      eval_every: evaluation period [iterations] (0: only after the last).
      eval_episodes: mean-action episodes per evaluation (a batched env of that many copies).
      checkpoint_every: checkpoint period [iterations].
      nthread: ``mujoco.batch`` threads (0: all CPUs).
      torch_threads: torch intra-op threads.
      progress: show a progress bar.
    """

    env_id: str = "lowcostdex/DClawTurnValve-v0"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    n_iter: int = 200
    num_envs: int = 32
    gamma: float = 0.99
    gae_lambda: float = 0.95
    lr: float = 1e-3
    anneal_lr: bool = True
    update_epochs: int = 10
    num_minibatches: int = 8
    clip_coef: float = 0.2
    clip_vloss: bool = True
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float | None = None
    norm_adv: bool = True
    reward_norm: bool = True
    policy: PolicyConfig = field(
        default_factory=lambda: PolicyConfig(hidden_sizes=(64, 64), init_log_std=-1.0))
    critic_hidden: tuple[int, ...] = (64, 64)
    eval_every: int = 5
    eval_episodes: int = 10
    checkpoint_every: int = 1
    nthread: int = 0
    torch_threads: int = 1
    progress: bool = True

    def __post_init__(self) -> None:
        for name in ("n_iter", "num_envs", "update_epochs", "num_minibatches", "eval_episodes",
                     "checkpoint_every", "torch_threads"):
            check_number(name, getattr(self, name), 1, integer=True)
        for name in ("seed", "eval_every", "nthread"):
            check_number(name, getattr(self, name), 0, integer=True)
        check_at_most("num_envs", self.num_envs, MAX_BATCH_ENVS, "every copy's simulator state "
                      "and rollout are held in memory at once")
        check_at_most("eval_episodes", self.eval_episodes, MAX_EPISODES, "more evaluation "
                      "episodes than a run needs")
        check_at_most("nthread", self.nthread, MAX_WORKERS, "more threads than any machine's "
                      "CPUs (0: all of them)")
        check_number("gamma", self.gamma, 0, 1, low_open=True)
        check_number("gae_lambda", self.gae_lambda, 0, 1)
        for name in ("lr", "clip_coef", "max_grad_norm"):
            check_number(name, getattr(self, name), 0, low_open=True)
        check_at_most("lr", self.lr, 1.0, "Adam moves every weight by about lr per update; at "
                      "1e9 the first update made the policy's actions NaN")
        check_number("ent_coef", self.ent_coef, 0)
        check_number("vf_coef", self.vf_coef, 0)
        check_number("target_kl", self.target_kl, 0, low_open=True, none_ok=True)
        check_sizes("critic_hidden", self.critic_hidden)
        for name in ("anneal_lr", "clip_vloss", "norm_adv", "reward_norm", "progress"):
            check_bool(name, getattr(self, name))
        _check_env(self.env_id, self.env_kwargs, backend_field=False)  # make_vec: sim only
        _check_part("policy", self.policy, PolicyConfig)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PPOConfig:
        """Inverse of ``dataclasses.asdict`` (e.g. a run's config.json)."""
        d = _known(cls, d, tuples=("critic_hidden",))
        if isinstance(d.get("policy"), dict):
            d["policy"] = PolicyConfig.from_dict(d["policy"])
        return cls(**d)


def _known(cls: type, d: Any, tuples: tuple[str, ...] = ()) -> dict[str, Any]:
    """A copy of ``d`` (a config read from JSON) after checking that it is a dict whose keys are
    fields of ``cls``: an unknown (misspelt) key is refused, listing the valid ones, instead of
    a TypeError from the constructor. The fields named in ``tuples`` (layer widths) come back
    from JSON as lists and are turned into tuples again."""
    if not isinstance(d, dict):
        raise ConfigError(f"{cls.__name__} settings must be a dict, got {d!r:.80}")
    check_keys(f"{cls.__name__} setting", d, [f.name for f in fields(cls)])
    d = dict(d)
    for name in tuples:
        if isinstance(d.get(name), list):
            d[name] = tuple(d[name])
    return d


def _check_env(env_id: object, env_kwargs: object, backend_field: bool = True) -> None:
    if not isinstance(env_id, str) or not env_id:
        raise ConfigError(f"env_id={env_id!r} must be a gymnasium id such as "
                          "'lowcostdex/DClawTurnValve-v0' (`lowcostdex envs` lists them)")
    check_env_kwargs(env_kwargs, backend_field)


def check_env_kwargs(env_kwargs: object, backend_field: bool = True) -> None:
    """A training config's ``env_kwargs``: a dict of ``gym.make`` keywords; with
    ``backend_field`` (the config has its own ``backend``), not ``backend``: written there as
    for ``gym.make`` (``{"backend": "emulated"}``), it trained on the emulated robot while the
    run said 'sim'."""
    if not isinstance(env_kwargs, dict) or not all(isinstance(k, str) for k in env_kwargs):
        raise ConfigError(f"env_kwargs={env_kwargs!r:.80} must be a dict of gym.make keyword "
                          "arguments, e.g. {'port': '/dev/ttyUSB0'}")
    if backend_field and "backend" in env_kwargs:
        raise ConfigError(f"env_kwargs holds 'backend': {env_kwargs['backend']!r:.40}; the "
                          "backend is the config's own field (it decides how samples are "
                          f"drawn and counted): give backend={env_kwargs['backend']!r:.40} and "
                          "leave it out of env_kwargs")


def _check_part(name: str, value: object, cls: type) -> None:
    if not isinstance(value, cls):
        raise ConfigError(f"{name}={value!r:.80} must be a {cls.__name__} (or, in from_dict, a "
                          "dict of its settings)")
