"""Careless calls on the Python API (issues 12 and 13): what a hurried researcher types after
reading README.md and docs/ gives one clear error raised by lowcostdex at the boundary (naming
the argument, its value and what is valid), never a traceback from inside numpy, torch or
MuJoCo, a silent unit mistake, or NaN carried into a robot or a checkpoint; and nothing of the
user's on disk changes.

``CASES`` is the table: the user's files, the call, the exception and a fragment of its
message. The checks are the same for every row (``test_careless_call_is_refused_cleanly``):
the exception type and message, the raising frame inside the ``lowcostdex`` package, and every
file in the user's folder byte-identical with nothing added. ``ROBOT_CASES`` are calls on an
emulated D'Claw, checked from the motors' side (no goal arrived). ``ACCEPTED`` are legitimate
but odd calls that must keep working.

The list of every call tried, with the ones found fine, is in the session notes
(/work/notes/careless.md).
"""

from __future__ import annotations

import io
import math
import re
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import lowcostdex  # noqa: F401  (registers the ids)
from lowcostdex.algos.configs import (
    BCConfig,
    NPGConfig,
    PolicyConfig,
    PPOConfig,
    TrainConfig,
)
from lowcostdex.algos.local_models.mdgps import MDGPSConfig
from lowcostdex.algos.local_models.train_config import TaskCostConfig
from lowcostdex.algos.policy import GaussianMLPPolicy
from lowcostdex.algos.train import load_policy
from lowcostdex.demonstrations.dataset import load_demos
from lowcostdex.errors import ConfigError, InputError
from lowcostdex.gap import GapConfig, LogError, load_dataset, write_log
from lowcostdex.gap.identify import IdentifyConfig
from lowcostdex.hardware.robot.guards import CurrentConfig, ThermalConfig
from lowcostdex.hardware.robot.reset import ResetConfig
from lowcostdex.hardware.robot.robot import RobotConfig
from lowcostdex.hardware.robot.safety import UnsafeCommand
from lowcostdex.sim.effects import DomainRandomization
from lowcostdex.sim.envs.dclaw_tasks import TurnValve
from lowcostdex.sim.envs.hand_env import HandEnv
from lowcostdex.sim.vector import make_vec
from lowcostdex.teachers import FlipBlockTeacher, ValveTurnTeacher

VALVE = "lowcostdex/DClawTurnValve-v0"
N_JOINTS = 9  # the D'Claw's action joints
OBS_DIM = 30  # DClawTurnValve-v0's observation


@dataclass(frozen=True)
class Case:
    """One careless call. ``call`` gets the user's folder (holding ``files``)."""

    id: str
    call: Callable[[Path], object]
    error: type[BaseException]
    message: str  # a fragment of the message (plain text, not a pattern)
    files: dict[str, Callable[[], bytes]] = field(default_factory=dict)


# ------------------------------------------------------------------------------------------------
# what the calls need


def _env(env_id: str = VALVE, **kwargs) -> gym.Env:
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    return env


def _step(action) -> Callable[[Path], object]:
    return lambda _: _env().step(action)


def _reset(**options) -> Callable[[Path], object]:
    return lambda _: _env().reset(seed=1, options=options)


def _dxl(**kwargs):
    from lowcostdex.hardware.dynamixel.config import DynamixelConfig

    return DynamixelConfig(ids=(10, 11), models=("XH430-W350", "XH430-W350"), **kwargs)


def _trajectory():
    from lowcostdex.gap import Trajectory

    t = np.arange(3) * 0.01
    return Trajectory("log", t, np.zeros((3, 1)), np.zeros((3, 1)), ("a",), ("a",))


def _teacher() -> ValveTurnTeacher:
    teacher = ValveTurnTeacher()
    teacher.reset(_env())  # a gym.make env, wrappers and all
    return teacher


def _vec():
    vec = make_vec(VALVE, num_envs=2)
    vec.reset(seed=0)
    return vec


def _policy() -> GaussianMLPPolicy:
    return GaussianMLPPolicy(OBS_DIM, N_JOINTS, PolicyConfig(hidden_sizes=(32, 32)),
                             torch.Generator().manual_seed(0))


def _saved(state) -> bytes:
    buf = io.BytesIO()
    torch.save(state, buf)
    return buf.getvalue()


def _checkpoint(**change) -> Callable[[], bytes]:
    """policy.pt as a run writes it, with entries of its policy changed."""
    def make() -> bytes:
        ckpt = _policy().to_checkpoint()
        for key, value in change.items():
            if key == "hidden_sizes":
                ckpt["config"]["hidden_sizes"] = value
            elif key == "log_std":
                ckpt["state_dict"]["log_std"] = value
            else:
                ckpt[key] = value
        return _saved({"policy": ckpt})
    return make


def _cut(make: Callable[[], bytes]) -> Callable[[], bytes]:
    return lambda: make()[: len(make()) // 2]


GOOD_CKPT = _checkpoint()


# ------------------------------------------------------------------------------------------------
# the table

CASES: list[Case] = [
    # gymnasium.make with bad keyword arguments: named with the valid ones, at construction
    Case("make-unknown-kwarg", lambda _: gym.make(VALVE, foo=1), ConfigError,
         "unknown keyword argument 'foo' for backend 'sim' of TurnValve; valid: init_range"),
    Case("make-port-on-sim", lambda _: gym.make(VALVE, port="/dev/ttyUSB0"), ConfigError,
         "unknown keyword argument 'port' for backend 'sim'"),
    Case("make-unknown-kwarg-emulated", lambda _: gym.make(VALVE, backend="emulated", foo=1),
         ConfigError, "unknown keyword argument 'foo' for backend 'emulated'"),
    Case("make-negative-range", lambda _: gym.make(VALVE, init_range=-1.0), ConfigError,
         "TurnConfig.init_range=-1.0 must be a finite number in [0, 3.14159] [rad]"),
    Case("make-range-as-string", lambda _: gym.make(VALVE, goal_range="0.5"), ConfigError,
         "TurnConfig.goal_range='0.5' must be a finite number"),
    Case("make-nan-range", lambda _: gym.make(VALVE, init_range=math.nan), ConfigError,
         "TurnConfig.init_range=nan"),
    Case("make-offset-in-degrees", lambda _: gym.make(VALVE, goal_offset=180), ConfigError,
         "TurnConfig.goal_offset=180 must be a finite number in [-12.5664, 12.5664] [rad] "
         "(an angle in rad, not degrees)"),
    Case("make-tolerance-zero-or-less", lambda _: gym.make(VALVE, success_tol=-0.1),
         ConfigError, "TurnConfig.success_tol=-0.1"),
    Case("make-screw-speed-in-deg-per-s", lambda _: gym.make("lowcostdex/DClawScrew-v0",
                                                              speed=30.0),
         ConfigError, "ScrewConfig.speed=30.0 must be a finite number in [-6.28319, 6.28319] "
         "[rad/s] (in rad/s, not deg/s)"),
    Case("make-screw-random-as-string",
         lambda _: gym.make("lowcostdex/DClawScrew-v0", random="false"), ConfigError,
         "ScrewConfig.random='false' must be True or False"),
    Case("make-flip-zero-axis",
         lambda _: gym.make("lowcostdex/DClawFlipBlock-v0", flip_axis=(0, 0, 0)), ConfigError,
         "FlipConfig.flip_axis=(0, 0, 0) must be 3 finite numbers, not all 0"),
    Case("make-flip-drop-height-in-mm",
         lambda _: gym.make("lowcostdex/DClawFlipBlock-v0", drop_height=30), ConfigError,
         "FlipConfig.drop_height=30 must be a finite number in [-1, 1] [m]"),
    Case("make-allegro-offset-in-degrees",
         lambda _: gym.make("lowcostdex/AllegroTurnValve-v0", goal_offset=360), ConfigError,
         "AllegroTurnConfig.goal_offset=360"),
    # step(): the wrong layout, dtype or NaN is refused before anything moves
    Case("step-3x3-for-9-joints", _step(np.zeros((3, 3))), ValueError,
         "action has shape (3, 3); this env takes (9,)"),
    Case("step-bool-array", _step(np.ones(N_JOINTS, bool)), ValueError, "has dtype bool"),
    Case("step-complex", _step(np.zeros(N_JOINTS) + 1j), ValueError, "has dtype complex128"),
    Case("step-string", _step("open"), ValueError, "this env takes 9 real numbers"),
    Case("step-none", _step(None), ValueError, "this env takes 9 real numbers"),
    Case("step-8-values", _step(np.zeros(8)), ValueError, "action has shape (8,)"),
    Case("step-nan", _step(np.full(N_JOINTS, np.nan)), ValueError, "NaN/inf"),
    # the batched env (README: make_vec(id, num_envs=64))
    Case("vec-fractional-num-envs", lambda _: make_vec(VALVE, num_envs=2.5), ConfigError,
         "num_envs=2.5 must be an integer in [1, inf)"),
    Case("vec-num-envs-as-string", lambda _: make_vec(VALVE, num_envs="4"), ConfigError,
         "num_envs='4' must be an integer"),
    Case("vec-one-action-for-two-copies", lambda _: _vec().step(np.zeros(N_JOINTS)),
         ValueError, "actions of shape (9,) and dtype float64; this vector env takes real "
         "numbers of shape (2, 9)"),
    Case("vec-bool-actions", lambda _: _vec().step(np.zeros((2, N_JOINTS), bool)), ValueError,
         "dtype bool"),
    # domain randomization (docs/gap_analysis.md: DomainRandomization(...), randomize=...)
    Case("dr-effects-as-string", lambda _: DomainRandomization("latency", ("ff_top",)),
         ConfigError, "DomainRandomization.effects='latency' must be a tuple of names"),
    Case("dr-latency-in-ms",
         lambda _: DomainRandomization(("latency",), ("ff_top",),
                                       {"latency": {"delay": (10.0, 30.0)}}),
         ConfigError, "range of latency.delay [s]: (10.0, 30.0) outside the parameter's limits "
         "[0, 0.25] s"),
    Case("dr-nan-range",
         lambda _: DomainRandomization(("latency",), ("ff_top",),
                                       {"latency": {"delay": (math.nan, 0.01)}}),
         ConfigError, "must be finite"),
    Case("dr-from-dict-misspelt", lambda _: gym.make(VALVE, randomize={"effect": ["latency"]}),
         ConfigError, "unknown DomainRandomization key 'effect'; valid: effects, joints, ranges"),
    Case("demos-none", lambda _: load_demos(None), InputError,
         "a demonstration file is given by its path (.h5), not NoneType"),
    Case("hand-env-randomization-as-names",
         lambda _: HandEnv(TurnValve(), randomization=["latency"]), ConfigError,
         "randomization must be a DomainRandomization, not list"),
    Case("hand-env-task-class", lambda _: HandEnv(TurnValve), ConfigError,
         "HandEnv takes a task instance (e.g. TurnValve())"),
    # teachers (README: scripted solvers in lowcostdex.teachers) on the wrong env or state
    Case("valve-teacher-on-the-flip-task",
         lambda _: ValveTurnTeacher().reset(_env("lowcostdex/DClawFlipBlock-v0")), ConfigError,
         "ValveTurnTeacher solves the D'Claw's valve, foam-valve and screw tasks; got FlipBlock "
         "on the dclaw hand"),
    Case("valve-teacher-on-the-allegro",
         lambda _: ValveTurnTeacher().reset(_env("lowcostdex/AllegroTurnValve-v0")),
         ConfigError, "got AllegroTurnValve on the allegro hand"),
    Case("flip-teacher-on-the-valve", lambda _: FlipBlockTeacher().reset(_env()), ConfigError,
         "FlipBlockTeacher solves the D'Claw's flip-block tasks; got TurnValve"),
    Case("teacher-called-before-reset",
         lambda _: ValveTurnTeacher()(np.zeros(10), {"angle": 0.0}), ConfigError,
         "ValveTurnTeacher: call reset(env) at the start of an episode first"),
    Case("teacher-given-hand-joints-only", lambda _: _teacher()(np.zeros(N_JOINTS),
                                                               {"angle": 0.0}),
         ValueError, "qpos has shape (9,); the bound model's full state is (10,)"),
    Case("teacher-given-no-goal", lambda _: _teacher()(np.zeros(10), {}), ValueError,
         "the goal lacks angle"),
    # reset(options=...): no silent ignore, no broadcast error, no NaN state
    Case("reset-misspelt-option", _reset(qpoz=np.zeros(10)), ValueError,
         "unknown reset option 'qpoz'; valid: 'qpos', 'qvel', 'goal'"),
    Case("reset-qpos-wrong-size", _reset(qpos=[0.0, 0.0]), ValueError,
         "reset option 'qpos' has shape (2,); this env's model takes (10,)"),
    Case("reset-qpos-nan", _reset(qpos=np.full(10, np.nan)), ValueError,
         "reset option 'qpos' has NaN/inf entries"),
    Case("reset-goal-unknown-key", _reset(goal={"target": 1.0}), ValueError,
         "reset option 'goal' has keys ['target']; this task's goal has ['angle']"),
    Case("reset-goal-nan", _reset(goal={"angle": math.nan}), ValueError,
         "reset option goal['angle']=nan must be finite"),
    Case("reset-goal-scalar-as-1-array", _reset(goal={"angle": np.array([math.pi])}),
         ValueError, "must be finite with shape ()"),
    # configs: wrong types are refused at construction, not read as truthy or compared later
    Case("npg-flag-as-string", lambda _: NPGConfig(normalize_advantages="false"), ConfigError,
         "normalize_advantages='false' must be True or False"),
    Case("bc-flag-as-int", lambda _: BCConfig(set_action_scaling=2), ConfigError,
         "BC set_action_scaling=2 must be True or False"),
    Case("train-flag-as-string", lambda _: TrainConfig(bootstrap_truncated="no"), ConfigError,
         "bootstrap_truncated='no' must be True or False"),
    Case("train-env-kwargs-as-string",
         lambda _: TrainConfig(env_kwargs="port=/dev/ttyUSB0"), ConfigError,
         "env_kwargs='port=/dev/ttyUSB0' must be a dict of gym.make keyword arguments"),
    Case("train-env-id-not-a-string", lambda _: TrainConfig(env_id=3), ConfigError,
         "env_id=3 must be a gymnasium id"),
    Case("train-policy-as-dict", lambda _: TrainConfig(policy={"hidden_sizes": (32,)}),
         ConfigError, "must be a PolicyConfig"),
    Case("train-demos-not-a-path", lambda _: TrainConfig(algo="dapg", demos=3), ConfigError,
         "demos=3 must be the path of a demonstration file"),
    Case("train-from-dict-misspelt-key", lambda _: TrainConfig.from_dict({"n_iters": 5}),
         ConfigError, "unknown TrainConfig setting 'n_iters'; valid: algo, env_id"),
    Case("train-from-dict-misspelt-nested",
         lambda _: TrainConfig.from_dict({"npg": {"stepsize": 0.1}}), ConfigError,
         "unknown NPGConfig setting 'stepsize'; valid: step_size"),
    Case("policy-hidden-as-strings", lambda _: PolicyConfig(hidden_sizes=("64", "64")),
         ConfigError, "hidden_sizes=('64', '64') must be positive integers"),
    Case("policy-hidden-as-string", lambda _: PolicyConfig(hidden_sizes="64"), ConfigError,
         "hidden_sizes='64' must be positive integers"),
    Case("ppo-flag-as-string", lambda _: PPOConfig(norm_adv="false"), ConfigError,
         "norm_adv='false' must be True or False"),
    Case("ppo-from-dict-misspelt", lambda _: PPOConfig.from_dict({"num_env": 8}), ConfigError,
         "unknown PPOConfig setting 'num_env'"),
    Case("gap-candidates-as-string", lambda _: GapConfig(candidates="latency"), ConfigError,
         "candidates='latency' must be a tuple of effect names"),
    Case("gap-fractional-count", lambda _: GapConfig(max_effects=1.5), ConfigError,
         "max_effects=1.5 must be an integer in [1, inf)"),
    Case("gap-nan-margin", lambda _: GapConfig(floor_margin=math.nan), ConfigError,
         "floor_margin=nan must be a finite number"),
    Case("gap-seed-as-string", lambda _: GapConfig(seed="0"), ConfigError,
         "seed='0' must be an integer"),
    Case("gap-test-logs-as-string", lambda _: GapConfig(test_logs="0"), ConfigError,
         "test_logs='0' must be a tuple of log indices"),
    Case("gap-probes-as-string", lambda _: GapConfig(probes="0.01"), ConfigError,
         "probes='0.01' must be a tuple"),
    Case("gap-negative-segment", lambda _: GapConfig(segment=-6.0), ConfigError,
         "segment must be > 0 s"),
    Case("identify-rounds-as-string", lambda _: IdentifyConfig(max_rounds="30"), ConfigError,
         "max_rounds='30' must be an integer in [1, inf)"),
    Case("identify-nan-tolerance", lambda _: IdentifyConfig(rtol=math.nan), ConfigError,
         "rtol=nan must be a finite number"),
    Case("identify-one-effect-as-string",
         lambda _: IdentifyConfig(effects="coulomb_friction"), ConfigError,
         "effects='coulomb_friction' must be a tuple of effect names"),
    Case("identify-start-of-unknown-parameter",
         lambda _: IdentifyConfig(starts=({("coulomb_friction", "force"): 0.1},)), ConfigError,
         "unknown coulomb_friction parameter 'force'"),
    # the Dynamixel bus's config (README: realtime_tick=True, a DynamixelConfig field)
    Case("dxl-flag-as-string", lambda _: _dxl(torque_off_on_close="no"), ConfigError,
         "torque_off_on_close='no' must be True or False"),
    Case("dxl-realtime-tick-as-string", lambda _: _dxl(realtime_tick="true"), ConfigError,
         "realtime_tick='true' must be True or False"),
    Case("dxl-nan-latency", lambda _: _dxl(latency_ms=math.nan), ConfigError,
         "latency_ms=nan must be a finite number"),
    Case("dxl-baudrate-as-string", lambda _: _dxl(baudrate="1000000"), ConfigError,
         "baudrate='1000000' must be an integer"),
    Case("robot-unbounded-motion", lambda _: RobotConfig(motion_scale=math.inf), ConfigError,
         "RobotConfig.motion_scale=inf must be a finite number"),
    Case("robot-period-in-ms", lambda _: RobotConfig(control_period=100), ConfigError,
         "RobotConfig.control_period [s]=100 must be a finite number in (0, 1]"),
    Case("thermal-pause-without-end", lambda _: ThermalConfig(max_pause=math.inf),
         ConfigError, "ThermalConfig.max_pause=inf must be a finite number"),
    Case("current-fraction-as-string", lambda _: CurrentConfig(fraction="0.5"), ConfigError,
         "CurrentConfig.fraction='0.5' must be a finite number"),
    Case("reset-nan-tolerance", lambda _: ResetConfig(tolerance=math.nan), ConfigError,
         "ResetConfig.tolerance=nan must be a finite number"),
    Case("mdgps-iterations-as-string", lambda _: MDGPSConfig(iterations="6"), ConfigError,
         "MDGPSConfig.iterations='6' must be an integer"),
    Case("task-cost-nan-weight", lambda _: TaskCostConfig(pose_weight=math.nan), ConfigError,
         "TaskCostConfig.pose_weight=nan must be a finite number"),
    # policies and checkpoints: the file named, never a torch/unpickler traceback
    Case("load-policy-empty-run-dir", lambda d: load_policy(d), FileNotFoundError,
         "a run directory holds policy.pt"),
    Case("load-policy-cut-short", lambda d: load_policy(d / "policy.pt"), InputError,
         "policy.pt: does not load: corrupt or cut short", {"policy.pt": _cut(GOOD_CKPT)}),
    Case("load-policy-empty-file", lambda d: load_policy(d / "policy.pt"), InputError,
         "policy.pt: does not load", {"policy.pt": lambda: b""}),
    Case("load-policy-text-file", lambda d: load_policy(d / "notes.pt"), InputError,
         "notes.pt: does not load", {"notes.pt": lambda: b"my notes\n"}),
    Case("load-policy-other-checkpoint", lambda d: load_policy(d / "model.pt"), InputError,
         "model.pt: lacks policy", {"model.pt": lambda: _saved(_policy().state_dict())}),
    Case("load-policy-other-architecture", lambda d: load_policy(d), InputError,
         "policy checkpoint's weights do not fit its own sizes 30 -> (64, 64) -> 9",
         {"policy.pt": _checkpoint(hidden_sizes=[64, 64])}),
    Case("load-policy-nan-weights", lambda d: load_policy(d), InputError,
         "policy checkpoint holds NaN/inf weights",
         {"policy.pt": _checkpoint(log_std=torch.full((N_JOINTS,), math.nan,
                                                      dtype=torch.float64))}),
    Case("load-policy-bad-dtype", lambda d: load_policy(d), InputError,
         "policy checkpoint dtype 'Tensor'; valid: 'float32', 'float64'",
         {"policy.pt": _checkpoint(dtype="Tensor")}),
    Case("policy-obs-of-another-env", lambda _: _policy().act(np.zeros(2 * OBS_DIM),
                                                              deterministic=True),
         ValueError, "observation of shape (60,); this policy takes (30,) or (n, 30)"),
    Case("policy-seed-instead-of-generator", lambda _: _policy().act(np.zeros(OBS_DIM),
                                                                     generator=0),
         ValueError, "stochastic actions need a seeded torch.Generator, got 0"),
    Case("policy-zero-obs-dim", lambda _: GaussianMLPPolicy(0, N_JOINTS), ConfigError,
         "obs_dim=0 must be an integer in [1, inf)"),
    # gap Python API: arrays or None where paths go, a folder as model, a timestep in ms
    Case("gap-array-as-logs", lambda _: load_dataset(np.zeros((100, 3))), LogError,
         "logs are given as file paths (a path, a folder, a glob pattern or a list of them), "
         "not ndarray"),
    Case("gap-dict-as-logs", lambda _: load_dataset({"time": [0.0, 0.01]}), LogError,
         "not dict; write arrays to a file first: lowcostdex.gap.write_log(path, "
         "Trajectory(...))"),
    Case("gap-write-log-of-columns",
         lambda d: write_log(d / "log.csv", {"time": np.arange(3) * 0.01}), LogError,
         "write_log(path, traj) writes a lowcostdex.gap.Trajectory"),
    Case("gap-write-log-swapped", lambda d: write_log(_trajectory(), d / "log.csv"), LogError,
         "write_log(path, traj): the path comes first"),
    Case("gap-none-as-logs", lambda _: load_dataset(None), LogError, "not NoneType"),
    Case("gap-folder-as-model", lambda d: load_dataset([d / "log.csv"], model=d), LogError,
         "a folder, not an MJCF model file", {"log.csv": lambda: b"time,goal:a,qpos:a\n0,0,0\n"}),
    Case("gap-timestep-in-ms", lambda d: load_dataset([d / "bam.json"], timestep=1.0),
         ConfigError, "timestep [s]=1.0 must be a finite number in (0, 0.05]",
         {"bam.json": lambda: b"{}"}),
]


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else b"<dir>"
            for p in sorted(folder.rglob("*"))}


def _raised_in_lowcostdex(exc: BaseException) -> str:
    """The file of the frame that raised ``exc`` (its innermost frame)."""
    return traceback.extract_tb(exc.__traceback__)[-1].filename


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_careless_call_is_refused_cleanly(case: Case, tmp_path: Path):
    user = tmp_path / "user"
    user.mkdir()
    for name, make in case.files.items():
        (user / name).write_bytes(make())
    before = _snapshot(user)
    with pytest.raises(case.error, match=re.escape(case.message)) as info:
        case.call(user)
    # raised by lowcostdex at the boundary, not by numpy/torch/mujoco from deep inside
    assert "/lowcostdex/" in _raised_in_lowcostdex(info.value).replace("\\", "/"), (
        "".join(traceback.format_exception(info.value)))
    assert "\n" not in str(info.value).strip()  # one line
    assert _snapshot(user) == before  # the user's files untouched, nothing added


# ------------------------------------------------------------------------------------------------
# the robot: careless commands on an emulated D'Claw, checked from the motors' side


@pytest.fixture(scope="module")
def robot():
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.hardware.emulated.chain import emulated_dclaw
    from lowcostdex.hardware.robot.backend import make_dynamixel_bus
    from lowcostdex.hardware.robot.robot import Robot

    hand = dclaw_spec()
    chain = emulated_dclaw("valve", hand=hand, rng=np.random.default_rng(0))
    bus = make_dynamixel_bus(hand, chain.port(), chain.plant.model, handle_signals=False)
    with Robot(hand, bus) as r:
        r.torque(True, hand.joint_names)
        r.step(r.read().position[:N_JOINTS])
        yield chain, r


def _present(r) -> np.ndarray:
    return r.read().position[:N_JOINTS].copy()


ROBOT_CASES = [
    ("goal-in-degrees", lambda r: r.send(np.degrees(_present(r)) + 30.0), UnsafeCommand,
     "goal far outside the joint limits: ff_top=3"),
    ("one-goal-in-degrees", lambda r: r.send(_present(r) + np.eye(N_JOINTS)[1] * 45.0),
     UnsafeCommand, "ff_middle=45"),
    ("goal-in-ticks", lambda r: r.send(np.full(N_JOINTS, 2048.0)), UnsafeCommand,
     "goals are in rad (degrees or ticks?)"),
    ("goal-as-text", lambda r: r.send("home"), UnsafeCommand,
     "goal 'home' is not 9 numbers [rad]"),
    ("goal-nan", lambda r: r.send(np.full(N_JOINTS, np.nan)), UnsafeCommand, "non-finite goal"),
    ("torque-off-as-string", lambda r: r.torque("off"), ConfigError,
     "enabled='off' must be True or False"),
    ("rest-negative", lambda r: r.rest(-1.0), ConfigError, "seconds=-1.0 must be a finite"),
    ("rest-nan", lambda r: r.rest(math.nan), ConfigError, "seconds=nan"),
]


@pytest.mark.parametrize("call,error,message", [c[1:] for c in ROBOT_CASES],
                         ids=[c[0] for c in ROBOT_CASES])
def test_careless_robot_command_reaches_no_motor(robot, call, error, message):
    chain, r = robot
    goals = sum(chain.goal_audit.count.values())  # goals the emulated motors received
    torque = r.torque_enabled
    with pytest.raises(error, match=re.escape(message)) as info:
        call(r)
    assert "/lowcostdex/" in _raised_in_lowcostdex(info.value).replace("\\", "/")
    assert sum(chain.goal_audit.count.values()) == goals  # device side: nothing arrived
    np.testing.assert_array_equal(r.torque_enabled, torque)


def test_a_goal_within_a_turn_beyond_a_limit_is_still_clipped_to_it(robot):
    """Within a full turn of the range a goal beyond a limit is a request for the limit (the
    documented gate): clipped, not refused."""
    _, r = robot
    goal = _present(r)
    goal[1] = r.high[1] + 6.0  # ff_middle, 6 rad past its upper limit
    sent = r.send(goal)
    assert sent[1] <= r.high[1] + 1e-12
    r.rest(0.0)  # zero seconds is a legitimate rest


# ------------------------------------------------------------------------------------------------
# legitimate but odd calls keep working


def test_odd_but_legitimate_actions_are_taken():
    env = _env()
    base = env.unwrapped
    for action in ([0.0] * N_JOINTS,                    # a list
                   np.zeros((1, N_JOINTS)),             # a batch of one (policy.act's output)
                   np.zeros(N_JOINTS, np.int64),        # integers
                   np.zeros(N_JOINTS, np.float32),      # the action space's dtype
                   torch.zeros(1, N_JOINTS, dtype=torch.float64)):  # a torch tensor
        _, reward, *_ = env.step(action)
        assert np.isfinite(reward)
    # beyond [-1, 1]: clipped to the bounds as documented (Gaussian policies sample there)
    _, _, _, _, high = _env().step(np.full(N_JOINTS, 5.0))
    _, _, _, _, one = _env().step(np.ones(N_JOINTS))
    np.testing.assert_array_equal(high["goal"], one["goal"])
    assert base.action_space.contains(np.ones(N_JOINTS, np.float32))


def test_a_reset_to_a_recorded_start_is_taken():
    """reset(options=...) with the state and goal another reset produced (what the local-model
    trainer does)."""
    env = _env()
    base = env.unwrapped
    qpos, qvel = base.data.qpos.copy(), base.data.qvel.copy()
    goal = {k: v.copy() for k, v in base.goal.items()}
    obs, _ = env.reset(seed=5, options={"qpos": qpos, "qvel": qvel, "goal": goal})
    np.testing.assert_array_equal(base.data.qpos, qpos)
    assert np.all(np.isfinite(obs))


def test_a_teacher_bound_to_a_wrapped_env_turns_the_valve():
    """``teacher.reset(gym.make(...))`` (the wrappers kept) binds to the task, and its goals
    step the env."""
    env = _env()
    teacher = ValveTurnTeacher()
    teacher.reset(env)
    base = env.unwrapped
    goals = teacher(base.data.qpos, base.goal)
    assert goals.shape == (N_JOINTS,) and np.all(np.isfinite(goals))


def test_one_effect_name_randomizes_that_effect_not_its_letters():
    env = gym.make(VALVE, randomize="latency")
    assert env.unwrapped.randomization.effects == ("latency",)


def test_a_policy_loads_from_its_run_directory_and_acts(tmp_path):
    (tmp_path / "policy.pt").write_bytes(GOOD_CKPT())
    policy = load_policy(tmp_path)
    reference = _policy()
    obs = np.linspace(-1, 1, OBS_DIM)
    torch.testing.assert_close(policy.act(obs, deterministic=True),
                               reference.act(obs, deterministic=True))
    assert policy.act(np.stack([obs, obs]), deterministic=True).shape == (2, N_JOINTS)


def test_configs_still_take_their_documented_forms():
    assert GapConfig(candidates=["latency", "backlash"]).candidates == ["latency", "backlash"]
    assert TrainConfig.from_dict({"policy": {"hidden_sizes": [16]}}).policy.hidden_sizes == (16,)
    assert PolicyConfig(hidden_sizes=()).hidden_sizes == ()  # a linear policy
    assert NPGConfig(normalize_advantages=np.bool_(False)).normalize_advantages is np.False_


def test_layer_widths_read_back_from_json_are_tuples_again():
    """A config saved with dataclasses.asdict and read back from JSON holds lists; from_dict must
    give back the same frozen config (tuples), for every config that has layer widths."""
    import dataclasses
    import json

    from lowcostdex.algos.configs import BaselineConfig, PPOConfig

    for config in (PolicyConfig(hidden_sizes=(8, 4)), BaselineConfig(hidden_sizes=(16,)),
                   PPOConfig(critic_hidden=(32, 8), policy=PolicyConfig(hidden_sizes=(5,)))):
        back = type(config).from_dict(json.loads(json.dumps(dataclasses.asdict(config))))
        assert back == config
