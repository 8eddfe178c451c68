"""Careless calls, session 28 (issues 13, 11): each test failed on the code before its fix. The
physics a test needs is written out here in plain MuJoCo; a command is run as a user types it."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from lowcostdex.errors import ConfigError

_TWO = """<mujoco><option timestep="0.002"/><worldbody>
<body><joint name="a" type="hinge" damping="0.1"/>
<geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0" mass="0.1"/></body>
<body pos="0 1 0"><joint name="b" type="hinge" damping="0.1"/>
<geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0" mass="0.1"/></body></worldbody>
<actuator><position name="a" joint="a" kp="2"/><position name="b" joint="b" kp="2"/></actuator>
</mujoco>"""


def _plant(batch: int = 0):
    from lowcostdex.sim.plant import BatchPlant, Plant

    model = mujoco.MjModel.from_xml_string(_TWO)
    return BatchPlant(model, batch, nthread=1) if batch else Plant(model)


_WHAT = "goals of the 2 actuators"


@pytest.mark.parametrize("goal,said", [
    (np.array([0.3]), r"goal of shape \(1,\) must have shape \(2,\): " + _WHAT),
    (0.3, r"goal of shape \(\) must have shape \(2,\): " + _WHAT),
    (np.zeros(3), r"goal of shape \(3,\) must have shape \(2,\): " + _WHAT),
    (np.zeros((2, 2)), r"goal of shape \(2, 2\) must have shape \(2,\): " + _WHAT),
    (np.array([np.nan, 0.0]), r"goal holds nan: must be finite numbers, " + _WHAT),
    (np.array([0.0, -np.inf]), r"goal holds -inf: must be finite numbers, " + _WHAT),
    (np.array([0.0, 1e12]), r"goal holds 1e\+12: must be at most 1e\+10 in size, " + _WHAT),
    (["0.1", "0.2"], r"goal holds '0.1', not numbers: " + _WHAT),
])
def test_a_plant_step_refuses_a_goal_it_would_broadcast_or_mujoco_would_zero(goal, said):
    # before: a (1,) or scalar goal drove both actuators to one angle without a word; a NaN,
    # inf or 1e12 goal made MuJoCo zero every control of the step (a printed warning only);
    # text goals a numpy error
    plant = _plant()
    with pytest.raises(ConfigError, match=said + r": positions \[rad\]"):
        plant.step(goal, 2)
    assert plant.time == 0.0 and not plant.ctrl.any()


@pytest.mark.parametrize("nstep", [0, -3, 2.5, "3", True, None])
def test_a_plant_step_refuses_a_count_of_substeps_that_is_no_count(nstep):
    # before: 0 and -3 stepped nothing without a word, 2.5 and "3" ended in MuJoCo's binding
    # error, True stepped once
    plant = _plant()
    with pytest.raises(ConfigError, match=rf"nstep \(physics substeps\)={nstep!r} must be an "
                                          r"integer in \[1, inf\)"):
        plant.step(np.zeros(2), nstep)
    assert plant.time == 0.0


def test_a_plant_step_with_good_arguments_is_unchanged():
    # the checks let every good call through: numpy counts, lists, a batch's (nu,) and
    # (nsim, nu) goals, and the numbers are those of plain MuJoCo's own position servo
    plant = _plant()
    plant.step([0.1, 0.2], np.int64(3))
    model = mujoco.MjModel.from_xml_string(_TWO)
    data = mujoco.MjData(model)
    data.ctrl[:] = [0.1, 0.2]
    mujoco.mj_step(model, data, nstep=3)
    np.testing.assert_array_equal(plant.qpos, data.qpos)
    batch = _plant(3)
    batch.step(np.array([0.1, 0.2]), 3)
    batch.step(np.zeros((3, 2)), 1)
    with pytest.raises(ConfigError, match=r"shape \(2,\) or \(3, 2\): goals of the 2 actuators "
                                          r"\(per simulation\)"):
        batch.step(np.zeros((2, 2)), 1)


@pytest.mark.parametrize("state,said", [
    (dict(qpos=0.3), r"qpos of shape \(\) must have shape \(2,\)"),
    (dict(qpos=[0.3]), r"qpos of shape \(1,\) must have shape \(2,\)"),
    (dict(qvel=[0.0, np.nan]), r"qvel holds nan: must be finite numbers"),
    (dict(ctrl=np.zeros(3)), r"ctrl of shape \(3,\) must have shape \(2,\)"),
])
def test_a_plant_reset_refuses_a_state_of_another_shape_or_not_finite(state, said):
    # before: a scalar or (1,) qpos was broadcast to every joint; a NaN qvel made MuJoCo reset
    # the simulation at the next step with a printed warning
    with pytest.raises(ConfigError, match=said):
        _plant().reset(**state)
    with pytest.raises(ConfigError, match=r"qpos of shape \(2,\) must have shape \(3, 2\)"):
        _plant(3).reset(qpos=np.zeros(2))  # (before: each simulation given one number)


def test_the_same_log_twice_from_python_is_refused_naming_it(tmp_path):
    # before: load_dataset([a, a]) read and fitted the log twice (the CLI uses it once with a
    # note); a folder and a file in it, or two spellings of one path, too
    from lowcostdex.gap.dataset import load_dataset
    from lowcostdex.gap.logs import LogError, Trajectory, write_log

    (tmp_path / "m.xml").write_text(_TWO)
    t = np.arange(200) * 0.01
    goal = np.stack([0.2 * np.sin(t), 0.1 * np.cos(t)], axis=1)
    log = write_log(tmp_path / "a.csv", Trajectory("a", t, goal, goal.copy(), ("a", "b"),
                                                   ("a", "b")))
    model = tmp_path / "m.xml"
    assert len(load_dataset([log], model=model).trajectories) == 1
    with pytest.raises(LogError, match=r"a.csv: the same log given twice; each log is fitted "
                                       r"once: give it once"):
        load_dataset([log, log], model=model)
    with pytest.raises(LogError, match=r"the same log given twice \(as .*a.csv and as "
                                       r".*sub/\.\./a.csv\)"):
        (tmp_path / "sub").mkdir()
        load_dataset([tmp_path, tmp_path / "sub" / ".." / "a.csv"], model=model)


def _policy():
    import torch

    from lowcostdex.algos.configs import PolicyConfig
    from lowcostdex.algos.policy import GaussianMLPPolicy

    return GaussianMLPPolicy(4, 2, PolicyConfig(hidden_sizes=(8,)), torch.Generator().manual_seed(0))


def _batch(n: int = 20):
    rng = np.random.default_rng(0)
    return rng.normal(size=(n, 4)), rng.uniform(-1, 1, size=(n, 2)), rng.normal(size=n)


_OBS = r"one observation per row, 4 numbers \(the policy's obs_dim\)"


@pytest.mark.parametrize("edit,said", [
    (lambda o, a, v: (np.where(np.arange(4) == 1, np.nan, o), a, v), r"obs holds nan \(row 0\): "
     r"must be finite numbers, " + _OBS),
    (lambda o, a, v: (o[:, :3], a, v), r"obs of shape \(20, 3\) must have shape \(n, 4\) with "
     r"n >= 1: " + _OBS),
    (lambda o, a, v: (o, a[:, :1], v), r"actions of shape \(20, 1\) must have shape \(20, 2\): "
     r"one action per observation, 2 numbers in \[-1, 1\]"),
    (lambda o, a, v: (o[:0], a[:0], v[:0]), r"obs of shape \(0, 4\) must have shape \(n, 4\) "
     r"with n >= 1"),
    (lambda o, a, v: (o, a, v[:5]), r"advantages of shape \(5,\) must have shape \(20,\)"),
    (lambda o, a, v: (o, a, v * np.nan), r"advantages holds nan \(row 0\)"),
])
def test_an_update_refuses_a_batch_it_would_broadcast_or_turn_to_nan(edit, said):
    # before: a NaN observation or advantage made the clone's / the step's statistics NaN
    # without a word, actions of one column for two were broadcast, an empty batch gave NaN
    # statistics, a wrong width failed deep in torch (RuntimeError: size of tensor a ...)
    import torch

    from lowcostdex.algos.bc import behavior_clone
    from lowcostdex.algos.configs import BCConfig, DAPGConfig, NPGConfig
    from lowcostdex.algos.dapg import dapg_update
    from lowcostdex.algos.npg import npg_update

    obs, actions, adv = edit(*_batch())
    good_obs, good_actions, _ = _batch()
    calls = [lambda p: npg_update(p, obs, actions, adv, NPGConfig()),
             lambda p: dapg_update(p, obs, actions, adv, good_obs, good_actions, 0, DAPGConfig(),
                                   NPGConfig())]
    if "advantages" not in said:
        calls.append(lambda p: behavior_clone(p, obs, actions, BCConfig(epochs=1),
                                              torch.Generator().manual_seed(1)))
    for call in calls:
        policy = _policy()
        before = torch.nn.utils.parameters_to_vector(policy.parameters()).clone()
        with pytest.raises(ConfigError, match=said):
            call(policy)
        assert torch.equal(torch.nn.utils.parameters_to_vector(policy.parameters()), before)


def test_dapg_with_no_demo_pairs_or_bc_with_no_generator_is_refused():
    # before: dapg_update with a zero-length demo set stepped as plain NPG without a word;
    # behavior_clone(generator=0) failed in torch.randperm, None shuffled by torch's global RNG
    import torch

    from lowcostdex.algos.bc import behavior_clone
    from lowcostdex.algos.configs import BCConfig, DAPGConfig, NPGConfig
    from lowcostdex.algos.dapg import dapg_update

    obs, actions, adv = _batch()
    with pytest.raises(ConfigError, match=r"demo_obs of shape \(0, 4\) must have shape \(n, 4\) "
                                          r"with n >= 1"):
        dapg_update(_policy(), obs, actions, adv, obs[:0], actions[:0], 0, DAPGConfig(),
                    NPGConfig())
    with pytest.raises(ConfigError, match=r"demo_obs of shape \(20, 3\)"):
        dapg_update(_policy(), obs, actions, adv, obs[:, :3], actions, 0, DAPGConfig(),
                    NPGConfig())
    for generator in (0, None):
        with pytest.raises(ConfigError, match=rf"generator={generator!r} must be a seeded "
                                              r"torch.Generator"):
            behavior_clone(_policy(), obs, actions, BCConfig(epochs=1), generator)
    stats = behavior_clone(_policy(), torch.as_tensor(obs), actions, BCConfig(epochs=1),
                           torch.Generator().manual_seed(1))  # tensors are taken as before
    assert np.isfinite(stats["bc_loss_after"])


@pytest.fixture
def demo_file(tmp_path):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from pointmass import demo_info, expert_action, make_pointmass

    from lowcostdex.demonstrations.dataset import save_demos, teacher_episodes

    episodes = teacher_episodes(make_pointmass(), lambda env, obs: expert_action(obs), seeds=[1, 2])
    return save_demos(tmp_path / "d.h5", episodes, demo_info()), episodes, demo_info()


@pytest.mark.parametrize("edit,said", [
    (lambda f: f.attrs.__delitem__("env_id"), r"d.h5: env_id is missing"),
    (lambda f: f.attrs.__delitem__("total_episodes"), r"d.h5: total_episodes is missing"),
    (lambda f: f.attrs.__setitem__("action_joints", "x"), r"d.h5: action_joints is not a JSON "
                                                         r"list of joint names: 'x'"),
])
def test_a_demo_file_missing_a_key_is_named_by_read_info(demo_file, edit, said):
    # before: a bare KeyError from h5py ("Unable to synchronously open attribute") or a
    # JSONDecodeError, also from check_demos when a run trains on the file
    import h5py

    from lowcostdex.demonstrations.file import read_info
    from lowcostdex.errors import InputError

    path = demo_file[0]
    with h5py.File(path, "a") as f:
        edit(f)
    with pytest.raises(InputError, match=said):
        read_info(path)


def test_a_label_model_of_an_episode_the_file_has_not_is_named(demo_file):
    # before: KeyError "object 'episode_9' doesn't exist"
    from lowcostdex.demonstrations.file import read_label_model
    from lowcostdex.errors import InputError

    assert read_label_model(demo_file[0], 1) is None
    with pytest.raises(InputError, match=r"d.h5: no episode 9; it holds episodes 0 to 1"):
        read_label_model(demo_file[0], 9)


def test_careless_demo_set_calls_are_refused(demo_file, tmp_path):
    # before: Demos.first(0) gave every episode and first(-1) all but the last; a demo set of
    # episodes of 0 steps loaded as no pairs; save_demos into a folder left NAME.partial beside
    # it and raised IsADirectoryError; an episode with a NaN observation was written (and the
    # whole file then refused by load_demos); save_demos(path, [1, 2], None): AttributeError
    from lowcostdex.demonstrations.dataset import load_demos, save_demos
    from lowcostdex.demonstrations.file import Episode

    path, episodes, info = demo_file
    demos = load_demos(path)
    assert demos.first(1).n_episodes == 1 and demos.first(None).n_episodes == 2
    for n in (0, -1, 1.5):
        with pytest.raises(ConfigError, match=rf"n \(demo episodes\)={n!r} must be an integer "
                                              r"in \[1, inf\) or None"):
            demos.first(n)
    e = episodes[0]
    empty = Episode(e.observations[:1], e.actions[:0], e.rewards[:0], e.qpos[:1], e.qvel[:1],
                    e.time[:1], e.success[:0])
    save_demos(tmp_path / "z.h5", [empty], info)
    with pytest.raises(ConfigError, match=r"z.h5: its 1 episode\(s\) have 0 steps: no "
                                          r"observation-action pair"):
        load_demos(tmp_path / "z.h5", only_successful=False)
    folder = tmp_path / "demos"
    folder.mkdir()
    with pytest.raises(ConfigError, match=r"demos is a folder; give the demo file"):
        save_demos(folder, episodes, info)
    nan = Episode(e.observations * np.nan, e.actions, e.rewards, e.qpos, e.qvel, e.time,
                  e.success)
    with pytest.raises(ConfigError, match=r"episode observations\[0, 0\] = nan is not finite: "
                                          r"the episode is not written"):
        save_demos(tmp_path / "n.h5", [nan], info)
    with pytest.raises(ConfigError, match=r"takes a list of Episode and a DatasetInfo, not int"):
        save_demos(tmp_path / "x.h5", [1, 2], info)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.h5", "demos", "z.h5"]
    assert not any(folder.iterdir())


@pytest.mark.parametrize("baud,said", [
    ("0", "--baud 0: the bit rate must be positive"),
    ("-0", "--baud 0: the bit rate must be positive"),
    ("-1", "--baud -1: the bit rate must be positive"),
    ("250000", "--baud 250000: the emulated motors run at one of 9600, 57600"),
])
def test_record_log_checks_its_bit_rate_as_scan_does(baud, said, tmp_path, capsys):
    # before: `record-log --baud 0` on the emulated robot recorded at 1 Mbit/s (0 read as 'not
    # given'), -1 and 250000 were taken too; scan refused them
    from lowcostdex.cli import USER_ERROR, main

    out = tmp_path / "logs"
    assert main(["record-log", "--port", "emulated", "--baud", baud, "--out", str(out)]) \
        == USER_ERROR
    assert said in capsys.readouterr().err
    assert not out.exists()
    assert main(["scan", "--port", "emulated", "--baud", baud]) == USER_ERROR
    assert said in capsys.readouterr().err


def test_a_joint_mask_given_to_the_robot_as_goals_is_refused():
    # before: robot.send(np.ones(9, bool)) sent 1 rad to every joint (0 rad for False): the gate
    # took True/False as numbers
    from lowcostdex.hardware.robot.safety import UnsafeCommand, check_finite

    names = ("ff_top", "ff_middle")
    with pytest.raises(UnsafeCommand, match=r"goal array\(\[ True, False\]\) is not 2 numbers "
                                            r"\[rad\] for joints ff_top, ff_middle; nothing sent"):
        check_finite(np.array([True, False]), names)
    np.testing.assert_array_equal(check_finite(np.array([1, 0]), names), [1.0, 0.0])


@pytest.mark.parametrize("kwargs,said", [
    (dict(rng=0), r"rng=0 must be a seeded numpy Generator, e.g. np.random.default_rng\(0\)"),
    (dict(wire_time="no"), r"wire_time='no' must be True or False"),
    (dict(record_replies="no"), r"record_replies='no' must be True or False"),
    (dict(supply_resistance=-1.0), r"supply_resistance \[Ohm\]=-1.0 must be a finite number in "
                                   r"\[0, inf\)"),
    (dict(supply_resistance=float("nan")), r"supply_resistance \[Ohm\]=nan"),
    (dict(effects="latency"), r"effects are a list of AppliedEffect, e.g. \[AppliedEffect\("
                              r"'latency', .*got 'latency'"),
])
def test_an_emulated_robot_built_with_careless_settings_says_which(kwargs, said):
    # before: rng=0 was kept and failed at the first noisy draw ('int' object has no attribute
    # ...), 'no' switched the wire timing and the reply recording ON, a negative or NaN supply
    # resistance ran (a supply voltage rising with the current), effects="latency" ended in
    # "'str' object has no attribute 'cls'"
    from lowcostdex.hardware.emulated.chain import emulated_bench

    with pytest.raises(ConfigError, match=said):
        emulated_bench(**kwargs)


def test_a_plant_given_one_effect_or_a_name_or_a_seed():
    # before: Plant(model, "latency") said "per-simulation effects need one list per simulation"
    # (a single plant), one AppliedEffect was refused the same way, rng=0 failed at a draw
    from lowcostdex.sim.effects import AppliedEffect
    from lowcostdex.sim.plant import Plant

    model = mujoco.MjModel.from_xml_string(_TWO)
    with pytest.raises(ConfigError, match=r"effects are a list of AppliedEffect; got 'latency'"):
        Plant(model, "latency")
    with pytest.raises(ConfigError, match=r"rng=3 must be a seeded numpy Generator"):
        Plant(model, rng=3)
    one = AppliedEffect("gain_error", ("a",), {"scale": 0.5})
    single, listed = Plant(model, one), Plant(model, [one])
    for p in (single, listed):
        p.step(np.array([0.2, 0.2]), 5)
    np.testing.assert_array_equal(single.qpos, listed.qpos)


@pytest.mark.parametrize("t_src,values,t_dst,said", [
    ([0.2, 0.1, 0.0], [1.0, 2.0, 3.0], [0.15], r"t_src must be finite, strictly increasing"),
    ([0.0, np.nan, 0.2], [1.0, 2.0, 3.0], [0.15], r"t_src must be finite, strictly increasing"),
    ([0.0, 0.1, 0.2], [1.0, 2.0], [0.15], r"t_src of shape \(3,\) and values of shape \(2,\)"),
    ([0.0, 0.1, 0.2], [1.0, 2.0, 3.0], [np.nan], r"t_dst holds nan: times \[s\] are finite"),
])
def test_zoh_refuses_times_it_would_hold_wrongly(t_src, values, t_dst, said):
    # before: unsorted source times or a NaN destination time gave a wrong hold without a word
    # (zoh([0.2, 0.1, 0], [1, 2, 3], [0.15]) held 3; a NaN destination held the last value),
    # and values shorter than the times were indexed past their end
    from lowcostdex.gap import LogError, zoh

    with pytest.raises(LogError, match=said):
        zoh(np.array(t_src), np.array(values), np.array(t_dst))
    np.testing.assert_array_equal(zoh(np.array([0.0, 0.1]), np.array([1.0, 2.0]),
                                      np.array([-1.0, 0.1, 5.0])), [1.0, 2.0, 2.0])


def test_save_extended_refuses_a_model_that_does_not_compile_or_a_file(tmp_path):
    # before: an unparsable model was written and load_extended refused the folder later; a
    # folder path that is a file gave FileExistsError
    from lowcostdex.gap import load_extended, save_extended

    with pytest.raises(ConfigError, match=r"model 'arm' does not compile: "):
        save_extended(tmp_path / "ext", {"arm": "<mujoco"}, [])
    assert not (tmp_path / "ext").exists()
    (tmp_path / "file").write_text("mine")
    with pytest.raises(ConfigError, match=r"file is a file; save_extended writes a folder"):
        save_extended(tmp_path / "file", {"arm": _TWO}, [])
    assert load_extended(save_extended(tmp_path / "ok", {"arm": _TWO}, [])).effects == []


@pytest.mark.parametrize("kwargs,said", [
    (dict(seeds=[1, 1]), r"seed 1 given twice: the same episode would be recorded twice"),
    (dict(seeds="12"), r"seeds='12' must be a list of reset seeds, e.g. range\(25\)"),
    (dict(seeds=5), r"seeds=5 must be a list of reset seeds"),
    (dict(seeds=[1.5]), r"seed=1.5 must be an integer in \[0, inf\)"),
    (dict(seeds=[1], max_tries=0), r"max_tries=0 must be an integer in \[1, inf\)"),
    (dict(seeds=[1], action_noise=-0.1), r"action_noise=-0.1 must be a finite number in \[0, 2\]"),
    (dict(seeds=[1], action_noise=float("nan")), r"action_noise=nan"),
])
def test_teacher_episodes_refuses_careless_seeds_and_settings(kwargs, said):
    # before: seeds [1, 1] recorded one episode twice (a deterministic teacher: identical
    # pairs weighing double), the string "12" recorded seeds 1 and 2, an int raised TypeError,
    # max_tries=0 said "the teacher failed 0 times from seed 1", a negative or NaN noise ran
    # noiseless without a word
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from pointmass import expert_action, make_pointmass

    from lowcostdex.demonstrations.dataset import teacher_episodes

    with pytest.raises(ConfigError, match=said):
        teacher_episodes(make_pointmass(), lambda env, obs: expert_action(obs), **kwargs)


def test_a_hidden_robots_chain_given_a_seed_for_rng_says_so():
    # before: HiddenRobot.chain(rng=0) dropped the 0 ('rng or default_rng(self.seed)') and ran
    # on the robot's own seed without a word (rng=5 failed at a draw deep inside)
    from lowcostdex.hardware.emulated.hidden_robots import hidden_robots

    robot = hidden_robots(1)[0]
    with pytest.raises(ConfigError, match=r"rng=0 must be a seeded numpy Generator"):
        robot.chain("none", rng=0)
