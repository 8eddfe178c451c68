"""Careless calls on the Python API (issue 13), session 16. Each test fails on the code before it.

- A simulated env (or a batched one) stepped after ``close()`` kept stepping as if nothing had
  happened, where the emulated robots refuse a closed bus: now the sim backend and the vector
  env raise ``ClosedError`` naming the fix.
- A typo in a keyword of IdentifyConfig, SimTraining, Budget, DomainRandomization, the transfer
  Size, BenchConfig or VirtualTeacherConfig gave Python's bare "unexpected keyword argument";
  now the closest setting is named ("did you mean max_rounds?") and the valid ones listed.
- A mistyped choice (an effect name, an algorithm, a parameter) listed the valid choices only,
  twenty of them for an effect; now the closest one is named too.
"""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest

import lowcostdex  # noqa: F401  (registers the envs)
from lowcostdex.errors import ClosedError, ConfigError, KeywordError, check_choice
from lowcostdex.sim.vector import make_vec

VALVE = "lowcostdex/DClawTurnValve-v0"


@pytest.mark.parametrize("env_id", [VALVE, "lowcostdex/DClawTurnValveRandomDynamics-v0",
                                    "lowcostdex/AllegroTurnValve-v0"])
def test_a_sim_env_stepped_after_close_says_it_was_closed(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    env.close()
    n = env.action_space.shape[0]
    for call, name in ((lambda: env.step(np.zeros(n)), "step"),
                       (lambda: env.reset(seed=1), "reset")):
        with pytest.raises(ClosedError) as exc:
            call()
        assert str(exc.value) == (f"{name}() on a simulation that was closed (by env.close()); "
                                  "make a new env with gym.make")
    env.close()  # closing twice is harmless


def test_a_vector_env_stepped_after_close_says_it_was_closed():
    vec = make_vec(VALVE, num_envs=2)
    vec.reset(seed=0)
    vec.close()
    with pytest.raises(ClosedError, match=r"^step\(\) on a vector env that was closed \(by "
                                          r"vec.close\(\)\); make a new one with make_vec$"):
        vec.step(np.zeros((2, 9)))
    with pytest.raises(ClosedError, match=r"^reset\(\) on a vector env that was closed"):
        vec.reset(seed=0)


def test_a_new_env_after_a_closed_one_still_works():
    env = gym.make(VALVE)
    env.reset(seed=0)
    env.close()
    env = gym.make(VALVE)
    env.reset(seed=0)
    assert np.all(np.isfinite(env.step(np.zeros(9))[0]))
    env.close()


def _identify(**kw):
    from lowcostdex.gap.identify import IdentifyConfig

    return IdentifyConfig(**kw)


def _sim_training(**kw):
    from lowcostdex.main_job.setup import SimTraining

    return SimTraining(**{"iters": 1, "traj": 2, "eval_every": 0, "eval_episodes": 1, **kw})


def _budget(**kw):
    from lowcostdex.main_job.setup import BUDGETS, Budget

    return Budget(**{**dataclasses.asdict(BUDGETS["smoke"]), "dapg_sim": None, **kw})


def _dr(**kw):
    from lowcostdex.sim.effects.randomization import DomainRandomization

    return DomainRandomization(**{"effects": ("latency",), **kw})


def _size(**kw):
    from lowcostdex.transfer.config import SIZES, Size

    return Size(**{**dataclasses.asdict(SIZES["smoke"]), **kw})


def _bench(**kw):
    from lowcostdex.sim.models.bench import BenchConfig

    return BenchConfig(**kw)


def _teacher(**kw):
    from lowcostdex.demonstrations.kinesthetic import VirtualTeacherConfig

    return VirtualTeacherConfig(**kw)


@pytest.mark.parametrize("make, typo, hint", [
    (_identify, {"max_round": 3}, "IdentifyConfig has no setting 'max_round'; did you mean "
                                  "max_rounds? (valid: effects, starts, "),
    (_sim_training, {"n_iters": 3}, "SimTraining has no setting 'n_iters'; did you mean iters? "
                                    "(valid: iters, traj, "),
    (_budget, {"demo": 3}, "Budget has no setting 'demo'; did you mean demos? (valid: demos, "),
    (_dr, {"joint": ("a",)}, "DomainRandomization has no setting 'joint'; did you mean joints? "
                             "(valid: effects, joints, ranges)"),
    (_size, {"n_iters": 3}, "Size has no setting 'n_iters'; did you mean n_iter or n_traj? "),
    (_bench, {"motr": "XM430-W350"}, "BenchConfig has no setting 'motr'; did you mean motor? "),
    (_teacher, {"k_p": 1.0}, "VirtualTeacherConfig has no setting 'k_p'; did you mean kp? "),
], ids=["IdentifyConfig", "SimTraining", "Budget", "DomainRandomization", "transfer.Size",
        "BenchConfig", "VirtualTeacherConfig"])
def test_a_typo_in_a_setting_names_the_closest_one(make, typo, hint):
    with pytest.raises(KeywordError) as exc:
        make(**typo)
    assert str(exc.value).startswith(hint)


def test_a_mistyped_effect_in_sim_training_is_refused_at_construction():
    """Before: SimTraining(randomize=('latncy',)) was accepted and failed in the train stage,
    after the demos and the gap stage had run; a bare string was taken letter by letter."""
    with pytest.raises(ConfigError) as exc:
        _sim_training(randomize=("latncy",))
    text = str(exc.value)
    assert text.startswith("unknown effect in SimTraining.randomize 'latncy'; valid choices: ")
    assert text.endswith("; did you mean 'latency'?")
    with pytest.raises(ConfigError, match=r"randomize='latency' must be a tuple of effect names"):
        _sim_training(randomize="latency")


@pytest.mark.parametrize("value, choices, end", [
    ("latncy", ("latency", "backlash"), "; did you mean 'latency'?"),
    ("NPG", ("npg", "dapg", "bc"), "; did you mean 'npg'?"),
    ("emulatd", ("sim", "emulated", "hardware"), "; did you mean 'emulated'?"),
])
def test_a_mistyped_choice_names_the_closest(value, choices, end):
    with pytest.raises(ConfigError) as exc:
        check_choice("thing", value, choices)
    assert str(exc.value) == (f"unknown thing {value!r}; valid choices: "
                              f"{', '.join(repr(c) for c in choices)}{end}")


def test_a_far_off_choice_only_lists_the_valid_ones():
    with pytest.raises(ConfigError) as exc:
        check_choice("thing", "zzz", ("latency", "backlash"))
    assert str(exc.value) == "unknown thing 'zzz'; valid choices: 'latency', 'backlash'"
    with pytest.raises(ConfigError) as exc:
        check_choice("thing", 3, ("latency", "backlash"))
    assert "did you mean" not in str(exc.value)


def test_a_mistyped_effect_for_the_randomization_names_the_closest():
    with pytest.raises(ConfigError) as exc:
        _dr(effects=("latncy",), joints=("a",))
    assert str(exc.value).endswith("; did you mean 'latency'?")
    with pytest.raises(ConfigError) as exc:
        gym.make(VALVE, randomize=["backlsh"])
    assert str(exc.value).endswith("; did you mean 'backlash'?")


# ------------------------------------------------------------------------------------------------
# seeds and counts from numpy, the buses driven carelessly


def test_a_numpy_seed_resets_the_env_as_the_same_int():
    """Before: gymnasium's "Seed must be a python integer, actual type: numpy.int64" (a seed
    sweep written ``for seed in np.arange(3)``)."""
    env = gym.make(VALVE)
    a = env.reset(seed=np.int64(3))[0]
    b = env.reset(seed=3)[0]
    env.close()
    np.testing.assert_array_equal(a, b)


def test_a_vector_env_s_size_reads_back_as_a_plain_int():
    vec = make_vec(VALVE, num_envs=np.int64(2))
    assert type(vec.num_envs) is int and vec.num_envs == 2
    vec.close()


def _dclaw_bus():
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.hardware.emulated.chain import emulated_dclaw
    from lowcostdex.hardware.robot.backend import make_dynamixel_bus, robot_hand
    from lowcostdex.sim.models.dclaw import build_dclaw

    hand = dclaw_spec()
    model = build_dclaw("none", hand).compile()
    chain = emulated_dclaw("none", hand=hand, effects=(), rng=np.random.default_rng(0))
    h = robot_hand(hand, model)
    return make_dynamixel_bus(h, chain.port(), model), chain


@pytest.mark.parametrize("word", ["no", "false", 0.0])
def test_torque_given_a_word_is_refused_on_both_buses(word):
    """Before: ``set_torque("no")`` (a flag read from a config file as text) turned the torque
    ON, the string being truthy, on the Dynamixel bus and on the Allegro's."""
    from lowcostdex.hardware.allegro.emulator import emulated_allegro

    bus, chain = _dclaw_bus()
    with bus:
        with pytest.raises(ConfigError, match=f"^enabled={word!r} must be True or False$"):
            bus.set_torque(word)
        assert not any(chain.motors[i].torque_on for i in bus.ids)  # seen by the device
    allegro, emu, _ = emulated_allegro()
    allegro.connect()
    try:
        with pytest.raises(ConfigError, match=f"^enabled={word!r} must be True or False$"):
            allegro.set_torque(word)
        assert not allegro.torque_enabled().any()
    finally:
        allegro.disconnect()
        emu.close()


def test_torque_for_a_motor_not_on_the_bus_says_so_at_once():
    """Before: four read attempts of the absent motor, then "no status packet"."""
    from lowcostdex.hardware.bus import CommandError

    bus, _ = _dclaw_bus()
    with bus:
        with pytest.raises(CommandError, match=r"^motor 99 is not on this bus \(10, 11, 12, "):
            bus.set_torque(False, ids=[99])


@pytest.mark.parametrize("goal, message", [
    (np.zeros(3), "3 goals for 16 joints"),
    (None, "0 goals for 16 joints"),
])
def test_the_allegro_given_the_wrong_number_of_goals_says_so(goal, message):
    """Before: numpy's "cannot reshape array of size 3 into shape (16,)"."""
    from lowcostdex.hardware.allegro.emulator import emulated_allegro
    from lowcostdex.hardware.bus import CommandError

    bus, emu, _ = emulated_allegro()
    bus.connect()
    try:
        with pytest.raises(CommandError) as exc:
            bus.write_goal_positions(goal)
        assert str(exc.value).startswith(message) and str(exc.value).endswith("; nothing sent")
    finally:
        bus.disconnect()
        emu.close()


def test_an_emulated_allegro_connected_again_after_disconnect_says_make_a_new_one():
    """Before: connect() opened the socketcan channel 'can0' and said "no such network
    interface", on a machine where the user never named can0."""
    from lowcostdex.hardware.allegro.emulator import emulated_allegro
    from lowcostdex.hardware.bus import BusError

    bus, emu, _ = emulated_allegro()
    bus.connect()
    bus.disconnect()
    with pytest.raises(BusError, match=r"^this AllegroBus was given its CAN bus .* make a new "
                                       r"one \(emulated_allegro\(\), or gym.make for an env\)$"):
        bus.connect()
    emu.close()


def test_robot_joints_given_as_one_name_is_that_joint():
    """Before: ``robot.send(goal, joints="ff_top")`` was read letter by letter: "unknown joint
    'f'"."""
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.hardware.emulated.chain import emulated_dclaw
    from lowcostdex.hardware.robot.backend import make_dynamixel_bus, robot_hand
    from lowcostdex.hardware.robot.robot import Robot, RobotConfig
    from lowcostdex.sim.models.dclaw import build_dclaw

    hand = dclaw_spec()
    model = build_dclaw("none", hand).compile()
    chain = emulated_dclaw("none", hand=hand, effects=(), rng=np.random.default_rng(0))
    h = robot_hand(hand, model)
    robot = Robot(h, make_dynamixel_bus(h, chain.port(), model), RobotConfig(control_period=0.02))
    assert robot.index("ff_top").tolist() == robot.index(["ff_top"]).tolist() == [0]


@pytest.mark.parametrize("out", ["", "  ", None])
def test_train_given_no_run_directory_writes_nothing(out, tmp_path, monkeypatch):
    """Before: ``train(config, "")`` (``os.environ.get("OUT", "")``) trained into the current
    folder, its checkpoints beside the user's files; ``None`` gave os.fspath's TypeError."""
    from lowcostdex.algos.configs import TrainConfig
    from lowcostdex.algos.train import train

    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(ConfigError, match=r"^run directory .* is no folder path; give one"):
        train(TrainConfig(algo="npg", n_iter=1, n_traj=2, progress=False), out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_an_npz_log_without_arrays_says_so(tmp_path):
    """Before: "missing column 'time' [s]; its columns: ; name the time stamps' column"."""
    from lowcostdex.gap.dataset import load_dataset
    from lowcostdex.gap.logs import LogError
    from lowcostdex.sim.models.bench import BenchConfig, build_bench

    np.savez(tmp_path / "empty.npz")
    model = tmp_path / "bench.xml"
    model.write_text(build_bench(BenchConfig(motor="XL330-M288")).to_xml())
    with pytest.raises(LogError) as exc:
        load_dataset([tmp_path / "empty.npz"], model=model)
    assert str(exc.value) == ("empty.npz: missing column 'time' [s]; its columns: none (an empty "
                              "NPZ?); name the time stamps' column 'time' (in seconds)")


def test_a_vector_env_of_a_billion_copies_is_refused_before_allocating():
    """Before: ``make_vec(..., num_envs=10**9)`` (a typo for 10**3) ended in MuJoCo's
    "std::bad_alloc" after trying to allocate terabytes."""
    with pytest.raises(ConfigError, match=r"^num_envs=1000000000 is above 100000: each copy "
                                          r"holds ~7 KB of MuJoCo state"):
        make_vec(VALVE, num_envs=10**9)


def test_a_model_that_is_no_model_file_says_what_to_give(tmp_path):
    """Before: MuJoCo's "could not find decoder for resource 'notes.txt'" alone."""
    from lowcostdex.gap.dataset import load_dataset
    from lowcostdex.gap.logs import LogError

    notes = tmp_path / "notes.txt"
    notes.write_text("my notes")
    log = tmp_path / "log.csv"
    log.write_text("time,goal:arm,qpos:arm\n" + "".join(f"{0.01 * k},0,0\n" for k in range(50)))
    with pytest.raises(LogError) as exc:
        load_dataset([log], model=notes)
    assert str(exc.value).startswith(f"{notes}: cannot load the model: ")
    assert str(exc.value).endswith("; give the rig's MJCF model (.xml; `lowcostdex model` writes "
                                   "the project's)")
