"""The TVLG trainer on the D'Claw valve env: run directory, fixed start, resume, CLI, init."""

import argparse
import dataclasses
import json
import math

import numpy as np
import pytest

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.local_models.episodes import (
    capture_start,
    controller_state,
    hold_action,
    offset_start,
    run_episode,
)
from lowcostdex.algos.local_models.initial import initial_controller
from lowcostdex.algos.local_models.task_cost import demo_hand_reference, task_cost
from lowcostdex.algos.local_models.train import (
    add_train_commands,
    config_from_args,
    default_env_factory,
    is_solved,
    load_controller,
    train,
)
from lowcostdex.algos.local_models.train_config import TaskCostConfig, TVLGTrainConfig
from lowcostdex.algos.samplers import TRAIN_STREAM, RolloutJob
from lowcostdex.errors import ConfigError

TIME_COLUMNS = ("time_sampling", "time_update", "time_eval")


def _small(**kw) -> TVLGTrainConfig:
    base = dict(n_iter=3, n_rollouts=2, progress=False)
    base.update(kw)
    return TVLGTrainConfig(**base)


@pytest.fixture(scope="module")
def valve():
    env = default_env_factory(TVLGTrainConfig())()
    start = capture_start(env, 0)
    hold = hold_action(env, start)
    yield env, start, hold
    env.close()


def test_episodes_start_from_the_fixed_state_and_record_commanded_actions(valve) -> None:
    env, start, hold = valve
    env.reset(options=start.reset_options())
    x0 = controller_state(env, hold)
    ctl = initial_controller(_small(init_noise=2.0), env, start, x0, hold, 41)
    eps = [
        run_episode(env, ctl, start, RolloutJob(0, TRAIN_STREAM, 0, i), True, hold, 0.0)
        for i in range(2)
    ]
    for ep in eps:
        np.testing.assert_array_equal(ep.X[0], x0)
        assert ep.X.shape == (41, 29) and ep.U.shape == (41, 9) and ep.rewards.shape == (40,)
        assert np.abs(ep.U).max() > 1.0  # commanded, not clipped
        np.testing.assert_allclose(ep.X[1:, 20:], np.clip(ep.U[:-1], -1, 1))  # last applied action
        assert ep.robot_seconds == pytest.approx(40 * env.unwrapped.control_period)
    assert not np.allclose(eps[0].U, eps[1].U)
    again = run_episode(env, ctl, start, RolloutJob(0, TRAIN_STREAM, 0, 1), True, hold, 0.0)
    np.testing.assert_array_equal(again.X, eps[1].X)


def test_valve_cost_targets_half_turn_positive_and_start_pose(valve) -> None:
    env, start, hold = valve
    cost = task_cost(env, start, hold, TVLGTrainConfig().cost, 41, 29)
    hand_term, object_term, action_term = cost.costs
    assert start.goal["angle"] == pytest.approx(math.pi)
    np.testing.assert_allclose(object_term.target[:, 18], math.pi)
    np.testing.assert_allclose(hand_term.target[0, :9], start.qpos[env.unwrapped.task.hand_qpos])
    np.testing.assert_allclose(action_term.target, hold)
    assert object_term.weights[18] == 1.0 and hand_term.weights[18] == 0.0


def test_object_target_turns_half_turns_positively_or_like_the_reference() -> None:
    from lowcostdex.algos.local_models.task_cost import object_target

    assert object_target(0.0, math.pi) == pytest.approx(math.pi)
    assert object_target(-0.01, math.pi) == pytest.approx(math.pi)  # not -pi for a hair off 0
    assert object_target(0.0, math.pi, reference=-3.0) == pytest.approx(-math.pi)
    assert object_target(0.0, -1.0) == pytest.approx(-1.0)
    assert object_target(2 * math.pi, 0.5) == pytest.approx(2 * math.pi + 0.5)


def test_demos_init_replays_the_mean_demonstration(valve, tmp_path) -> None:
    import lowcostdex.demonstrations.dataset  # noqa: F401  (an import error fails, never skips)
    from lowcostdex.demonstrations.dataset import save_demos
    from lowcostdex.demonstrations.file import DatasetInfo, Episode

    env, start, hold = valve
    rng = np.random.default_rng(0)
    a, b = rng.uniform(-1, 1, size=(40, 9)), rng.uniform(-1, 1, size=(30, 9))
    episodes = [
        Episode(np.zeros((len(u) + 1, 30)), u, np.zeros(len(u)), np.zeros((len(u) + 1, 1)),
                np.zeros((len(u) + 1, 1)), np.zeros(len(u) + 1), np.ones(len(u), bool))
        for u in (a, b)
    ]  # fmt: skip
    info = DatasetInfo.from_env(env, "scripted_teacher")
    path = save_demos(tmp_path / "demos.h5", episodes, info)
    env.reset(options=start.reset_options())
    x0 = controller_state(env, hold)
    ctl = initial_controller(_small(init="demos", demos=str(path)), env, start, x0, hold, 41)
    np.testing.assert_allclose(ctl.act(5, x0), 0.5 * (a[5] + b[5]))
    np.testing.assert_allclose(ctl.act(35, x0), a[35])
    np.testing.assert_allclose(ctl.act(40, x0), a[39])
    with pytest.raises(ConfigError, match="demonstration"):
        TVLGTrainConfig(init="demos")


def test_teacher_init_replays_a_successful_teacher_episode(valve, tmp_path) -> None:
    import lowcostdex.teachers.valve  # noqa: F401  (an import error fails, never skips)
    from lowcostdex.algos.local_models.initial import teacher_episodes
    from lowcostdex.demonstrations.dataset import load_demos

    env, start, hold = valve
    cfg = _small(init="teacher", init_noise=0.05)
    teach = teacher_episodes(env, start, cfg, hold, 41, tmp_path / "teacher.h5")
    assert teach.X.shape == (1, 41, 29) and teach.successes.all()
    assert load_demos(tmp_path / "teacher.h5").actions.shape == (40, 9)
    env.reset(options=start.reset_options())
    x0 = controller_state(env, hold)
    ctl = initial_controller(cfg, env, start, x0, hold, 41, teach.U)
    ep = run_episode(env, ctl, start, RolloutJob(0, 1, 0, 0, deterministic=True), True, hold, 0.0)
    assert ep.success("final") and abs(ep.final_error) < 0.1
    assert np.ptp(ctl.k[:, 0]) > 0.5  # a real motion, not the hold action


def test_run_directory_and_resume_reproduce_the_uninterrupted_run(tmp_path) -> None:
    full = train(_small(), tmp_path / "full").read_metrics()
    assert list(full[ex.ITERATION]) == [0, 1, 2]
    assert list(full["rollouts"]) == [2, 4, 6]
    assert list(full[ex.SAMPLES]) == [80, 160, 240]
    assert np.all(full["converged"] == 1.0)
    for name in ("config.json", "metrics.csv", "learning_curves.png", "controller.npz"):
        assert (tmp_path / "full" / name).exists()
    ctl, start, cfg = load_controller(tmp_path / "full")
    assert (ctl.T, ctl.dX, ctl.dU) == (41, 29, 9) and cfg == _small()

    train(_small(), tmp_path / "cut", stop_after=0)
    with pytest.raises(ConfigError, match="already holds a run"):
        train(_small(), tmp_path / "cut")
    with pytest.raises(ConfigError, match="differs"):
        train(_small(seed=1), tmp_path / "cut", resume=True)
    resumed = train(_small(), tmp_path / "cut", resume=True).read_metrics()
    for key, values in full.items():
        if key not in TIME_COLUMNS:
            np.testing.assert_array_equal(resumed[key], values, err_msg=key)
    np.testing.assert_array_equal(load_controller(tmp_path / "cut")[0].K, ctl.K)


def test_cli_builds_the_config() -> None:
    parser = argparse.ArgumentParser()
    add_train_commands(parser.add_subparsers())
    args = parser.parse_args(
        ["tvlg", "--env", "DClawTurnValve-v0", "--backend", "emulated", "--out", "r"]
    )
    cfg = config_from_args(args)
    assert cfg.env_id == "lowcostdex/DClawTurnValve-v0" and cfg.backend == "emulated"
    assert cfg.n_rollouts == 5 and cfg.init == "pd"
    args = parser.parse_args(
        [
            "tvlg",
            "--out",
            "r",
            "--kl-step",
            "0.5",
            "--port",
            "/dev/ttyUSB0",
            "--backend",
            "hardware",
        ]
    )
    cfg = config_from_args(args)
    assert cfg.algo.traj_opt.kl_step == 0.5 and cfg.env_kwargs == {"port": "/dev/ttyUSB0"}
    assert cfg.cost == TaskCostConfig.task()
    args = parser.parse_args(
        ["tvlg", "--out", "r", "--init", "teacher", "--cost", "tracking", "--final-steps", "3",
         "--min-step-mult", "0.1", "--eval-noisy-episodes", "20", "--start-hand-qpos",
         *["0.1"] * 9]
    )  # fmt: skip
    cfg = config_from_args(args)
    assert cfg.cost == dataclasses.replace(TaskCostConfig.tracking(), final_steps=3)
    assert cfg.algo.traj_opt.min_step_mult == 0.1 and cfg.eval_noisy_episodes == 20
    assert cfg.algo.traj_opt.kl_step == 0.5  # the tracking preset's measured step
    assert cfg.start_hand_qpos == (0.1,) * 9
    with pytest.raises(SystemExit):
        parser.parse_args(["tvlg", "--out", "r", "--backend", "simulated"])


def test_demo_hand_reference_is_the_start_pose_then_the_demonstrated_joint_targets(valve) -> None:
    env, start, hold = valve
    task = env.unwrapped.task
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1.2, 1.2, size=(2, 41, 9))
    actions[1, 30:] = np.nan  # the second demonstration is shorter
    ref = demo_hand_reference(env, start, actions)
    assert ref.shape == (41, 9)
    np.testing.assert_allclose(ref[0], start.qpos[task.hand_qpos])
    mean = np.nanmean(np.clip(actions, -1, 1), axis=0)
    goal = 0.5 * (task.hand_high + task.hand_low) + 0.5 * (task.hand_high - task.hand_low) * mean
    np.testing.assert_allclose(ref[1:], goal[:-1])
    assert np.all(ref >= task.hand_low - 1e-12) and np.all(ref <= task.hand_high + 1e-12)


def test_tracking_cost_follows_the_reference_and_pays_the_goal_only_at_the_end(valve) -> None:
    env, start, hold = valve
    cfg = TaskCostConfig.tracking()
    actions = np.random.default_rng(1).uniform(-1, 1, size=(1, 41, 9))
    hand_term, object_term, action_term = task_cost(env, start, hold, cfg, 41, 29, actions).costs
    np.testing.assert_allclose(hand_term.target[:, :9], demo_hand_reference(env, start, actions))
    np.testing.assert_allclose(action_term.target, actions[0])
    ref = hand_term.target[:, :9]
    assert hand_term.weights[0] == cfg.pose_weight == 0.1
    X = np.zeros((41, 29))
    X[:, :9] = ref
    value = object_term.evaluate(X, np.zeros((41, 9))).value  # valve at 0, goal pi
    np.testing.assert_allclose(value[:36], 0.0)
    np.testing.assert_allclose(value[36:], 0.5 * cfg.object_weight * math.pi**2)
    with pytest.raises(ConfigError, match="demonstrated actions"):
        task_cost(env, start, hold, cfg, 41, 29)
    with pytest.raises(ConfigError, match="demonstration"):
        TVLGTrainConfig(cost=cfg)  # init "pd" has no demonstration to track


def test_solved_needs_the_noise_free_episode_and_enough_noisy_successes() -> None:
    assert is_solved(True, 0.8, 0.8) and is_solved(True, math.nan, 0.8)
    assert not is_solved(True, 0.75, 0.8) and not is_solved(False, 1.0, 0.8)


def test_tracking_run_logs_noisy_evaluations_and_resumes_identically(tmp_path) -> None:
    import lowcostdex.teachers.valve  # noqa: F401  (an import error fails, never skips)
    cfg = _small(
        n_iter=2, init="teacher", init_noise=0.05, cost=TaskCostConfig.tracking(),
        eval_noisy_episodes=2,
    )  # fmt: skip
    full = train(cfg, tmp_path / "full").read_metrics()
    assert list(full["rollouts"]) == [2, 4]  # held-out episodes are not learning rollouts
    assert set(full["eval_noisy_success_rate"]) <= {0.0, 0.5, 1.0}
    solved = (full[ex.EVAL_SUCCESS_RATE] == 1.0) & (full["eval_noisy_success_rate"] >= 0.8)
    np.testing.assert_array_equal(full["solved"], solved.astype(float))
    # robot time: 1 teacher + 2 x (2 rollouts + 1 noise-free + 2 noisy) episodes of 4 s
    assert full[ex.ROBOT_HOURS][-1] * 3600 == pytest.approx(11 * 4.0)
    train(cfg, tmp_path / "cut", stop_after=0)
    resumed = train(cfg, tmp_path / "cut", resume=True).read_metrics()
    for key, values in full.items():
        if key not in TIME_COLUMNS:
            np.testing.assert_array_equal(resumed[key], values, err_msg=key)


def test_resume_uses_the_demonstration_the_run_started_from(tmp_path, monkeypatch) -> None:
    """Failed teacher episodes and the un-executed last action stay in a resumed run's cost."""
    import lowcostdex.teachers.valve  # noqa: F401  (an import error fails, never skips)
    from lowcostdex.algos.local_models import train as tvlg_train

    teach = tvlg_train.teacher_episodes
    noisy = {}

    def noisy_teacher(*args, **kw):  # exploration noise: some teacher episodes fail
        # 0.09 mixes successes and failures with the relay valve teacher (9edd932): 0.03-0.07
        # all 3 succeed, 0.08 and 0.1 all fail
        out = teach(*args, **kw, noise=0.09)
        noisy["successes"] = out.successes
        return out

    monkeypatch.setattr(tvlg_train, "teacher_episodes", noisy_teacher)
    cfg = _small(
        n_iter=2, init="teacher", teacher_episodes=3, init_noise=0.05,
        cost=TaskCostConfig.tracking(),
    )  # fmt: skip
    full = train(cfg, tmp_path / "full").read_metrics()
    assert noisy["successes"].any() and not noisy["successes"].all()
    train(cfg, tmp_path / "cut", stop_after=0)
    (tmp_path / "cut" / "teacher_demo.h5").unlink()  # not read again
    resumed = train(cfg, tmp_path / "cut", resume=True).read_metrics()
    for key, values in full.items():
        if key not in TIME_COLUMNS:
            np.testing.assert_array_equal(resumed[key], values, err_msg=key)
    ctl, cut = load_controller(tmp_path / "full")[0], load_controller(tmp_path / "cut")[0]
    np.testing.assert_array_equal(cut.K, ctl.K)
    np.testing.assert_array_equal(cut.k, ctl.k)


def test_fixed_start_can_put_the_hand_elsewhere(valve) -> None:
    env, _, _ = valve
    pose = np.tile([-0.27, -0.23, 0.79], 3)
    start = capture_start(env, 0, pose)
    np.testing.assert_allclose(start.qpos[env.unwrapped.task.hand_qpos], pose)
    assert start.goal["angle"] == pytest.approx(math.pi)
    stored = json.loads(json.dumps(dataclasses.asdict(_small(start_hand_qpos=tuple(pose)))))
    cfg = TVLGTrainConfig.from_dict(stored)  # as read back from config.json
    assert cfg.start_hand_qpos == tuple(pose)


def test_offset_start_turns_object_and_goal_together(valve) -> None:
    env, start, _ = valve
    shifted = offset_start(env, start, -0.3)
    obj = env.unwrapped.task.obj_qpos
    assert shifted.qpos[obj] == pytest.approx(start.qpos[obj] - 0.3)
    assert float(shifted.goal["angle"]) == pytest.approx(math.pi - 0.3)
    hand = env.unwrapped.task.hand_qpos
    np.testing.assert_array_equal(shifted.qpos[hand], start.qpos[hand])


def test_tvlg_demo_script_runs(tmp_path, monkeypatch, capsys) -> None:
    import importlib.util
    import sys
    from pathlib import Path

    import lowcostdex.teachers.valve  # noqa: F401  (an import error fails, never skips)

    path = Path(__file__).resolve().parents[1] / "demos" / "tvlg_turn_valve.py"
    spec = importlib.util.spec_from_file_location("tvlg_turn_valve", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(sys, "argv", ["tvlg_turn_valve", "--n-iter", "1", "--out", str(tmp_path)])
    module.main()
    out = capsys.readouterr().out
    assert "held-out noisy success" in out and "noise-free replay" in out
    assert (tmp_path / "demo_short.h5").exists() and (tmp_path / "controller.npz").exists()


@pytest.mark.parametrize("bad, message", [
    (dict(init_noise=float("nan")), r"init_noise=nan must be a finite number in \(0, inf\)"),
    (dict(n_iter=0), r"n_iter=0 must be an integer in \[1, inf\)"),
    (dict(solve_rate=0.0), r"solve_rate=0.0 must be a finite number in \(0, 1\]"),
    (dict(pd_gain=-1.0), r"pd_gain=-1.0"),
    (dict(seed=-1), r"seed=-1 must be an integer"),
    (dict(eval_every=1.5), r"eval_every=1.5 must be an integer"),
])
def test_tvlg_config_numbers_are_checked(bad, message):
    """Issue 12: NaN, out-of-range and fractional counts are refused with the valid range."""
    from lowcostdex.algos.local_models.train_config import TVLGTrainConfig
    from lowcostdex.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        TVLGTrainConfig(**bad)


def test_ctrl_c_saves_the_last_iteration_and_a_failed_start_leaves_nothing(tmp_path, monkeypatch):
    """Issue 12 for `train tvlg`: Ctrl-C between checkpoints saves the iteration it finished
    (resume continues from there); a start that fails before writing leaves no folder."""
    from lowcostdex.algos import experiment as ex
    from lowcostdex.algos.local_models import train as tvlg_train

    real = tvlg_train.tvlg_iteration
    calls = {"n": 0}

    def interrupt_third(*args, **kw):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return real(*args, **kw)

    monkeypatch.setattr(tvlg_train, "tvlg_iteration", interrupt_third)
    with pytest.raises(ex.Interrupted) as caught:
        train(_small(n_iter=4, checkpoint_every=10), tmp_path / "run")
    assert caught.value.iteration == 1                      # iterations 0 and 1 finished
    assert (tmp_path / "run" / ex.CHECKPOINT_DIR / "ckpt_000001.pt").exists()
    monkeypatch.setattr(tvlg_train, "tvlg_iteration", real)
    resumed = train(_small(n_iter=4, checkpoint_every=10), tmp_path / "run", resume=True)
    assert resumed.read_metrics()[ex.ITERATION].tolist() == [0, 1, 2, 3]

    def no_env():
        raise ConfigError("no such robot")

    with pytest.raises(ConfigError, match="no such robot"):
        train(_small(), tmp_path / "failed", env_factory=no_env)
    assert not (tmp_path / "failed").exists()
