"""Careless calls, session 20 (careless16): what careless15 left.

Every truth here is the file system and the shell's own rule for '~' (os.path.expanduser under
a HOME the test sets), not project code.
"""

from __future__ import annotations

import numpy as np
import pytest
from pointmass import demo_info, expert_action, make_pointmass

# ------------------------------------------------------------------------------------------------
# '~' in the Python API: only the CLI read it as the home folder (careless15); train(out_dir=
# "~/runs/x") wrote ./~/runs/x, and load_demos("~/d.h5") said "not found".


def test_a_run_folder_under_tilde_is_in_the_home_folder(home_and_cwd):
    from lowcostdex.algos.experiment import Run

    home, cwd = home_and_cwd
    run = Run.open("~/runs/npg", {"n_iter": 2}, tensorboard=False)
    run.close()
    assert (home / "runs" / "npg" / "config.json").is_file()
    assert list(cwd.iterdir()) == []  # no folder named '~' beside the user's files
    Run.check("~/runs/npg", {"n_iter": 2})  # the same folder is seen again (a start, no ckpt)


def test_demos_saved_and_loaded_under_tilde(home_and_cwd):
    from lowcostdex.demonstrations.dataset import load_demos, save_demos, teacher_episodes

    home, cwd = home_and_cwd
    episodes = teacher_episodes(make_pointmass(), lambda env, obs: expert_action(obs),
                                seeds=range(2))
    written = save_demos("~/demos.h5", episodes, demo_info())
    assert written == home / "demos.h5" and written.is_file()
    assert list(cwd.iterdir()) == []
    assert len(load_demos("~/demos.h5", only_successful=False).observations) > 0


def test_a_policy_and_a_log_under_tilde(home_and_cwd):
    import torch

    from lowcostdex.algos.configs import PolicyConfig
    from lowcostdex.algos.policy import GaussianMLPPolicy
    from lowcostdex.algos.train import load_policy
    from lowcostdex.gap import Trajectory, read_log, write_log

    home, cwd = home_and_cwd
    policy = GaussianMLPPolicy(6, 2, PolicyConfig(hidden_sizes=(8,)),
                               torch.Generator().manual_seed(3))
    torch.save({"policy": policy.to_checkpoint()}, home / "policy.pt")
    obs = np.zeros((1, 6))
    assert np.array_equal(np.asarray(load_policy("~/policy.pt").act(obs, deterministic=True)),
                          np.asarray(policy.act(obs, deterministic=True)))
    t = np.arange(100) * 0.01
    goal, q = np.sin(t)[:, None], 0.9 * np.sin(t - 0.05)[:, None]
    write_log("~/log.csv", Trajectory("log", t, goal, q, ("j",), ("j",)))
    assert (home / "log.csv").is_file() and list(cwd.iterdir()) == []
    assert np.allclose(read_log("~/log.csv").qpos, q)


def test_a_report_folder_under_tilde(home_and_cwd):
    from lowcostdex.outdir import staged_output  # write_report's only way to its folder

    home, cwd = home_and_cwd
    with staged_output("~/report", "gap analyze") as tmp:
        (tmp / "report.md").write_text("x")
    assert (home / "report" / "report.md").read_text() == "x"
    assert list(cwd.iterdir()) == []


# ------------------------------------------------------------------------------------------------
# a policy file lacking a PolicyConfig setting loaded silently with its default


def _checkpoint(**config):
    import torch

    from lowcostdex.algos.configs import PolicyConfig
    from lowcostdex.algos.policy import GaussianMLPPolicy

    policy = GaussianMLPPolicy(3, 2, PolicyConfig(hidden_sizes=(8,), **config),
                               torch.Generator().manual_seed(1))
    return policy, policy.to_checkpoint()


@pytest.mark.parametrize("setting,value", [("activation", "relu"), ("min_obs_std", 0.5)])
def test_a_policy_file_lacking_a_setting_it_acts_by_is_refused(setting, value):
    """Truth: the same net with relu instead of tanh (or another std floor) acts otherwise, so
    the default is a different policy; the refusal names the setting."""
    from lowcostdex.algos.policy import GaussianMLPPolicy
    from lowcostdex.errors import ConfigError

    _, ckpt = _checkpoint(**{setting: value})
    del ckpt["config"][setting]
    with pytest.raises(ConfigError, match=f"lacks {setting}, which shape how the policy acts"):
        GaussianMLPPolicy.from_checkpoint(ckpt)


def test_a_policy_file_lacking_a_training_setting_loads_with_a_warning():
    from lowcostdex.algos.policy import GaussianMLPPolicy

    policy, ckpt = _checkpoint(min_log_std=-2.0)
    del ckpt["config"]["min_log_std"]
    with pytest.warns(UserWarning, match=r"lacks min_log_std: loaded with the default "
                                         r"\(min_log_std=-3.0\)"):
        loaded = GaussianMLPPolicy.from_checkpoint(ckpt)
    obs = np.ones((2, 3))
    assert np.array_equal(np.asarray(loaded.act(obs, deterministic=True)),
                          np.asarray(policy.act(obs, deterministic=True)))


# ------------------------------------------------------------------------------------------------
# `train --resume` typed without the run's flags: told the differing settings, not what to type


def test_a_resume_without_the_runs_flags_names_the_flags_to_type(tmp_path, capsys):
    """Truth: the flags the refusal names, added to the same command, pass the run's own
    resume check (Run.check against the config.json the first command wrote)."""
    import dataclasses
    import shlex

    import torch
    from cli_check import run_cli

    from lowcostdex.algos.experiment import CHECKPOINT_DIR, Run
    from lowcostdex.algos.train import MUTABLE_ON_RESUME
    from lowcostdex.algos.train_cli import config_from_args
    from lowcostdex.cli import build_parser

    run = tmp_path / "run"
    first = ["train", "npg", "--out", str(run), "--n-traj", "7", "--hidden", "16", "16",
             "--eval-paired", "--step-size", "0.02"]
    Run.open(run, dataclasses.asdict(config_from_args(build_parser().parse_args(first))),
             tensorboard=False).close()
    (run / CHECKPOINT_DIR).mkdir()
    torch.save({"iteration": 0}, run / CHECKPOINT_DIR / "ckpt_000000.pt")
    again = ["train", "npg", "--out", str(run), "--resume"]
    code, err = run_cli(again, capsys)
    assert code != 0
    said = err.split("The run's own settings as flags: ")[1].strip()
    assert set(shlex.split(said)) == {"--eval-paired", "--n-traj", "7", "--hidden", "16",
                                      "--step-size", "0.02"}
    typed = build_parser().parse_args([*again, *shlex.split(said)])
    Run.check(run, dataclasses.asdict(config_from_args(typed)), resume=True,
              mutable_keys=MUTABLE_ON_RESUME)


def test_a_resume_with_a_switch_the_run_lacked_says_leave_it_out(tmp_path, capsys):
    import dataclasses

    import torch
    from cli_check import run_cli

    from lowcostdex.algos.experiment import CHECKPOINT_DIR, Run
    from lowcostdex.algos.train_cli import config_from_args
    from lowcostdex.cli import build_parser

    run = tmp_path / "run"
    first = ["train", "npg", "--out", str(run)]
    Run.open(run, dataclasses.asdict(config_from_args(build_parser().parse_args(first))),
             tensorboard=False).close()
    (run / CHECKPOINT_DIR).mkdir()
    torch.save({"iteration": 0}, run / CHECKPOINT_DIR / "ckpt_000000.pt")
    code, err = run_cli([*first, "--resume", "--eval-paired"], capsys)
    assert code != 0 and err.endswith("The run's own settings as flags: without --eval-paired")


# ------------------------------------------------------------------------------------------------
# two record-demos into one file at once


def test_an_append_waits_while_another_process_has_the_demo_file_open(tmp_path):
    """Truth: HDF5's own lock (a second process holding the file open, as another record-demos's
    append does); the append failed with 'unable to lock file' and the episode was lost."""
    import subprocess
    import sys

    from lowcostdex.demonstrations.dataset import load_demos, teacher_episodes
    from lowcostdex.demonstrations.file import DemoWriter

    episodes = teacher_episodes(make_pointmass(), lambda env, obs: expert_action(obs),
                                seeds=range(2))
    path = tmp_path / "demos.h5"
    writer = DemoWriter(path, demo_info())
    writer.append(episodes[0])
    holder = subprocess.Popen(
        [sys.executable, "-c", "import h5py, sys, time\nf = h5py.File(sys.argv[1], 'a')\n"
         "print('open', flush=True)\ntime.sleep(1.0)\nf.close()", str(path)],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "open"
        writer.append(episodes[1])  # while the other process holds it, then after
    finally:
        holder.wait(timeout=30)
    assert load_demos(path, only_successful=False).n_episodes == 2


# ------------------------------------------------------------------------------------------------
# a CSV log with units in its header


@pytest.mark.parametrize("header,said", [
    ("time [s],goal:j,qpos:j", "column 'time [s]' has a unit in its name; name it 'time' and "
                               "write its values in s"),
    ("time,goal:j [deg],qpos:j [deg]", "column 'goal:j [deg]' has a unit in its name; name it "
                                       "'goal:j' and write its values in rad (degrees times "
                                       "pi/180)"),
    ("time,goal:j,qpos:j (rad)", "name it 'qpos:j' and write its values in rad:"),
])
def test_a_csv_log_with_units_in_its_header_names_the_column_to_write(tmp_path, header, said):
    """Before: 'time [s]' was a "missing column 'time'"; 'qpos:j [deg]' a joint named
    'j [deg]'. A user's own column with a unit (not a channel) is not refused by this rule."""
    from lowcostdex.gap import LogError, read_log

    t = np.arange(100) * 0.01
    rows = "\n".join(f"{a:.3f},{np.sin(a):.5f},{0.9 * np.sin(a - 0.05):.5f}" for a in t)
    path = tmp_path / "log.csv"
    path.write_text(f"{header}\n{rows}\n")
    with pytest.raises(LogError) as err:
        read_log(path)
    assert said in str(err.value)
