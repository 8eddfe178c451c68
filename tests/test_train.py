"""NPG/DAPG training runs on a tiny point-mass task: learning, reproducibility, resume, CLI."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from pointmass import demo_info, expert_action, make_pointmass

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.bc import BCConfig
from lowcostdex.algos.dapg import DAPGConfig
from lowcostdex.algos.npg import NPGConfig
from lowcostdex.algos.policy import PolicyConfig
from lowcostdex.algos.samplers import make_jobs, rollout
from lowcostdex.algos.train import TrainConfig, load_policy, train
from lowcostdex.demonstrations.dataset import save_demos, teacher_episodes
from lowcostdex.errors import ConfigError

TESTS = Path(__file__).parent


def _config(**kw):
    base = dict(
        env_id="test/PointMass",
        n_iter=12,
        n_traj=16,
        gamma=0.98,
        gae_lambda=0.95,
        eval_every=4,
        eval_episodes=8,
        progress=False,
        policy=PolicyConfig(hidden_sizes=(32, 32), init_log_std=-0.5),
        npg=NPGConfig(step_size=0.05, damping=1e-2),
    )
    base.update(kw)
    return TrainConfig(**base)


def _metrics(run_dir):
    m = ex.read_metrics(Path(run_dir) / ex.METRICS_FILE)
    return {k: v for k, v in m.items() if not k.startswith("time_")}


def _assert_same_metrics(a, b):
    assert list(a) == list(b)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def _expert_demos(path, n=10):
    episodes = teacher_episodes(
        make_pointmass(), lambda env, obs: expert_action(obs), seeds=range(1000, 1000 + n)
    )
    return save_demos(path, episodes, demo_info())


def test_npg_improves_return_and_writes_the_run_directory(tmp_path):
    run = train(_config(n_iter=15), tmp_path / "run", env_factory=make_pointmass)
    m = run.read_metrics()
    assert m["return_mean"][-3:].mean() > m["return_mean"][0] + 5.0
    assert m["eval_success_rate"][-1] > m["success_rate"][0]
    np.testing.assert_array_equal(m["samples"], 16 * 30 * np.arange(1, 16))
    np.testing.assert_allclose(m["robot_hours"][0], (16 + 0) * 30 * 0.1 / 3600)
    # evaluations after iterations 3, 7, 11 and the last (14), 8 episodes of 30 steps each:
    # counted apart from the training samples (issue 13: the report gave only the latter)
    evals = np.cumsum([(k + 1) % 4 == 0 or k == 14 for k in range(15)])
    np.testing.assert_array_equal(m["eval_samples"], 8 * 30 * evals)
    assert np.all(m["kl"] < 2 * 0.05)  # delta / 2 to second order
    for name in ("config.json", "metrics.csv", "learning_curves.png", "policy.pt"):
        assert (run.path / name).exists(), name
    policy = load_policy(run.path)  # weights_only checkpoint of the final policy
    assert policy.obs_dim == 3


def test_seeded_runs_are_reproducible(tmp_path):
    for name, seed in (("a", 1), ("b", 1), ("c", 2)):
        train(_config(n_iter=3, seed=seed), tmp_path / name, env_factory=make_pointmass)
    _assert_same_metrics(_metrics(tmp_path / "a"), _metrics(tmp_path / "b"))
    assert not np.array_equal(
        _metrics(tmp_path / "a")["return_mean"], _metrics(tmp_path / "c")["return_mean"]
    )


def test_process_sampler_run_equals_serial_run(tmp_path):
    train(_config(n_iter=3), tmp_path / "serial", env_factory=make_pointmass)
    train(
        _config(n_iter=3, sampler="process", n_workers=2),
        tmp_path / "pool",
        env_factory=make_pointmass,
    )
    _assert_same_metrics(_metrics(tmp_path / "serial"), _metrics(tmp_path / "pool"))


def test_resume_equals_uninterrupted_run(tmp_path):
    cfg = _config(n_iter=6, checkpoint_every=2)
    train(cfg, tmp_path / "full", env_factory=make_pointmass)
    train(cfg, tmp_path / "cut", env_factory=make_pointmass, stop_after=2)
    assert ex.read_metrics(tmp_path / "cut" / "metrics.csv")["iteration"][-1] == 2
    train(cfg, tmp_path / "cut", env_factory=make_pointmass, resume=True)
    _assert_same_metrics(_metrics(tmp_path / "full"), _metrics(tmp_path / "cut"))
    a, b = load_policy(tmp_path / "full"), load_policy(tmp_path / "cut")
    assert torch.equal(
        torch.nn.utils.parameters_to_vector(a.parameters()),
        torch.nn.utils.parameters_to_vector(b.parameters()),
    )


def test_resume_after_sigkill_equals_uninterrupted_run(tmp_path):
    """Kill a training process at an arbitrary moment, resume it, compare with a clean run."""
    cfg = _config(n_iter=8, checkpoint_every=3)
    script = textwrap.dedent(
        f"""
        import sys, time
        sys.path.insert(0, {str(TESTS)!r})
        from pointmass import make_pointmass
        from lowcostdex.algos.train import TrainConfig, train

        def slow():  # ~0.3 s per iteration so that the kill lands mid-run
            env = make_pointmass()
            step = env.step
            env.step = lambda a: (time.sleep(0.0006), step(a))[1]
            return env

        train(TrainConfig.from_dict({dataclasses.asdict(cfg)!r}), sys.argv[1], env_factory=slow)
        """
    )
    file = tmp_path / "job.py"
    file.write_text(script)
    run_dir = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, str(file), str(run_dir)], start_new_session=True)
    latest = run_dir / "checkpoints" / "latest.json"
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        if latest.exists() and ex.read_json(latest)["iteration"] >= 2:
            time.sleep(0.45)  # somewhere in the next iterations, possibly mid-write
            break
        time.sleep(0.01)
    assert proc.poll() is None, "the run finished before it could be killed"
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    done = ex.read_metrics(run_dir / "metrics.csv")["iteration"]
    assert 2 <= done[-1] < 7, done
    train(cfg, run_dir, resume=True, env_factory=make_pointmass)
    train(cfg, tmp_path / "clean", env_factory=make_pointmass)
    _assert_same_metrics(_metrics(tmp_path / "clean"), _metrics(run_dir))


def test_dapg_runs_bc_first_and_decays_the_demo_weight(tmp_path):
    demos = _expert_demos(tmp_path / "demos.h5")
    cfg = _config(
        algo="dapg",
        demos=str(demos),
        n_iter=6,
        dapg=DAPGConfig(lam0=0.1, lam1=0.8, demo_weight="mjrl"),
        bc=BCConfig(epochs=25),
    )
    run = train(cfg, tmp_path / "run", env_factory=make_pointmass)
    bc = ex.read_json(run.path / "bc.json")
    assert bc["bc_loss_after"] < 0.2 * bc["bc_loss_before"] and bc["n_episodes"] == 10
    m = run.read_metrics()
    np.testing.assert_allclose(m["demo_weight"], 0.1 * 0.8 ** np.arange(6))
    # BC from a good teacher already succeeds far more often than the untrained NPG policy.
    assert m["success_rate"][0] >= 0.5


def test_bc_initialised_policy_tracks_the_teacher(tmp_path):
    demos = _expert_demos(tmp_path / "demos.h5", n=20)
    cfg = _config(
        algo="dapg", demos=str(demos), n_iter=1, dapg=DAPGConfig(lam0=0.0), bc=BCConfig(epochs=100)
    )
    run = train(cfg, tmp_path / "run", env_factory=make_pointmass)
    snap = load_policy(run.path).snapshot()
    path = rollout(make_pointmass(), snap, make_jobs(99, 1, 0, 1, deterministic=True)[0])
    teacher = np.array([expert_action(o) for o in path.observations])
    assert np.abs(path.actions - teacher).mean() < 0.1


def test_train_config_validation_names_the_choices():
    with pytest.raises(ConfigError, match="'npg', 'dapg'"):
        TrainConfig(algo="ppo")
    with pytest.raises(ConfigError, match="DAPG needs demonstrations"):
        TrainConfig(algo="dapg")
    with pytest.raises(ConfigError, match="one robot"):
        TrainConfig(backend="emulated", sampler="process")
    with pytest.raises(ConfigError, match="eval_bc needs a behaviour clone"):
        TrainConfig(algo="npg", eval_bc=True)


def test_cli_trains_a_registered_env(tmp_path, capsys):
    import gymnasium as gym

    from lowcostdex.cli import main

    env_id = "lowcostdex_test/PointMass-v0"
    if env_id not in gym.registry:
        gym.register(env_id, entry_point="pointmass:PointMass", max_episode_steps=30)
    args = ["train", "npg", "--env", env_id, "--out", str(tmp_path / "run"), "--n-iter", "2", "--n-traj", "4",
            "--eval-every", "1", "--eval-episodes", "2", "--no-progress", "--hidden", "8"]  # fmt: skip
    assert main(args) == 0
    assert "final eval success rate" in capsys.readouterr().out
    assert ex.read_json(tmp_path / "run" / "config.json")["policy"]["hidden_sizes"] == [8]
    # a resume may extend the budget but not change the method
    assert main([*args, "--resume", "--step-size", "0.3"]) == 2
    assert "configuration differs" in capsys.readouterr().err
    args[args.index("--n-iter") + 1] = "3"
    assert main([*args, "--resume"]) == 0
    assert ex.read_metrics(tmp_path / "run" / "metrics.csv")["iteration"].tolist() == [0, 1, 2]


def test_until_ends_the_run_early_with_an_evaluation(tmp_path):
    seen = []
    run = train(
        _config(n_iter=10, eval_every=0),
        tmp_path / "run",
        env_factory=make_pointmass,
        until=lambda row: seen.append(row["samples"]) or row["iteration"] >= 1,
    )
    m = run.read_metrics()
    assert m["iteration"].tolist() == [0, 1] and seen == [480, 960]
    assert np.isnan(m["eval_success_rate"][0]) and np.isfinite(m["eval_success_rate"][1])
    assert ex.read_json(run.path / "checkpoints" / "latest.json")["iteration"] == 1


def test_sim_training_with_the_vector_sampler_is_independent_of_num_envs(tmp_path):
    import lowcostdex.sim.vector  # noqa: F401  (an import error fails, never skips)
    cfg = dict(env_id="lowcostdex/DClawTurnValve-v0", n_iter=2, n_traj=4, eval_every=0, eval_episodes=2,
               progress=False, sampler="vector", policy=PolicyConfig(hidden_sizes=(16,)))  # fmt: skip
    for n in (2, 4):
        train(TrainConfig(**cfg, n_workers=n), tmp_path / f"vec{n}")
    _assert_same_metrics(_metrics(tmp_path / "vec2"), _metrics(tmp_path / "vec4"))
    m = _metrics(tmp_path / "vec2")
    assert m["samples"].tolist() == [160, 320] and np.all(m["goal_error_final"] > 0)


def test_an_update_that_produces_nan_stops_the_run_with_a_message(tmp_path, monkeypatch):
    """Issue 12: a step that blows the policy up (e.g. a huge finite step size) stops the run
    with one message; the checkpoints before it stay loadable and finite."""
    import torch

    from lowcostdex.algos import train as train_module

    real = train_module.npg_update

    def blow_up(policy, *args, **kw):
        stats = real(policy, *args, **kw)
        if blow_up.calls == 2:
            with torch.no_grad():
                next(iter(policy.parameters())).fill_(float("nan"))
        blow_up.calls += 1
        return stats

    blow_up.calls = 0
    monkeypatch.setattr(train_module, "npg_update", blow_up)
    with pytest.raises(train_module.TrainingDiverged, match="iteration 2.*non-finite"):
        train(_config(n_iter=4, eval_every=0), tmp_path / "run", env_factory=make_pointmass)
    files = sorted((tmp_path / "run" / ex.CHECKPOINT_DIR).glob("ckpt_*.pt"))
    assert files and files[-1].name == "ckpt_000001.pt"       # nothing from iteration 2 on
    state = ex.load_state(files[-1])
    flat = torch.cat([v.reshape(-1) for v in state["policy"]["state_dict"].values()])
    assert torch.isfinite(flat).all()


class _SeedLog(gym.Wrapper):
    """Records the seed of every reset the trainer asks the env for (the env's side)."""

    def __init__(self, env, log):
        super().__init__(env)
        self.log = log

    def reset(self, *, seed=None, options=None):
        self.log.append(seed)
        return self.env.reset(seed=seed, options=options)


@pytest.mark.parametrize("paired", [False, True])
def test_paired_evaluations_run_the_clones_episodes_again(tmp_path, paired):
    """With ``eval_paired`` the clone and every evaluation reset the env with the same seeds
    (the same episodes), so the run's policy is chosen on paired comparisons; without it each
    evaluation draws new ones. Read from the env's resets: the clone's 3 evaluation episodes,
    then per iteration 2 training episodes and after iterations 1 and 3 an evaluation of 3."""
    log = []
    demos = _expert_demos(tmp_path / "demos.h5")
    cfg = _config(algo="dapg", demos=str(demos), n_iter=4, n_traj=2, eval_every=2,
                  eval_episodes=3, eval_bc=True, eval_paired=paired, bc=BCConfig(epochs=5))
    train(cfg, tmp_path / "run", env_factory=lambda: _SeedLog(make_pointmass(), log))
    assert len(log) == 3 + 4 * 2 + 2 * 3 and None not in log
    clone, evals = log[:3], [log[7:10], log[14:17]]
    training = log[3:7] + log[10:14]
    assert len(set(clone)) == 3 and not set(training) & set(clone + evals[0] + evals[1])
    if paired:
        assert evals[0] == clone and evals[1] == clone
    else:
        assert not set(evals[0]) & set(clone) and not set(evals[1]) & set(evals[0] + clone)


def test_eval_paired_on_the_command_line():
    from lowcostdex.algos.train_cli import config_from_args
    from lowcostdex.cli import build_parser

    parser = build_parser()
    for algo in ("npg", "dapg"):
        argv = ["train", algo, "--out", "x"] + (["--demos", "d.h5"] if algo == "dapg" else [])
        assert not config_from_args(parser.parse_args(argv)).eval_paired
        assert config_from_args(parser.parse_args([*argv, "--eval-paired"])).eval_paired


@pytest.mark.parametrize("step_size", [0.05, 20.0])
def test_the_evaluated_clone_competes_for_the_runs_policy(tmp_path, step_size):
    """With ``eval_bc`` the clone is a candidate (iteration -1): the run's policy is the clone
    unless an RL evaluation scored higher (success, then return), else that best iterate. A
    huge step (KL ~ 10 nats) wrecks the clone's tracking, so the clone must be kept there."""
    demos = _expert_demos(tmp_path / "demos.h5")
    cfg = _config(algo="dapg", demos=str(demos), n_iter=4, eval_every=2, eval_bc=True,
                  dapg=DAPGConfig(lam0=0.0), bc=BCConfig(epochs=25),
                  npg=NPGConfig(step_size=step_size, damping=1e-2))
    run = train(cfg, tmp_path / "run", env_factory=make_pointmass)
    bc, m = ex.read_json(run.path / "bc.json"), run.read_metrics()
    scores = [(bc["eval_success_rate"], bc["eval_return_mean"], -1)] + [
        (s, r, int(i)) for s, r, i in zip(m["eval_success_rate"], m["eval_return_mean"],
                                          m["iteration"], strict=True) if np.isfinite(s)]
    best = scores[0]
    for s in scores[1:]:  # the first of equal scores is kept
        best = s if s[:2] > best[:2] else best
    summary = ex.read_json(run.path / ex.SUMMARY_FILE)
    assert summary["best"]["iteration"] == best[2]
    chosen = load_policy(run.path).state_dict()
    clone = load_policy(run.path / ex.BC_POLICY_FILE).state_dict()
    same = all(torch.equal(chosen[k], clone[k]) for k in clone)
    assert same == (best[2] == -1)
    if step_size > 1:
        assert best[2] == -1, scores


def test_progress_names_simulated_time_apart_from_robot_time():
    """A run in simulation spends no robot time: its progress bar says sim_h, not robot_h."""
    from lowcostdex.algos.train import _State, _time_postfix

    state = _State(policy=None, baseline=None, robot_seconds=7200.0, pause_seconds=360.0)
    assert _time_postfix(_config(backend="sim"), state) == {"sim_h": "2.00"}
    assert _time_postfix(_config(backend="emulated"), state) == {"robot_h": "2.00",
                                                                  "pause_h": "0.10"}
