"""Careless calls and bad inputs, session 22 (careless19): each test's truth is the user's own
input written here (the command line typed, a file saved by the user); the code must refuse it
saying what to type, or say what it is about to do."""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.cli import main
from lowcostdex.errors import InputError

# ------------------------------------------------------------------------------------------------
# comma-separated names with an empty item or a repeat (careless18 found-not-fixed)


@pytest.mark.parametrize("argv,said", [
    # before: ran dapg and npg without a word about the missing name
    (["transfer", "--algos", "dapg,,npg"],
     "--algos 'dapg,,npg' has an empty name (two commas together: a name left out?); type "
     "--algos dapg,npg"),
    # before: ('dapg', 'dapg') went into the size as typed
    (["transfer", "--algos", "dapg,dapg"],
     "--algos 'dapg,dapg' names dapg more than once; name each once; type --algos dapg"),
    (["transfer", "--conditions", ",nominal"], "--conditions ',nominal' has an empty name"),
    # before: 'ff,,mf' handed build_dclaw an empty finger name
    (["model", "dclaw", "--fingers", "ff,,mf"], "--fingers 'ff,,mf' has an empty name"),
    (["model", "dclaw", "--fingers", "ff,ff"], "--fingers 'ff,ff' names ff more than"),
    (["main", "--stages", "bus,bus"], "--stages 'bus,bus' names bus more than once"),
])
def test_a_list_option_with_an_empty_name_or_a_repeat_is_refused_before_anything_runs(
        argv, said, tmp_path, capsys):
    out = tmp_path / ("m.xml" if argv[0] == "model" else "out")
    assert main([*argv, "--out", str(out)]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert said in err
    assert not out.exists()  # nothing written


def test_a_trailing_comma_is_still_read_as_the_names_before_it():
    from lowcostdex.argtypes import names

    assert names("latency, backlash,", "--candidates") == ("latency", "backlash")
    assert names(",", "--algos") == ()  # the caller says "empty" in its own words


# ------------------------------------------------------------------------------------------------
# a bare `reset-test` says what it runs before the first trial (careless17 found-not-fixed)


def test_a_bare_reset_test_says_what_it_runs_before_the_first_trial(monkeypatch, capsys):
    """Before: the first output was the progress bar of 20 trials; nothing said they run on the
    emulated hand, nor how to run them on the user's D'Claw. The trials are stopped here as
    Ctrl-C would stop them."""
    import lowcostdex.hardware.robot.reset_trials as trials

    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(trials, "reset_trials", ctrl_c)
    assert main(["reset-test"]) == 130
    err = " ".join(capsys.readouterr().err.split())
    assert ("lowcostdex reset-test: 20 trials of the lowcostdex reset (tangle the fingers, then "
            "reset) on the emulated D'Claw (virtual time, the default servo effects), seed 0; "
            "--trials N, --backend hardware --port DEVICE for your D'Claw") in err


# ------------------------------------------------------------------------------------------------
# a policy file of another task (careless17 found-not-fixed: policy files recorded no env)

VALVE, SCREW = "lowcostdex/DClawTurnValve-v0", "lowcostdex/DClawScrew-v0"


OLD_KEYS = ("obs_dim", "act_dim", "config", "dtype", "state_dict")
"""The entries of a policy checkpoint written before policies recorded their env (session 21)."""


def _policy_file(path, obs_dim=4, act_dim=2, trained_on=None, old=False):
    import torch

    from lowcostdex.algos.policy import GaussianMLPPolicy
    from lowcostdex.algos.run_files import save_state

    policy = GaussianMLPPolicy(obs_dim, act_dim, generator=torch.Generator().manual_seed(0))
    policy.trained_on = trained_on
    path.parent.mkdir(parents=True, exist_ok=True)
    ckpt = policy.to_checkpoint()
    save_state(path, {"policy": {k: ckpt[k] for k in OLD_KEYS} if old else ckpt})
    return path


def test_a_policy_saved_with_its_env_is_refused_for_another_env(tmp_path):
    # before: load_policy read any policy of the right sizes; it acted on the valve silently
    from lowcostdex.algos.policy_files import load_policy

    file = _policy_file(tmp_path / "screw.pt", trained_on=SCREW)
    assert load_policy(file).trained_on == SCREW
    with pytest.raises(InputError, match=rf"a policy trained on {SCREW}, not on {VALVE}.*"
                                         rf"--env {VALVE}"):
        load_policy(file, env=VALVE)
    assert load_policy(file, env=SCREW).trained_on == SCREW


def test_a_policy_file_of_an_older_run_takes_its_env_from_the_runs_config(tmp_path):
    # a run folder as `train` wrote it before policies recorded their env: config.json beside
    import json

    from lowcostdex.algos.policy_files import load_policy

    run = tmp_path / "run"
    _policy_file(run / "policy.pt", old=True)
    _policy_file(run / "checkpoints" / "ckpt_000001.pt", old=True)
    (run / "config.json").write_text(json.dumps({"algo": "npg", "env_id": SCREW}))
    for path in (run, run / "policy.pt", run / "checkpoints" / "ckpt_000001.pt"):
        with pytest.raises(InputError, match=rf"trained on {SCREW}, not on {VALVE}"):
            load_policy(path, env=VALVE)
    # a new file whose env is unknown (an env_factory without a gymnasium spec) is not given
    # the config's env_id, which that run's env did not come from
    _policy_file(run / "policy.pt", trained_on=None)
    assert load_policy(run, env=VALVE).trained_on is None


def test_a_policy_of_other_sizes_is_refused_for_an_env_before_it_acts(tmp_path):
    import gymnasium as gym

    import lowcostdex.sim.envs  # noqa: F401  (registers the envs)
    from lowcostdex.algos.policy_files import load_policy

    env = gym.make(VALVE)
    try:
        obs_dim = int(np.prod(env.observation_space.shape))
        act_dim = int(np.prod(env.action_space.shape))
        file = _policy_file(tmp_path / "p.pt", obs_dim=obs_dim + 3, act_dim=act_dim)
        with pytest.raises(InputError, match=rf"sizes {obs_dim + 3}/{act_dim}; {VALVE} has "
                                             rf"{obs_dim}/{act_dim}"):
            load_policy(file, env=env)
        assert load_policy(_policy_file(tmp_path / "q.pt", obs_dim, act_dim, VALVE), env=env)
    finally:
        env.close()


# ------------------------------------------------------------------------------------------------
# `gap analyze --logs DIR`: the plural record-log writes (--logs N, its folder of logs)


@pytest.mark.parametrize("sub", ["analyze", "identify"])
def test_gap_takes_logs_spelt_as_record_log_spells_them(sub, tmp_path, capsys):
    # before: "the following arguments are required: --log" for a folder the user did give
    where = tmp_path / "my logs"  # a folder name with a space, as a user names one
    assert main(["gap", sub, "--logs", str(where), "--out", str(tmp_path / "out")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert f"{where}: no such file" in err and "required" not in err


# ------------------------------------------------------------------------------------------------
# every option of every command says what it is (`lowcostdex <sub> --help`)


def test_every_option_of_every_command_has_a_help_line(capsys):
    """Before: 43 options listed bare in --help (gap analyze --max-effects, train npg --sampler,
    --workers, --eval-every, tvlg --init, calibrate --baud, setup-motors --hand, ...): a new
    user could not tell what --max-effects counts or what --eval-every 0 does. (careless17's
    test covers the number options of type float only.)"""
    import argparse

    from lowcostdex.cli import build_parser

    def walk(parser, path):
        yield path, parser
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, child in action.choices.items():
                    yield from walk(child, [*path, name])

    bare = [f"{' '.join(path)} {action.option_strings[-1]}"
            for path, parser in walk(build_parser(), [])
            for action in parser._actions if action.option_strings and not action.help]
    assert bare == []


# ------------------------------------------------------------------------------------------------
# an env keyword misspelt names the one meant


def test_a_misspelt_env_keyword_names_the_one_meant():
    # before: "unknown keyword argument 'goal_rang' ...; valid: init_range, goal_offset,
    # goal_range, ..." - nine names and no word of which one was meant
    import gymnasium as gym

    import lowcostdex.sim.envs  # noqa: F401  (registers the envs)
    from lowcostdex.errors import ConfigError

    with pytest.raises(ConfigError, match=r"'goal_rang'.*did you mean 'goal_range'"):
        gym.make(VALVE, goal_rang=0.5)


# ------------------------------------------------------------------------------------------------
# record-demos stopped with Ctrl-C, then the same command again


def _demo_file(path, seeds):
    """A D'Claw valve demo file holding one short episode per seed, as an earlier record-demos
    run left it (its sizes are the env's: 9 joints; the observation size does not matter here)."""
    from lowcostdex.demonstrations.file import DatasetInfo, DemoWriter, Episode

    joints = tuple(f"{f}_{p}" for f in ("ff", "mf", "th") for p in ("top", "middle", "bottom"))
    info = DatasetInfo(env_id=VALVE, task="turn-valve", hand="{}", source="virtual_teacher",
                       control_period=0.1, obs_dim=3, act_dim=9, action_joints=joints)
    writer = DemoWriter(path, info)
    for seed in seeds:
        writer.append(Episode(observations=np.zeros((3, 3)), actions=np.zeros((2, 9)),
                              rewards=np.zeros(2), qpos=np.zeros((3, 10)),
                              qvel=np.zeros((3, 10)), time=np.arange(3) * 0.1,
                              success=np.ones(2, bool), seed=seed))
    return path


def test_record_demos_run_again_on_its_own_file_is_told_the_seed_that_adds_new_episodes(
        tmp_path, capsys):
    # before: the second run appended the episodes of seeds 0, 1, ... again; with the virtual
    # teacher they are the same demonstrations bit for bit (measured: 6 of 6 episodes' actions
    # equal across two runs), which BC and DAPG then count twice
    out = _demo_file(tmp_path / "demos.h5", seeds=[0, 1, 2])
    before = out.read_bytes()
    assert main(["record-demos", "--backend", "emulated", "--episodes", "5", "--out",
                 str(out)]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert (f"--out {out} already holds episodes of seeds 0-2 (an earlier run, stopped with "
            "Ctrl-C?); --seed 0 would record 3 of them again") in err
    assert "pass --seed 3 to add new ones" in err
    assert out.read_bytes() == before  # nothing recorded


def test_scan_ids_with_an_empty_item_is_refused():
    # before: "10,,12" scanned 10 and 12 as if the id between them had been typed
    from lowcostdex.hardware.cli import parse_ids

    with pytest.raises(InputError, match=r"--ids '10,,12' has an empty item .* type --ids 10,12"):
        parse_ids("10,,12")
    assert parse_ids("10-11,12,") == [10, 11, 12]
