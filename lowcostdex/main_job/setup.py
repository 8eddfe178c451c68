"""The main job's tasks, budgets and the context every stage sees."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lowcostdex.errors import ConfigError, keyword_hints


@dataclass(frozen=True)
class TaskSetup:
    """What differs between the main job's tasks.

    Attributes:
      env_id: the registered task.
      teacher: class name of the scripted solver the virtual teacher follows.
      station: the D'Claw station (``valve`` has the valve motor, ``block`` does not).
      did: what a successful episode did ("turned the valve").
      title: plot titles.
      playbacks: noisy playbacks of each successful demonstration (see
        ``lowcostdex.demonstrations.kinesthetic``); 0 for the flip, whose open-loop playbacks fail (the block
        outcome is too sensitive to the finger motion: bench/RESULTS.md).
      demo_tries: the demos stage records until ``Budget.demos`` demonstrations succeeded, at
        most this many times as many episodes (a person also throws failed ones away).
      env_overrides: task-configuration values passed to ``gym.make`` with the env id (e.g.
        ``TurnConfig.goal_range``), for every stage that makes the env.
    """

    env_id: str
    teacher: str
    station: str
    did: str
    title: str
    playbacks: int
    demo_tries: int
    env_overrides: dict[str, Any] = field(default_factory=dict)


TARGET_RANGE = 0.5
"""Half-width [rad] of the ``valve-target`` task's goal around 180 deg (+-29 deg). The main job's
default: the fixed valve start and its 20 demonstrations leave the clone short of the task
(bench/RESULTS.md, "Does the RL stage add anything in the main job?"), where the fixed 180 deg
goal makes every evaluation episode the same one and the clone already solves it, and random
start angles (``valve-random``) leave the clone at 0/20."""
DEFAULT_TASK = "valve-target"
TASKS = {
    "valve": TaskSetup("lowcostdex/DClawTurnValve-v0", "ValveTurnTeacher", "valve",
                       "turned the valve", "Valve turning", 2, 1),
    "valve-target": TaskSetup("lowcostdex/DClawTurnValve-v0", "ValveTurnTeacher", "valve",
                              "turned the valve to its target",
                              "Valve turning (random target)", 2, 1,
                              env_overrides={"goal_range": TARGET_RANGE}),
    "valve-random": TaskSetup("lowcostdex/DClawTurnValveRandom-v0", "ValveTurnTeacher",
                              "valve", "turned the valve to its random target",
                              "Valve turning (random start and target)", 2, 1),
    "flip": TaskSetup("lowcostdex/DClawFlipBlock-v0", "PinchFlipTeacher", "block",
                      "flipped the block", "Block flipping", 0, 3),
}
ENV_ID = TASKS["valve"].env_id
GAP_JOINTS = ("ff_top", "ff_middle", "ff_bottom")
GAP_RATE = 50.0
"""Control rate of the identification logs [Hz]."""
SIZES = ("smoke", "default", "long")


def robot_effects(joints: tuple[str, ...]) -> list[Any]:
    """The emulated robot's "reality": servo effects the nominal simulation does not model.

    12 ms command latency (USB latency timer plus bus), 1 deg of gear/horn backlash and 0.05 N m
    of extra dry friction per joint: magnitudes inside the plausible D'Claw ranges of
    ../shared/reference/04-sysid.md section 6.
    """
    from lowcostdex.hardware.robot.backend import default_effects

    return default_effects(joints, latency=0.012, backlash=math.radians(1.0), friction=0.05)


DAPG_RANDOMIZE = ("coulomb_friction", "viscous_damping", "gain_error", "latency", "backlash",
                  "inertia_error", "mass_error", "observation_noise", "action_noise")
"""Effects the main job's simulation randomizes while DAPG trains in it (every effect of the
catalogue's default domain randomization, ``sim.effects.randomization.DEFAULT_DR_EFFECTS``, at
its catalogue range, each episode; tests/test_main_job_report.py checks they are the same)."""


@keyword_hints
@dataclass(frozen=True)
class SimTraining:
    """DAPG's budget when it trains in simulation (MuJoCo, the task's model, with domain
    randomization over ``randomize``) instead of on the robot.

    Why: the emulated robot gives 68 samples/s, the simulation 1230 (773 with the
    randomization), so the simulation affords 5x the robot's samples in less wall-clock; on the
    robot 12 x 20 episodes added nothing measurable over the clone (46 vs 50 of 120 held-out,
    3 seeds). Trained in the randomized simulation for 30 x 40 episodes and validated there on
    100 episodes, DAPG's policy solved more of the robot's 40 held-out episodes than its clone
    on each of seeds 0-2 (15 -> 21, 16 -> 24, 0 -> 10; pooled 31 -> 55 of 120, 31 vs 7
    episodes solved by one only; bench/RESULTS.md, "DAPG trained in simulation, judged on the
    robot"). The plain simulation did not transfer (seed 0: 15 -> 15), and longer runs did not
    climb further (validation peaks at iterations 19-29).

    Attributes:
      iters, traj: iterations and episodes per iteration.
      eval_every, eval_episodes: validation (one fixed episode set, the clone competing) in
        the simulation the gap stage identified when it ran before train
        (``main_job.gapsim.validation_sim``), else in the same randomized simulation.
      dense_from: from this iteration index on, every iterate is validated too
        (``TrainConfig.eval_dense_from``); None: every ``eval_every`` only. See ``DENSE_FROM``.
      randomize: effect names (``DAPG_RANDOMIZE``).
      clones: behaviour clones fitted (BC seeds) before DAPG, each judged on
        ``eval_episodes`` episodes of the same randomized simulation (their own episode set,
        ``samplers.BC_EVAL_STREAM``); DAPG starts from the best (``main_job.clones``). 1: the
        run's seed's clone only.
      runs: DAPG runs from that clone, each with its own seed (randomization draws, training
        episodes); with more than one, DAPG's policy is the average of their last iterates'
        weights (``main_job.streams``), the clone if that validates below it. 1 (every
        budget): the single run's best validated policy. Not adopted (bench/RESULTS.md,
        "DAPG averaged over randomization streams", seeds 0 and 2): 3 runs' average solved
        44 and 30 of 100 held-out robot episodes where the single run solved 48 and 32
        (clones 40 and 20), for three runs' CPU (47 s each), although in the randomized
        simulation the average validated above every run's last iterate (50 vs 28-42 of 100;
        36 vs 24-34).
    """

    iters: int
    traj: int
    eval_every: int
    eval_episodes: int
    randomize: tuple[str, ...] = DAPG_RANDOMIZE
    clones: int = 1
    runs: int = 1
    dense_from: int | None = None

    def __post_init__(self) -> None:
        from lowcostdex.errors import check_choice, check_number
        from lowcostdex.sim.effects import EFFECTS

        if isinstance(self.randomize, str) or not isinstance(self.randomize, (tuple, list)):
            raise ConfigError(f"SimTraining.randomize={self.randomize!r} must be a tuple of "
                              "effect names, e.g. ('latency', 'backlash')")
        for name in self.randomize:
            check_choice("effect in SimTraining.randomize", name, EFFECTS)
        for name in ("iters", "traj", "eval_episodes", "clones", "runs"):
            check_number(f"SimTraining.{name}", getattr(self, name), 1, integer=True)
        check_number("SimTraining.eval_every", self.eval_every, 0, integer=True)
        check_number("SimTraining.dense_from", self.dense_from, 0, self.iters - 1, integer=True,
                     none_ok=True)


CLONES = 6
"""Behaviour clones DAPG chooses from in the default and long budgets (``SimTraining.clones``).
Measured (valve-target, seeds 0-2, the main job's demonstrations; bench/RESULTS.md, "Best of six
clones"): six clones' held-out robot successes spread 6-20, 9-24 and 1-19 of 40; the best on
100 randomized-sim validation episodes solved 18, 19, 12 of 40 where the run's-seed clone alone
solved 16, 16, 1 (49 vs 33 of 120), for ~25 s of CPU and no robot time."""


DENSE_FROM = 15
"""DAPG's validation runs after every iteration from this one on (``SimTraining.dense_from`` of
the default and long budgets; before: iterations 9, 19, 29 only). DAPG's deterministic policy
changes by several successes in 100 episodes from one iteration to the next (seed 0's iterates
15-29 in a simulation with the robot's own effects: 42-56 of 100), so the best of the late
iterates, by the same validation, beats the one every tenth iteration hits. Measured on the 100
held-out robot episodes (bench/RESULTS.md, "The main job's DAPG validated at every late
iterate"): seed 0 it 22 instead of 29, 49 instead of 48 of 100 (clone 40: 17 / 8, McNemar p
0.054, Wilcoxon p 0.002); seed 1 it 24 instead of 19, 52 instead of 50 (clone 39: 16 / 3, p
0.0022); seed 2 it 28 instead of 29, 37 instead of 32 (clone 20: 24 / 7, p 0.0017). Cost: 12
more validations of 100 simulated episodes, ~30 s of CPU."""


HELDOUT = 100
"""Held-out robot episodes per policy in the default and long budgets (was 40). On 40 a real
gain does not show in one run: seed 1's DAPG from its chosen clone went 39 -> 51 of 100 (19 vs 7
episodes solved by one only, McNemar p 0.015; final errors Wilcoxon p < 1e-4), and 22 -> 27 on
the first 40 of them (p 0.09; bench/RESULTS.md, "Best of six clones"). The cost: 4 x 60 more
episodes, ~1 min of CPU on the emulated robot; on a real D'Claw ~7 s of robot time each with its
reset (144 s per 20 episodes measured on the emulated robot: 29 min more)."""


@keyword_hints
@dataclass
class Budget:
    """How much each stage does.

    ``eval_episodes`` are the validation episodes of each evaluation during training (every
    ``eval_every`` iterations; the behaviour clone's too), which choose each run's policy;
    ``heldout_episodes`` the held-out episodes on which the random actions, the clone, DAPG
    and NPG are compared after training (``samplers.HELDOUT_STREAM``, the same for all four).
    ``dapg_sim``: DAPG trains in simulation with this budget (its ``dapg_iters``,
    ``traj_per_iter`` and validation settings then apply to NPG only); None: on the robot.
    """

    demos: int
    dapg_iters: int
    npg_iters: int
    traj_per_iter: int
    eval_episodes: int
    eval_every: int
    gap_logs: int
    gap_seconds: float
    heldout_episodes: int
    dapg_sim: SimTraining | None = None


BUDGETS = {
    "smoke": Budget(demos=4, dapg_iters=1, npg_iters=1, traj_per_iter=4, eval_episodes=3,
                    eval_every=0, gap_logs=3, gap_seconds=6.0, heldout_episodes=3,
                    dapg_sim=SimTraining(iters=1, traj=4, eval_every=0, eval_episodes=3,
                                         clones=2)),
    "default": Budget(demos=20, dapg_iters=12, npg_iters=12, traj_per_iter=20, eval_episodes=20,
                      eval_every=4, gap_logs=6, gap_seconds=15.0,
                      heldout_episodes=HELDOUT,
                      dapg_sim=SimTraining(iters=30, traj=40, eval_every=10, eval_episodes=100,
                                           clones=CLONES, dense_from=DENSE_FROM)),
    "long": Budget(demos=50, dapg_iters=60, npg_iters=60, traj_per_iter=40, eval_episodes=20,
                   eval_every=5, gap_logs=10, gap_seconds=30.0,
                   heldout_episodes=HELDOUT,
                   dapg_sim=SimTraining(iters=30, traj=40, eval_every=10, eval_episodes=100,
                                        clones=CLONES, dense_from=DENSE_FROM)),
}


DAPG_LAM0 = 0.01
"""DAPG's initial demo weight in the main job (``DAPGConfig.lam0``; hand_dapg's released value,
the paper's 0.1 is the trainer's default). The clone is fitted to the same demonstrations, so
with 0.1 the demo term (~1680 pairs at weight ~0.3 against 800 on-policy samples) holds DAPG near
the clone it has to improve on. Measured (valve-target, seed 0, emulated D'Claw, a weak clone from
soft-hand demonstrations; the clone and DAPG's policy every 4 iterations on the same 20 held-out
episodes): lam0 0.1: 3, 7, 7, 6, 6 successes at iterations 0, 4, 8, 12, 16; lam0 0.01: 3, 7,
10, 11, 11. From the main job's own (better) clone neither moved success beyond the noise
(bench/RESULTS.md, "The RL stage in the main job")."""


@dataclass
class Context:
    """What every stage sees.

    Attributes:
      out: output folder.
      size: one of SIZES.
      seed: master seed.
      port: serial port of a real robot, or None for the emulated D'Claw.
      task: one of TASKS.
      results: results of earlier stages by name (JSON-serializable).
    """

    out: Path
    size: str = "default"
    seed: int = 0
    port: str | None = None
    task: str = DEFAULT_TASK
    results: dict[str, dict[str, Any]] = field(default_factory=dict)

    def __post_init__(self) -> None:  # the CLI checks its options; Python callers get the same
        from lowcostdex.errors import check_choice, check_number
        from lowcostdex.outdir import user_path

        self.out = user_path(self.out)  # (a str: "runs/main" / "results.json" failed in a stage)
        check_choice("main job size", self.size, SIZES)
        check_choice("main job task", self.task, TASKS)
        check_number("Context.seed", self.seed, 0, integer=True)
        if self.port is not None and not isinstance(self.port, str):
            raise ConfigError(f"Context.port={self.port!r} must be a serial port path (a str, "
                              "e.g. '/dev/ttyUSB0') or None for the emulated D'Claw")

    @property
    def budget(self) -> Budget:
        return BUDGETS[self.size]

    @property
    def setup(self) -> TaskSetup:
        return TASKS[self.task]

    @property
    def emulated(self) -> bool:
        return self.port is None

    def env_kwargs(self) -> dict[str, Any]:
        """gym.make keyword arguments selecting the robot (JSON-serializable)."""
        from lowcostdex.hands import dclaw_spec

        task = dict(self.setup.env_overrides)
        if self.port is None:
            effects = robot_effects(dclaw_spec().joint_names)
            return {**task, "backend": "emulated", "effects": [e.to_dict() for e in effects]}
        return {**task, "backend": "hardware", "port": self.port}
