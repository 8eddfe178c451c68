"""Careless calls, session 29 (issues 13, 11): each test failed on the code before its fix. The
physics a test needs is written out here in plain MuJoCo; a command is run as a user types it."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from test_careless25 import _TWO  # two hinges on plain position servos (kp 2)

from lowcostdex.errors import ConfigError


def _trajectory(t: np.ndarray, name: str = "arm"):
    from lowcostdex.gap.trajectory import Trajectory

    goal = np.stack([0.2 * np.sin(t), 0.1 * np.cos(t)], axis=1)
    return Trajectory(name, t, goal, goal.copy(), ("a", "b"), ("a", "b"))


# -- leftovers of session 28 ------------------------------------------------------------------

@pytest.mark.parametrize("edit,said", [
    (lambda t: t[::-1].copy(), r"time\[1\]=1\.98 is before time\[0\]=1\.99"),
    (lambda t: np.concatenate([t[:100], t[100:][::-1]]), r"time\[101\]=1\.98 is before "
                                                          r"time\[100\]=1\.99"),
    (lambda t: np.where(np.arange(len(t)) == 7, t[6], t), r"time\[7\]=0\.06 repeats time\[6\]"),
    (lambda t: np.where(np.arange(len(t)) == 3, np.nan, t), r"time\[3\] is nan: sample times "
                                                            r"\[s\] must be finite"),
])
@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_write_log_refuses_times_that_do_not_increase(edit, said, suffix, tmp_path):
    # before: written without a word (the reader sorts a little disorder with a note, refuses
    # the rest): the file written is not the trajectory given
    from lowcostdex.gap.logs import LogError, write_log

    tr = _trajectory(edit(np.arange(200) * 0.01))
    with pytest.raises(LogError, match=r"Trajectory 'arm': " + said if "nan" in said else
                       r"Trajectory 'arm': time must be strictly increasing \[s\], but " + said):
        write_log(tmp_path / f"arm{suffix}", tr)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("kwargs,said", [
    ({"events_kept": 0}, "EmulatedChain events_kept=0"),
    ({"replies_kept": 1.5}, "EmulatedChain replies_kept=1.5"),
    ({"events_kept": "100"}, "EmulatedChain events_kept='100'"),
])
def test_an_emulated_chain_names_a_bad_count_of_entries_kept(kwargs, said):
    # before: events_kept=0 gave RingLog's "RingLog needs maxlen >= 1", not naming the option;
    # replies_kept=1.5 was taken (and kept 1 reply); "100" a TypeError
    from lowcostdex.hardware.emulated.chain import emulated_bench

    with pytest.raises(ConfigError, match=said + r" must be an integer in \[1, inf\)"):
        emulated_bench(**kwargs)


def test_a_replayer_refuses_what_is_no_dataset_or_a_goal_it_cannot_replay():
    # before: Replayer(None) raised AttributeError ('NoneType' object has no attribute
    # 'trajectories'); a NaN goal of a Dataset built in Python was refused by the plant at the
    # first step, without naming the trajectory (the replay now steps its plant unchecked)
    from lowcostdex.gap.dataset import Dataset
    from lowcostdex.gap.replay import Replayer

    for ds in (None, "logs/arm.csv"):
        with pytest.raises(ConfigError, match=r"Replayer\(ds\) replays a lowcostdex.gap.Dataset "
                                              r"\(from load_dataset\), not "):
            Replayer(ds)
    tr = _trajectory(np.arange(200) * 0.01)
    tr.goal[50, 1] = np.nan
    with pytest.raises(ConfigError, match=r"trajectory 'arm': goal holds nan: must be finite "
                                          r"numbers, goals of the actuators a, b"):
        Replayer(Dataset({"model": _TWO}, [tr]))


@pytest.mark.parametrize("env_id,goal,said", [
    ("lowcostdex/DClawTurnValve-v0", {"angle": 400.0},
     r"goal\['angle'\]=400.0 is outside \[-18.85, 18.85\] rad, the farthest this task's settings "
     r"reach; in rad, not deg \(400 deg is 6.981 rad\)"),
    ("lowcostdex/DClawTurnValve-v0", {"angle": -90},
     r"goal\['angle'\]=-90 is outside \[-18.85, 18.85\] rad"),
    ("lowcostdex/AllegroTurnValve-v0", {"angle": 360.0},
     r"goal\['angle'\]=360.0 is outside \[-18.85, 18.85\] rad.*\(360 deg is 6.283 rad\)"),
    ("lowcostdex/DClawScrew-v0", {"angle": 0.0, "start": 0.0, "speed": 30.0},
     r"goal\['speed'\]=30.0 is outside \[-6.283, 6.283\] rad/s, the farthest this task's "
     r"settings reach; in rad/s, not deg/s \(30 deg/s is 0.5236 rad/s\)"),
])
def test_a_valve_reset_goal_in_degrees_is_refused(env_id, goal, said):
    # before: taken (a goal of 400 rad: 64 turns); the configs' goal_offset had a bound (+-4 pi)
    # but a goal given at reset none
    import gymnasium as gym

    import lowcostdex  # noqa: F401

    env = gym.make(env_id)
    try:
        with pytest.raises(ValueError, match=r"reset option " + said):
            env.reset(seed=0, options={"goal": goal})
        fine = {k: 6 * math.pi if k == "angle" else 0.5 for k in goal}  # at the bound: taken
        env.reset(seed=0, options={"goal": fine})
        assert float(env.unwrapped._goal["angle"]) == fine["angle"]
    finally:
        env.close()


@pytest.mark.parametrize("kwargs,said", [
    ({"frame_skip": 0}, r"TaskSpec.frame_skip \(physics substeps\)=0"),
    ({"frame_skip": 2.5}, r"TaskSpec.frame_skip \(physics substeps\)=2.5"),
    ({"episode_steps": -1}, r"TaskSpec.episode_steps=-1"),
])
def test_a_task_timing_that_is_no_count_is_refused_where_made(kwargs, said):
    # before: taken; a frame_skip of 0 was refused by Plant.step at the first env step (the env
    # now steps its plant unchecked), 2.5 likewise; episode_steps=-1 truncated every step
    from lowcostdex.sim.envs.task import TaskSpec

    with pytest.raises(ConfigError, match=said + r" must be an integer in \[1, inf\)"):
        TaskSpec(**kwargs)


def test_the_unchecked_step_is_the_checked_step_to_the_bit():
    # the replay's and envs' path: Plant.step_unchecked (did not exist before); the physics of
    # a plain MuJoCo position servo, stepped beside it, and Plant.step give the same bits
    from lowcostdex.sim.plant import BatchPlant, Plant

    model = mujoco.MjModel.from_xml_string(_TWO)
    rng = np.random.default_rng(3)
    goals = rng.uniform(-0.5, 0.5, (30, 2))
    data = mujoco.MjData(model)
    checked, unchecked = Plant(model), Plant(model)
    for g in goals:
        data.ctrl[:] = g
        mujoco.mj_step(model, data, nstep=3)
        checked.step(g, 3)
        unchecked.step_unchecked(g, 3)
        assert np.array_equal(unchecked.qpos, data.qpos)
        assert np.array_equal(checked.qpos, data.qpos)
    a, b = BatchPlant(model, 3, nthread=1), BatchPlant(model, 3, nthread=1)
    for g in goals:
        a.step(np.stack([g, -g, 0 * g]), 2)
        b.step_unchecked(np.stack([g, -g, 0 * g]), 2)
    assert np.array_equal(a.qpos, b.qpos) and np.array_equal(a.qvel, b.qvel)


def test_env_steps_skip_the_goal_check_the_public_step_keeps(monkeypatch):
    # before: every env step (and replay step) paid Plant.step's argument check (2-4 us a call,
    # 10-20 % of a one-substep step); their goals come from checked actions and logs
    import gymnasium as gym

    import lowcostdex  # noqa: F401
    from lowcostdex.sim import plant as plant_module
    from lowcostdex.sim.vector import make_vec

    calls = []
    real = plant_module.check_finite_array
    monkeypatch.setattr(plant_module, "check_finite_array",
                        lambda *a, **k: calls.append(a[0]) or real(*a, **k))
    env = gym.make("lowcostdex/DClawTurnValve-v0")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    vec = make_vec("lowcostdex/DClawTurnValve-v0", num_envs=2, nthread=1)
    vec.reset(seed=0)
    vec.step(np.zeros(vec.action_space.shape))
    assert "goal" not in calls and calls  # (reset still checks its qpos and qvel)
    with pytest.raises(ConfigError, match=r"goal of shape \(1,\)"):
        env.unwrapped.backend.plant.step(np.zeros(1), 1)  # the public call: still checked
    env.close()
    vec.close()


# -- fresh hunt: learned local models (TVLG fit, KL-iLQG) --------------------------------------

def _rollouts(n: int = 5, t: int = 10):
    rng = np.random.default_rng(0)
    return rng.normal(size=(n, t, 4)), rng.normal(size=(n, t, 2))


_SHAPES = r"must be \(N, T, dX\) and \(N, T, dU\) with the same N >= 1 rollouts and T >= 2 steps"


@pytest.mark.parametrize("edit,said", [
    (lambda X, U: (X, U[:, :9]), r"X \(5, 10, 4\) and U \(5, 9, 2\) " + _SHAPES),
    (lambda X, U: (X, U[:4]), r"X \(5, 10, 4\) and U \(4, 10, 2\) " + _SHAPES),
    (lambda X, U: (X[:0], U[:0]), r"X \(0, 10, 4\) and U \(0, 10, 2\) " + _SHAPES),
    (lambda X, U: (X[:, :1], U[:, :1]), r"X \(5, 1, 4\) and U \(5, 1, 2\) " + _SHAPES),
    (lambda X, U: (X[0], U[0]), r"X of shape \(10, 4\) must be \(N, T, dX\): N rollouts of T "
                                r"steps of dX states \(one rollout: X\[None\]\)"),
    (lambda X, U: (X, np.where(np.arange(10)[None, :, None] == 3, np.inf, U)),
     r"rollout data contains NaN or inf: U\[0, 3, 0\] = inf; cannot fit dynamics"),
])
def test_fit_dynamics_names_rollouts_it_cannot_fit(edit, said):
    # before: numpy's concatenate error (other T or N), "not enough values to unpack" (one
    # rollout given as (T, dX)), "negative dimensions" (T=0), and 0 rollouts fitted NaN
    # dynamics without a word (a RuntimeWarning of numpy's only)
    from lowcostdex.algos.local_models.dynamics import DynamicsConfig, fit_dynamics

    with pytest.raises(ConfigError, match=said):
        fit_dynamics(*edit(*_rollouts()), DynamicsConfig(use_prior=False))


def test_fit_dynamics_takes_lists_and_names_a_singular_fit_or_a_missing_config():
    # before: lists raised AttributeError ('list' object has no attribute 'shape'), a fit whose
    # data span fewer dimensions than [x, u] with regularization 0 numpy's LinAlgError
    # "Singular matrix", cfg=None AttributeError
    from lowcostdex.algos.local_models.dynamics import DynamicsConfig, fit_dynamics

    X, U = _rollouts()
    cfg = DynamicsConfig(use_prior=False)
    assert np.array_equal(fit_dynamics(X.tolist(), U.tolist(), cfg).F, fit_dynamics(X, U, cfg).F)
    with pytest.raises(ConfigError, match=r"the 1 rollouts' \[x, u\] at step 0 span fewer than "
                                          r"their 6 dimensions .*regularization=1e-6"):
        fit_dynamics(X[:1], U[:1], DynamicsConfig(use_prior=False, regularization=0.0))
    with pytest.raises(ConfigError, match=r"cfg=None must be a DynamicsConfig"):
        fit_dynamics(X, U, None)


_PD = dict(x0=np.zeros(4), u0=np.zeros(2), T=5, pos_index=[0, 1], vel_index=[2, 3],
           pos_gain=1.0, vel_gain=0.1, noise_var=0.1)


@pytest.mark.parametrize("change,said", [
    ({"T": 0}, r"pd_controller T \(horizon, steps\)=0 must be an integer in \[1, inf\)"),
    ({"T": 2.5}, r"pd_controller T \(horizon, steps\)=2.5 must be an integer"),
    ({"pos_gain": np.nan}, r"pd_controller pos_gain=nan must be a finite number"),
    ({"noise_var": np.nan}, r"noise_var \(action units squared\)=nan must be a finite number in "
                            r"\(0, inf\)"),
    ({"pos_index": [0, 7]}, r"pd_controller state index=7 must be an integer in \[-4, 3\]"),
    ({"x0": np.array([np.nan, 0, 0, 0])}, r"pd_controller x0=.* must be a 1-D array of finite"),
    ({"u0": 0.0, "pos_index": [0], "vel_index": [2]}, r"pd_controller u0=array\(0\.\) must be "
                                                      r"a 1-D array"),
])
def test_pd_controller_names_a_careless_setting(change, said):
    # before: T=0 gave an empty controller, a NaN gain, noise or start state a NaN controller
    # without a word; T=2.5 a TypeError, index 7 an IndexError, a scalar u0 "tuple index out
    # of range"
    from lowcostdex.algos.local_models.controller import pd_controller

    with pytest.raises(ConfigError, match=said):
        pd_controller(**{**_PD, **change})


def test_a_controller_or_its_noise_from_careless_arrays_is_named():
    # before: a NaN gain made a controller acting NaN; a (T, dX) K "not enough values to
    # unpack"; exploration_noise(T=-1) numpy's "negative dimensions", smooth_sigma=nan taken
    from lowcostdex.algos.local_models.controller import (
        LinearGaussianController,
        exploration_noise,
    )

    cov = np.broadcast_to(np.eye(2), (3, 2, 2))
    with pytest.raises(ConfigError, match=r"controller K holds NaN or inf \(first at index "
                                          r"\(0, 0, 0\)\)"):
        LinearGaussianController.from_cov(np.full((3, 2, 4), np.nan), np.zeros((3, 2)), cov)
    with pytest.raises(ConfigError, match=r"K of shape \(2, 4\) must be \(T, dU, dX\)"):
        LinearGaussianController.from_cov(np.zeros((2, 4)), np.zeros((3, 2)), cov)
    rng = np.random.default_rng(0)
    with pytest.raises(ConfigError, match=r"exploration_noise T \(steps\)=-1 must be an integer"):
        exploration_noise(rng, -1, 2)
    with pytest.raises(ConfigError, match=r"smooth_sigma \(steps\)=nan must be a finite number"):
        exploration_noise(rng, 5, 2, np.nan)


def test_a_kl_update_of_other_sizes_or_a_nan_budget_is_named():
    # before: a controller of another horizon than the model failed in numpy's matmul deep in
    # the backward pass; a NaN epsilon or eta ran the whole dual search on NaN
    from lowcostdex.algos.local_models.controller import LinearGaussianController
    from lowcostdex.algos.local_models.costs import QuadraticCost
    from lowcostdex.algos.local_models.dynamics import LinearGaussianDynamics
    from lowcostdex.algos.local_models.traj_opt import TrajOptConfig, kl_constrained_update

    T = 6  # a point mass: x' = x + 0.1 u (dX = dU = 1)
    dyn = LinearGaussianDynamics(np.tile([[1.0, 0.1]], (T - 1, 1, 1)), np.zeros((T - 1, 1)),
                                 np.full((T - 1, 1, 1), 1e-4), np.ones(1), np.full((1, 1), 1e-6))
    cost = QuadraticCost(np.tile(np.diag([1.0, 0.01]), (T, 1, 1)), np.zeros((T, 2)), np.zeros(T))

    def ctl(t):
        return LinearGaussianController.from_cov(np.zeros((t, 1, 1)), np.zeros((t, 1)),
                                                 np.ones((t, 1, 1)))

    assert kl_constrained_update(dyn, cost, ctl(T), 0.5, 1.0, TrajOptConfig()).kl > 0
    with pytest.raises(ConfigError, match=r"dynamics F has shape \(5, 1, 2\); the controller "
                                          r"\(T=8, dU=1, dX=1\) needs \(7, 1, 2\)"):
        kl_constrained_update(dyn, cost, ctl(8), 0.5, 1.0, TrajOptConfig())
    for eps, eta, said in ((np.nan, 1.0, r"epsilon \(KL budget, nats\)=nan"),
                           (0.5, np.nan, r"eta \(dual variable\)=nan")):
        with pytest.raises(ConfigError, match=said + r" must be a finite number in \(0, inf\)"):
            kl_constrained_update(dyn, cost, ctl(T), eps, eta, TrajOptConfig())


# -- fresh hunt: the main job from Python --------------------------------------------------------

@pytest.mark.parametrize("kwargs,said", [
    ({"size": "huge"}, r"unknown main job size 'huge'"),
    ({"task": "valve_target"}, r"unknown main job task 'valve_target'.*did you mean "
                               r"'valve-target'"),
    ({"seed": -1}, r"Context.seed=-1 must be an integer in \[0, inf\)"),
    ({"seed": "1"}, r"Context.seed='1' must be an integer"),
    ({"port": 0}, r"Context.port=0 must be a serial port path"),
    ({"out": None}, r"a file or folder path .* not NoneType"),
])
def test_a_main_job_context_with_a_careless_setting_is_refused_where_made(kwargs, said,
                                                                          tmp_path):
    # before: all taken; size 'huge' and task 'valve_target' failed with a KeyError inside the
    # first stage that read them, a seed '1' in numpy's default_rng, port 0 was a robot port
    from lowcostdex.main_job.setup import Context

    with pytest.raises(ConfigError, match=said):
        Context(**{"out": tmp_path, **kwargs})


def test_the_main_job_from_python_refuses_stages_it_would_not_run(tmp_path):
    # before: run(ctx, ("nope",)) ran no stage and wrote an empty report.md; a str was matched
    # by substring ('train' ran train, 'bus,demo' ran bus only); out='folder' (a str) failed
    # in the first stage writing results.json
    from lowcostdex.main_job.job import run
    from lowcostdex.main_job.setup import Context

    ctx = Context(out=str(tmp_path / "run"))
    assert ctx.out == tmp_path / "run"
    for stages, said in ((("nope",), r"unknown stage 'nope'"), ("gap", r"stages='gap' must be "
                         r"None \(every stage\) or a non-empty tuple of stage names, e.g. "
                         r"\('gap',\); valid: bus, demos, gap, train, report"), ((), "stages=()")):
        with pytest.raises(ConfigError, match=said):
            run(ctx, stages)
    assert not (tmp_path / "run").exists()


# -- fresh hunt: the Allegro on its CAN bus ------------------------------------------------------

def test_an_emulated_allegro_answers_on_the_device_id_its_bus_is_given():
    # before: emulated_allegro(device_id=1) made a bus addressing hand 1 and an emulated hand 0:
    # connect() said "no HAND_INFO reply from the Allegro within 1.0 s"
    from lowcostdex.hardware.allegro.emulator import emulated_allegro

    bus, emu, _ = emulated_allegro(device_id=1)
    with bus:
        state = bus.read_state()
    emu.bus.shutdown()
    assert emu.device_id == 1 and state.valid.all() and np.all(np.isfinite(state.position))


@pytest.mark.parametrize("kwargs,said", [
    ({"device_id": 2.5}, r"Allegro device_id \(the hand's 2-bit CAN id\)=2.5 must be an integer "
                         r"in \[0, 3\]"),
    ({"device_id": 4}, r"Allegro device_id \(the hand's 2-bit CAN id\)=4"),
    ({"period_ms": 2.5}, r"period_ms \(pose streaming period, ms\)=2.5 must be an integer in "
                         r"\[1, 100\]"),
    ({"temperature_period_ms": -5}, r"temperature_period_ms \(0: no temperatures, the thermal "
                                    r"guard blind\)=-5 must be an integer in \[0, 60000\]"),
    ({"stale_after": float("nan")}, r"stale_after \[s\]=nan must be a finite number in "
                                    r"\(0, inf\)"),
    ({"stale_after": -1.0}, r"stale_after \[s\]=-1.0"),
    ({"timeout": 0.0}, r"timeout \[s\]=0.0 must be a finite number in \(0, inf\)"),
])
def test_an_allegro_bus_with_a_careless_setting_is_refused_before_any_bus_opens(kwargs, said):
    # before: device_id 2.5 failed at connect in a bit operation ("unsupported operand type(s)
    # for |"), 4 at the first frame; period_ms 2.5 in struct.pack; temperature_period_ms -5 ran
    # without temperatures (the thermal guard blind) and stale_after nan / -1 read every joint
    # invalid, both without a word; timeout 0 gave up on the hand's first reply
    import can

    from lowcostdex.hardware.allegro.driver import AllegroBus

    host = can.Bus(interface="virtual", channel="careless26")
    try:
        with pytest.raises(ConfigError, match=said):
            AllegroBus(host, own_bus=True, **kwargs)
    finally:
        host.shutdown()


# -- fresh hunt: the transfer loop's sizes from Python ----------------------------------------

@pytest.mark.parametrize("change,said", [
    ({"algos": "dapg"}, r"size: algos='dapg' must be a tuple of names, e.g. \('dapg',\)"),
    ({"fingers": "ff"}, r"size: fingers='ff' must be a tuple of names, e.g. \('ff',\)"),
    ({"n_traj": 2.5}, r"size: n_traj=2.5 must be an integer in \[1, inf\)"),
    ({"seeds": "2"}, r"size: seeds='2' must be an integer in \[1, inf\)"),
    ({"playbacks": -1}, r"size: playbacks=-1 must be an integer in \[0, inf\)"),
    ({"eval_every": -5}, r"size: eval_every=-5 must be an integer in \[0, inf\)"),
    ({"eval_every": 2, "eval_episodes": 0}, r"size: eval_every=2 evaluates with eval_episodes=0"),
    ({"episodes": float("nan")}, r"size: episodes=nan must be an integer"),
    ({"bc_epochs": -3}, r"size: bc_epochs=-3 must be an integer in \[1, inf\) or None"),
    ({"id_seconds": "3"}, r"size: id_seconds \[s\]='3' must be a finite number in \(0, inf\)"),
])
def test_a_transfer_size_with_a_careless_setting_is_named(change, said):
    # before: 'dapg' was read letter by letter ("unknown algo 'd'"); n_traj 2.5, seeds '2', a
    # negative playbacks / eval_every, eval_episodes 0 with evaluations and bc_epochs -3 were
    # taken (failing or running as none in the loop, hours in); NaN and '3' raised int()'s or
    # '>''s own errors
    import dataclasses

    from lowcostdex.transfer.config import SIZES, Size

    with pytest.raises(ConfigError, match=said):
        Size(**{**dataclasses.asdict(SIZES["smoke"]), **change})


# -- fresh hunt: entry points called from Python -----------------------------------------------

@pytest.mark.parametrize("argv,said", [
    ("scan --help", r"main\(argv\) takes the words of a command as a list, e.g. "
                    r"main\(\['scan', '--help'\]\) \(shlex.split of the line\), not one str"),
    (["main", "--seed", 3], r"main\(argv\): argv\[2\]=3 is not a str; give every word as typed "
                            r"in a shell, e.g. '3'"),
    (5, r"main\(argv\) takes a list of words, not int"),
])
def test_the_command_line_from_python_names_argv_that_is_no_list_of_words(argv, said, capsys):
    # before: a str was read letter by letter ("invalid choice: 's'"), a number in the list
    # raised argparse's TypeError "'int' object is not subscriptable", an int "not iterable"
    import re

    from lowcostdex.cli import main

    assert main(argv) == 2
    assert re.search(r"lowcostdex: error: " + said, capsys.readouterr().err)


def test_the_emulated_robot_refuses_a_goal_its_unchecked_step_would_zero():
    # the drive's physics step is now unchecked; before, a NaN goal given to set_goal reached
    # Plant.step and was refused at the next physics step, far from the call that set it
    from lowcostdex.hardware.emulated.chain import emulated_bench

    drive = emulated_bench().drive
    for bad in (float("nan"), float("inf"), 1e12):
        with pytest.raises(ConfigError, match=rf"servo 0's goal {bad!r} \[rad\] must be a finite"):
            drive.set_goal(0, bad)
    drive.set_goal(0, 0.5)
    drive.step()
    assert drive.goal[drive.acts[0]] == 0.5


def test_the_transfer_loop_refuses_a_size_or_override_it_would_fail_on_hours_later(tmp_path):
    # before: run(out, None) raised AttributeError ('NoneType' object has no attribute
    # 'robots'); a misspelt gap override ran the demos and the identification logs, then
    # failed in the gap stage; a misspelt valve_fit key failed after the valve episodes
    # (made_for=() stops the code before at its own check, before any work)
    import dataclasses

    from lowcostdex.errors import KeywordError
    from lowcostdex.transfer.config import SIZES, Size, size_with
    from lowcostdex.transfer.loop import run

    with pytest.raises(ConfigError, match=r"size=None must be a transfer Size or one of smoke, "
                                          r"default, long"):
        run(tmp_path / "t", None, made_for=())
    with pytest.raises(KeywordError, match=r"GapConfig has no setting 'max_efects'.*did you "
                                           r"mean max_effects"):
        run(tmp_path / "t", size_with("smoke", gap=(("max_efects", 1),)), made_for=())
    with pytest.raises(ConfigError, match=r"unknown size valve_fit setting 'gird'; valid: grid, "
                                          r".*did you mean 'grid'"):
        Size(**{**dataclasses.asdict(SIZES["smoke"]), "valve_fit": (("gird", 3),)})
    assert not (tmp_path / "t").exists()


def test_a_policy_snapshot_refuses_noise_it_would_broadcast():
    # before: act(obs, 0.5) or a (1,) noise shifted every action by one draw without a word
    import re

    from lowcostdex.algos.policy import GaussianMLPPolicy

    snap = GaussianMLPPolicy(3, 2).snapshot()
    obs, noise = np.zeros(3), np.array([0.3, -0.2])
    assert np.array_equal(snap.act(obs, noise), snap.mean(obs) + snap.std * noise)
    for bad in (0.5, np.array([0.5]), np.zeros(3)):
        with pytest.raises(ValueError, match=re.escape(f"noise of shape {np.shape(bad)}") +
                           r"; this policy "
                                             r"draws \(2,\) \(one standard-normal number per "
                                             r"action\), or None for the mean action"):
            snap.act(obs, bad)


@pytest.mark.parametrize("actuators,enabled,said", [
    ([0], "no", r"enabled='no' must be True or False"),
    ([5], False, r"actuators: index 5 is not one of the 2 actuators \(0 \.\. 1\)"),
    ([-1], False, r"actuators: index -1 is not one of the 2 actuators"),
    (np.array([True, False]), False, r"actuators=array\(\[ True, False\]\) must be integer "
                                     r"indices of the 2 actuators"),
    (["a"], False, r"actuators=\['a'\] must be integer indices"),
])
def test_a_plant_torque_switch_with_careless_arguments_is_refused(actuators, enabled, said):
    # before: 'no' switched the torque ON (a non-empty str is truthy), a boolean mask was read
    # as the indices 1 and 0, -1 switched the last actuator, 5 a bare IndexError, 'a' int()'s
    # ValueError
    from lowcostdex.sim.plant import Plant

    plant = Plant(mujoco.MjModel.from_xml_string(_TWO))
    with pytest.raises(ConfigError, match=said):
        plant.set_torque_enabled(actuators, enabled)
    assert plant.torque_enabled().all()
    plant.set_torque_enabled(np.int64(1), np.bool_(False))  # numpy scalars: taken
    assert plant.torque_enabled().tolist() == [True, False]


def test_a_batch_plant_of_a_fractional_number_of_simulations_is_refused():
    # before: BatchPlant(model, 2.5) failed in mujoco.batch's constructor ("incompatible
    # constructor arguments") listing its C++ signatures
    with pytest.raises(ConfigError, match=r"nsim \(simulations\)=2.5 must be an integer in "
                                          r"\[1, inf\)"):
        from lowcostdex.sim.plant import BatchPlant

        BatchPlant(mujoco.MjModel.from_xml_string(_TWO), 2.5, nthread=1)


@pytest.mark.parametrize("make,said", [
    (lambda c: c.StateCost(np.zeros(2), np.ones(2), l2=np.nan), r"StateCost.l2=nan must be a "
                                                                 r"finite number in \[0, inf\)"),
    (lambda c: c.StateCost(np.zeros(2), np.ones(2), alpha=np.nan), r"StateCost.alpha=nan"),
    (lambda c: c.StateCost(np.zeros(2), np.ones(2), final_multiplier=np.inf),
     r"StateCost.final_multiplier=inf must be a finite number"),
    (lambda c: c.StateCost(np.zeros(2), np.ones(2), final_steps=1.5),
     r"StateCost.final_steps=1.5 must be an integer"),
    (lambda c: c.ActionCost(np.ones(2), final_multiplier=np.nan),
     r"ActionCost.final_multiplier=nan must be a finite number"),
    (lambda c: c.StateCost(np.zeros(2), np.ones(2)).evaluate(np.zeros((5, 3)), np.zeros((5, 1))),
     r"states of 3 coordinates; this cost weighs 2 \(weights, target\)"),
    (lambda c: c.ActionCost(np.ones(2)).evaluate(np.zeros((5, 3)), np.zeros((5, 1))),
     r"actions of 1 coordinates; this cost weighs 2 \(weights, target\)"),
])
def test_a_local_model_cost_with_a_nan_weight_or_another_size_is_named(make, said):
    # before: a NaN l2, alpha or multiplier passed every comparison and made every cost NaN;
    # final_steps 1.5 failed in numpy's slice; a state or action of another size raised numpy's
    # broadcast / einsum error
    from lowcostdex.algos.local_models import costs

    with pytest.raises(ConfigError, match=said):
        make(costs)


@pytest.mark.parametrize("change,said", [
    ({"data": "nan"}, r"fit_gmm data holds nan \(row 2\): must be finite numbers"),
    ({"data": "1d"}, r"fit_gmm data of shape \(50,\) must be \(N, D\)"),
    ({"n_clusters": 2.5}, r"n_clusters=2.5 must be an integer in \[1, inf\)"),
    ({"rng": 0}, r"rng=0 must be a seeded numpy Generator"),
    ({"rng": None}, r"fit_gmm needs rng, a seeded numpy Generator"),
])
def test_the_dynamics_prior_mixture_names_careless_data_and_settings(change, said):
    # before: NaN points fitted a NaN mixture without a word (the dynamics prior of every later
    # fit), (N,) data "not enough values to unpack", K 2.5 a TypeError, rng 0 / None
    # "object has no attribute 'permutation'"
    from lowcostdex.algos.local_models.gmm import fit_gmm

    data = np.random.default_rng(0).normal(size=(50, 3))
    edited = {"nan": np.where(np.arange(150).reshape(50, 3) == 7, np.nan, data),
              "1d": data[:, 0]}
    kw = {"data": data, "n_clusters": 2, "rng": np.random.default_rng(1), **change}
    if isinstance(kw["data"], str):
        kw["data"] = edited[kw["data"]]
    with pytest.raises(ConfigError, match=said):
        fit_gmm(kw.pop("data"), kw.pop("n_clusters"), **kw)


def test_a_vector_env_refuses_reset_options_it_would_ignore():
    # before: vec.reset(options={"goal": ...}) (or qpos) was ignored without a word: the copies
    # started from the task's own distribution
    from lowcostdex.sim.vector import make_vec

    vec = make_vec("lowcostdex/DClawTurnValve-v0", num_envs=2, nthread=1)
    try:
        with pytest.raises(ConfigError, match=r"reset\(options=\{'goal'\}\): the vector env takes "
                                              r"no reset options .* on one env"):
            vec.reset(seed=0, options={"goal": {"angle": 1.0}})
        vec.reset(seed=0, options={})  # none given: as before
    finally:
        vec.close()
