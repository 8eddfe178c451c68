"""What the transfer loop runs: its conditions, algorithms, tasks (``Task``, ``TASKS``) and sizes
(``Size``, ``SIZES``), and the command-line list parsing. The loop is ``lowcostdex.transfer.loop``.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

from lowcostdex.errors import keyword_hints

COMMAND = "transfer"
CONDITIONS = ("nominal", "randomized", "identified", "identified_randomized", "on_robot")
PER_ROBOT = ("identified", "identified_randomized", "on_robot")  # one policy per robot
ALGOS = ("dapg", "npg")
FINGERS = ("ff", "mf", "th")
EVAL_SEED = 20261125  # seeds of the evaluation episodes (same in every cell)
NARROW_PAD = 0.1  # identified_randomized: ranges at least +-10 % of each identified value
# [rad] success counted again at a looser tolerance than the valve task's 0.1 rad
# (``TurnConfig.success_tol``): policies trained in robot A's identified model end 0.068-0.109
# rad from the goal on A (bench/RESULTS.md, transfer6), so 0.1 splits them by 0.01 rad
LOOSE_TOL = 0.12
STEPS = 40  # steps per episode of the valve tasks (the sample count of an episode)
# a simulated policy whose last in-training evaluation (in its own training sim) is below the
# run's success target trains on from its checkpoint up to EXTEND x the size's iterations (once;
# sizes with in-training evaluations only, not smoke):
# around the varied-log fit on robot C, (d) seed 1 ended its 48k samples at 0.2 in its own sim
# and 0/50 on C; the same run resumed to 96k: 1.0 in its sim from 53k on, 50/50 on C (transfer18)
EXTEND = 2
CPU_FILE = "transfer_cpu.json"  # in a run folder: the CPU seconds its training took here
VALVE_FIT_FILE = "valve_fit.json"  # in identify/ROBOT: the valve-log fit (``transfer.valve_fit``)
OUTPUTS = ("table.md", "transfer.json", "transfer.png", "identified.json")
VALVE_FIT_OPTIONS = ("grid", "starts", "iterations", "profile_half", "profile_points",
                     "profile_iterations", "max_step")
"""``Size.valve_fit`` keys: ``tilt_joint.fit_tilt_jointly`` settings (``grid``: points per axis)."""


@dataclass(frozen=True)
class Task:
    """The task every condition trains and is evaluated on: a registered id and its task
    options (``gym.make`` keyword arguments, e.g. ``TurnConfig`` fields)."""

    env_id: str
    kwargs: tuple[tuple[str, Any], ...] = ()

    def make_kwargs(self, **more: Any) -> dict[str, Any]:
        return {**dict(self.kwargs), **more}

    def label(self) -> str:
        opts = ", ".join(f"{k}={v}" for k, v in self.kwargs)
        return self.env_id.split("/")[1] + (f" ({opts})" if opts else "")

    def training(self, start_range: float = 0.0) -> Task:
        """The task the policies train on: this one, or, when ``start_range`` [rad] is wider
        than the task's own ranges, with the valve's start drawn within +-start_range and the
        goal within +-start_range of its offset from the start (``TurnConfig.init_range`` and
        ``goal_range``): on a robot the start lands a tick or two off while the goal stays,
        so what varies is the start relative to the goal (a 180 deg turn whose wrapped error
        flips sign when the start is past goal - pi). Evaluation and demonstrations stay on
        this task."""
        own = dict(self.kwargs)
        if start_range <= min(own.get("init_range", 0.0), own.get("goal_range", 0.0)):
            return self
        wider = {k: max(float(start_range), own.get(k, 0.0)) for k in ("init_range",
                                                                          "goal_range")}
        return Task(self.env_id, tuple({**own, **wider}.items()))


TASKS = {
    "valve": Task("lowcostdex/DClawTurnValve-v0"),  # 180 deg from the fixed start
    # start and goal each within +-0.25 rad of the fixed ones
    "valve-near": Task("lowcostdex/DClawTurnValve-v0", (("init_range", 0.25),
                                                         ("goal_range", 0.25))),
    "valve-random": Task("lowcostdex/DClawTurnValveRandom-v0"),  # +-60 deg start and goal
}


@keyword_hints
@dataclass(frozen=True)
class Size:
    """How much each stage does.

    Attributes:
      robots: hidden robots (ignored with a port: one robot).
      seeds: training seeds (0, 1, ...).
      algos: learners ("dapg", "npg"), each trained under every condition.
      conditions: training conditions (subset of ``CONDITIONS``).
      demos: virtual-teacher demonstrations (each played back ``playbacks`` times).
      n_iter, n_traj: iterations and trajectories per iteration (the sample budget:
        ``n_iter * n_traj * 40`` steps per policy, every condition and learner).
      eval_every, eval_episodes: in-training evaluations (choose the run's policy).
      episodes: evaluation episodes per cell (policy x robot, policy x its sim).
      id_logs, id_seconds: identification logs per finger and their length [s].
      fingers: fingers identified (others keep the nominal model).
      gap: ``GapConfig`` overrides (the smoke size trims the search; default: none, what
        ``lowcostdex gap analyze`` does).
      bc_epochs: behaviour-cloning epochs before DAPG (None: the trainer's default).
      valve_episodes: the valve-log fit (``transfer.valve_fit``): valve episodes the robot
        plays with the valve on, the k-th a playback demonstration's goals played as
        ``valve_fit.DESIGNS[k % 5]`` (as recorded 4 s, fast 4 s, slow 8 s, stop-and-go 6.4 s,
        twice 8 s), to fit the identified conditions' geometry and valve (a finger base's tilt,
        the valve's friction / damping / inertia, the link lengths); 0: none, the identified
        conditions use the nominal geometry.
      valve_fingers: the fingers whose base tilt is fitted (one fit each; the lowest cost wins).
      valve_fit: ``tilt_joint.fit_tilt_jointly`` overrides (``grid``: points per axis).
    """

    robots: int
    seeds: int
    algos: tuple[str, ...]
    conditions: tuple[str, ...]
    demos: int
    playbacks: int
    n_iter: int
    n_traj: int
    eval_every: int
    eval_episodes: int
    episodes: int
    id_logs: int
    id_seconds: float
    fingers: tuple[str, ...] = FINGERS
    gap: tuple[tuple[str, Any], ...] = ()
    bc_epochs: int | None = None
    valve_episodes: int = 0
    valve_fingers: tuple[str, ...] = FINGERS
    valve_fit: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        from lowcostdex.errors import ConfigError, check_choice, check_keys, check_number

        for name in ("algos", "conditions", "fingers", "valve_fingers"):  # 'dapg' is no list
            v = getattr(self, name)
            if not isinstance(v, (tuple, list)):
                raise ConfigError(f"size: {name}={v!r:.60} must be a tuple of names, e.g. "
                                  f"{(v,) if isinstance(v, str) else ('...',)!r}")
        # (before: n_traj 2.5 and seeds '2' were taken and failed in the training loop, a
        # negative playbacks / eval_every ran as none, bc_epochs -3 as no clone, NaN a raw error)
        for name in ("robots", "seeds", "demos", "n_iter", "n_traj", "episodes", "id_logs"):
            check_number(f"size: {name}", getattr(self, name), 1, integer=True)
        for name in ("playbacks", "eval_every", "eval_episodes", "valve_episodes"):
            check_number(f"size: {name}", getattr(self, name), 0, integer=True)
        check_number("size: bc_epochs", self.bc_epochs, 1, integer=True, none_ok=True)
        check_number("size: id_seconds [s]", self.id_seconds, 0, low_open=True)
        # (a misspelt key failed in fit_tilt_jointly, after the valve episodes were recorded)
        check_keys("size valve_fit setting", [k for k, _ in self.valve_fit], VALVE_FIT_OPTIONS)
        if self.eval_every and not self.eval_episodes:
            raise ConfigError(f"size: eval_every={self.eval_every} evaluates with "
                              "eval_episodes=0 episodes; give eval_episodes >= 1 or eval_every=0")
        for a in self.algos:
            check_choice("algo", a, ALGOS)
        for c in self.conditions:
            check_choice("condition", c, CONDITIONS)
        for f in (*self.fingers, *self.valve_fingers):
            check_choice("finger", f, FINGERS)
        if self.valve_episodes and (int(self.valve_episodes) < 2 or not self.valve_fingers):
            raise ConfigError(f"size: valve_episodes must be 0 (no valve-log fit) or >= 2 (the "
                              f"fit's intervals are paired across episodes) with at least one "
                              f"valve finger, got {self.valve_episodes} and "
                              f"{self.valve_fingers}")
        if not self.algos or not self.conditions:
            raise ConfigError("size: give at least one algo and one condition")

    def budget(self) -> dict[str, Any]:
        """The settings that finished pieces were made with (a resume must keep them)."""
        d = asdict(self)
        for k in ("robots", "seeds", "algos", "conditions"):
            d.pop(k)
        if not self.valve_episodes:  # folders made before the valve-log fit still resume
            for k in ("valve_episodes", "valve_fingers", "valve_fit"):
                d.pop(k)
        return json.loads(json.dumps(d))

    @property
    def samples(self) -> int:
        return self.n_iter * self.n_traj * STEPS


SIZES = {
    # checks the loop end to end in well under a minute (2 robots, 1 seed, every condition)
    "smoke": Size(robots=2, seeds=1, algos=("dapg", "npg"), conditions=CONDITIONS, demos=2,
                  playbacks=1, n_iter=1, n_traj=4, eval_every=0, eval_episodes=2, episodes=2,
                  id_logs=3, id_seconds=3.0, fingers=("ff",),
                  gap=(("max_effects", 1), ("top_k", 2), ("search", "forward"),
                       ("bootstrap", 100), ("max_rounds", 5), ("rank_seconds", 3.0)),
                  bc_epochs=10, valve_episodes=2, valve_fingers=("ff",),
                  valve_fit=(("grid", 3), ("starts", 1), ("iterations", 0),
                             ("profile_points", 2), ("profile_iterations", 0))),
    # the budgets of bench/RESULTS.md's table (48k samples per policy, 50 episodes per cell),
    # one seed of DAPG: an evening on 2 cores (2-4 h measured piece by piece at load 3-15; a
    # third of it or more is on_robot training, 21-70 min per robot). The full table, --seeds 3
    # --algos dapg,npg on the same folder, is 6x the training and evaluation: ~10 h or more.
    "default": Size(robots=3, seeds=1, algos=("dapg",), conditions=CONDITIONS, demos=20,
                    playbacks=2, n_iter=30, n_traj=40, eval_every=5, eval_episodes=20,
                    episodes=50, id_logs=3, id_seconds=10.0, valve_episodes=5),
    "long": Size(robots=3, seeds=3, algos=("dapg", "npg"), conditions=CONDITIONS, demos=40,
                 playbacks=2, n_iter=100, n_traj=40, eval_every=10, eval_episodes=20,
                 episodes=100, id_logs=6, id_seconds=10.0, valve_episodes=5),
}


def extended_iterations(summary: dict[str, Any], n_iter: int) -> int | None:
    """The iterations a finished simulated run trains to under the ``EXTEND`` rule, or None:
    its last in-training evaluation (``summary["final"]["eval_success_rate"]``) is below
    ``summary["target"]`` and it has done fewer than ``EXTEND * n_iter`` iterations. A run
    without in-training evaluations is never extended."""
    final = summary.get("final") or {}
    success, done = final.get("eval_success_rate"), final.get("iteration")
    if success is None or done is None or not math.isfinite(float(success)):
        return None
    if float(success) >= float(summary["target"]) or int(done) + 1 >= EXTEND * n_iter:
        return None
    return EXTEND * n_iter


def size_with(name: str, **overrides: Any) -> Size:
    """A named size with some fields replaced (None values are ignored)."""
    from lowcostdex.errors import check_choice

    check_choice("size", name, tuple(SIZES))
    return replace(SIZES[name], **{k: v for k, v in overrides.items() if v is not None})


def parse_list(text: str | None, valid: Sequence[str], what: str) -> tuple[str, ...] | None:
    """``"a,b"`` -> ``("a", "b")`` checked against ``valid``; None stays None."""
    from lowcostdex.errors import ConfigError, check_choice

    if text is None:
        return None
    from lowcostdex.argtypes import names

    items = names(text, f"--{what}s")  # "dapg,,npg" and "dapg,dapg" refused
    if not items:  # before: "size: give at least one algo and one condition", no option named
        raise ConfigError(f"--{what}s is empty; name at least one {what} ({', '.join(valid)}), "
                          "or leave it out for the default")
    for s in items:
        check_choice(what, s, tuple(valid))
    return items
