"""``lowcostdex train`` under bad input and faults: the real CLI entry, what goes in, what must
come out (exit code, one line naming the file/field, no traceback, nothing of the user's gone,
nothing left behind that blocks the next start).

The runs are tiny (the point mass of tests/pointmass.py, 1-2 iterations of a few episodes).
"""

from __future__ import annotations

import dataclasses
import shlex
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np
import pytest
from pointmass import demo_info, expert_action, make_pointmass

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.policy import PolicyConfig
from lowcostdex.algos.train import TrainConfig, train
from lowcostdex.cli import INTERRUPTED, USER_ERROR, main  # exit codes 130 and 2
from lowcostdex.demonstrations.dataset import save_demos, teacher_episodes

ENV = "lowcostdex_test/PointMass-v0"
TINY = ["--n-iter", "2", "--n-traj", "2", "--eval-every", "1", "--eval-episodes", "1",
        "--hidden", "8", "--no-progress"]
BC = ["--bc-epochs", "2"]  # a clone's setting: dapg, or npg with --bc-init (refused otherwise)


@pytest.fixture(autouse=True)
def _pointmass_registered():
    if ENV not in gym.registry:
        gym.register(ENV, entry_point="pointmass:PointMass", max_episode_steps=30)


def _demos(path: Path, n: int = 2) -> Path:
    episodes = teacher_episodes(make_pointmass(), lambda env, obs: expert_action(obs),
                                seeds=range(1000, 1000 + n))
    return save_demos(path, episodes, dataclasses.replace(demo_info(), env_id=ENV))


def _train(capsys, algo: str, out: Path, *extra: str) -> tuple[int, str, str]:
    bc = BC if algo == "dapg" or "--bc-init" in extra else []
    code = main(["train", algo, "--env", ENV, "--out", str(out), *TINY, *bc, *extra])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def _assert_refused(code: int, err: str, *needles: str) -> None:
    """Refused as a user error: the exit code, one line naming ``needles``, no traceback."""
    assert code == USER_ERROR, err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def _tree(path: Path) -> dict[str, bytes]:
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*"))
            if p.is_file()}


# ----------------------------------------------------------------------------------------------
# 1. A failed start leaves nothing that blocks the next one


def test_a_missing_demo_file_writes_nothing_and_the_next_start_runs(tmp_path, capsys):
    out, missing = tmp_path / "run", tmp_path / "missing.h5"
    code, _, err = _train(capsys, "dapg", out, "--demos", str(missing))
    _assert_refused(code, err, str(missing), "does not exist")
    assert not out.exists()
    code, stdout, err = _train(capsys, "dapg", out, "--demos", str(_demos(tmp_path / "d.h5")))
    assert code == 0, err
    assert "final eval success rate" in stdout
    assert ex.read_metrics(out / ex.METRICS_FILE)["iteration"].tolist() == [0, 1]


def test_a_refused_start_in_an_existing_empty_folder_leaves_it_empty(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    code, _, err = _train(capsys, "npg", out, "--bc-init", "--demos", str(tmp_path / "no.h5"))
    _assert_refused(code, err, "no.h5")
    assert out.is_dir() and not any(out.iterdir())


def test_an_unknown_env_is_refused_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["train", "npg", "--env", "lowcostdex/NoSuchTask-v0", "--out", str(out), *TINY])
    _assert_refused(code, capsys.readouterr().err, "'lowcostdex/NoSuchTask-v0'",
                    "lowcostdex/DClawTurnValve-v0")
    assert not out.exists()


def test_a_start_killed_before_its_first_checkpoint_does_not_block(tmp_path, capsys):
    """What a kill (or a power cut) during the first iteration leaves: the config, perhaps some
    metric rows, no checkpoint. The next start replaces it; its rows are not kept."""
    out = tmp_path / "run"
    cfg = TrainConfig(env_id=ENV, n_iter=5, checkpoint_every=5, progress=False)
    run = ex.Run.open(out, dataclasses.asdict(cfg))
    run.log({ex.ITERATION: 0, ex.SAMPLES: 1})
    run.close()
    code, _, err = _train(capsys, "npg", out)
    assert code == 0, err
    assert ex.read_metrics(out / ex.METRICS_FILE)[ex.SAMPLES].tolist() == [60, 120]
    assert ex.read_json(out / ex.CONFIG_FILE)["n_iter"] == 2


def test_a_start_failing_during_its_first_iteration_removes_what_it_wrote(tmp_path):
    out = tmp_path / "run"

    def breaks_on_step():
        env = make_pointmass()
        env.step = lambda action: (_ for _ in ()).throw(RuntimeError("robot unplugged"))
        return env

    cfg = TrainConfig(env_id=ENV, n_iter=2, n_traj=2, progress=False)
    with pytest.raises(RuntimeError, match="unplugged"):
        train(cfg, out, env_factory=breaks_on_step)
    assert not out.exists()
    train(cfg, out, env_factory=make_pointmass)  # the next start runs
    assert (out / ex.POLICY_FILE).exists()


def test_a_run_with_a_checkpoint_is_kept_and_named(tmp_path, capsys):
    out = tmp_path / "run"
    assert _train(capsys, "npg", out)[0] == 0
    before = _tree(out)
    code, _, err = _train(capsys, "npg", out)
    _assert_refused(code, err, str(out), "iteration 1", "--resume")
    assert _tree(out) == before


@pytest.mark.parametrize("content", [{"config.json": "{\"mine\": 1}"},
                                     {"notes.txt": "my notes", "metrics.csv": "a,b\n1,2\n"}])
def test_a_users_folder_is_refused_untouched(tmp_path, capsys, content):
    out = tmp_path / "mine"
    out.mkdir()
    for name, text in content.items():
        (out / name).write_text(text)
    before = _tree(out)
    code, _, err = _train(capsys, "npg", out)
    _assert_refused(code, err, str(out))
    assert _tree(out) == before


def test_a_folder_holding_only_inputs_receives_the_run_beside_them(tmp_path, capsys):
    out = tmp_path / "run"
    demos = _demos(out / "demos.h5")
    data = demos.read_bytes()
    code, _, err = _train(capsys, "dapg", out, "--demos", str(demos))
    assert code == 0, err
    assert demos.read_bytes() == data and (out / ex.POLICY_FILE).exists()


# ----------------------------------------------------------------------------------------------
# 2. --resume falls back to the newest checkpoint that loads, and says which


def _assert_same_metrics(a, b):
    """Equal columns and values (NaN equals NaN), the timings aside."""
    keys = [k for k in a if not k.startswith("time_")]
    assert keys == [k for k in b if not k.startswith("time_")]
    for key in keys:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def _cut(file: Path) -> None:
    """What a full disk or a copy stopped half-way leaves: the first half of the file."""
    data = file.read_bytes()
    file.write_bytes(data[: len(data) // 2])


class _Payload:
    """An object whose unpickling would create ``marker`` (a malicious checkpoint)."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (open, (str(self.marker), "w"))


def test_resume_skips_a_cut_checkpoint_and_equals_the_uninterrupted_run(tmp_path, capsys):
    out, clean = tmp_path / "run", tmp_path / "clean"
    assert _train(capsys, "npg", out, "--n-iter", "3")[0] == 0
    _cut(out / "checkpoints" / "ckpt_000002.pt")
    code, stdout, err = _train(capsys, "npg", out, "--n-iter", "4", "--resume")
    assert code == 0, err
    assert "Traceback" not in err
    (line,) = [x for x in stdout.splitlines() if x.startswith("resuming")]
    assert "checkpoints/ckpt_000001.pt (after iteration 1)" in line
    assert "skipped ckpt_000002.pt (does not load" in line
    assert _train(capsys, "npg", clean, "--n-iter", "4")[0] == 0
    resumed, reference = (ex.read_metrics(d / ex.METRICS_FILE) for d in (out, clean))
    assert resumed["iteration"].tolist() == [0, 1, 2, 3]
    _assert_same_metrics(resumed, reference)


def test_resume_never_unpickles_objects_from_a_checkpoint(tmp_path, capsys):
    import torch

    out, marker = tmp_path / "run", tmp_path / "pwned"
    assert _train(capsys, "npg", out)[0] == 0
    torch.save({"policy": _Payload(marker), "baseline": {}, "counters": {}},
               out / "checkpoints" / "ckpt_000001.pt")
    code, stdout, err = _train(capsys, "npg", out, "--n-iter", "3", "--resume")
    assert code == 0, err
    assert "ckpt_000000.pt (after iteration 0); skipped ckpt_000001.pt (does not load" in stdout
    assert not marker.exists()


def test_resume_without_a_loadable_checkpoint_is_refused_and_changes_nothing(tmp_path, capsys):
    out = tmp_path / "run"
    assert _train(capsys, "npg", out)[0] == 0
    for file in (out / "checkpoints").glob("ckpt_*.pt"):
        _cut(file)
    before = _tree(out)
    code, _, err = _train(capsys, "npg", out, "--resume")
    _assert_refused(code, err, str(out), "no checkpoint loads", "ckpt_000000.pt", "ckpt_000001.pt")
    assert _tree(out) == before


# ----------------------------------------------------------------------------------------------
# 3. Ctrl-C saves and prints the exact resume command; exit code 130


def _ctrl_c_after(monkeypatch, steps: int) -> None:
    """Ctrl-C lands in the ``steps``-th env step from now (of any point mass)."""
    from pointmass import PointMass

    step, count = PointMass.step, [0]

    def interrupted(self, action):
        count[0] += 1
        if count[0] == steps:
            raise KeyboardInterrupt
        return step(self, action)

    monkeypatch.setattr(PointMass, "step", interrupted)


def _resume_command(err: str) -> list[str]:
    lines = err.splitlines()
    i = next(i for i, line in enumerate(lines) if line.endswith("Resume with:"))
    words = shlex.split(lines[i + 1])
    assert words[:3] == ["lowcostdex", "train", "npg"] and words[-1] == "--resume"
    return words[1:]


def test_ctrl_c_saves_prints_the_resume_command_and_the_resumed_run_equals_a_clean_one(
        tmp_path, capsys, monkeypatch):
    out, clean = tmp_path / "my run", tmp_path / "clean"  # a space the command must quote
    # iterations of 2 training + 1 evaluation episodes of 30 steps: Ctrl-C in iteration 2
    _ctrl_c_after(monkeypatch, 2 * 90 + 40)
    code, _, err = _train(capsys, "npg", out, "--n-iter", "4", "--seed", "3")
    assert code == INTERRUPTED, err
    assert "Traceback" not in err
    assert "interrupted (Ctrl-C); saved the state after iteration 1" in err
    monkeypatch.undo()
    code, _, err = main(_resume_command(err)), *capsys.readouterr()
    assert code == 0, err
    assert _train(capsys, "npg", clean, "--n-iter", "4", "--seed", "3")[0] == 0
    _assert_same_metrics(*(ex.read_metrics(d / ex.METRICS_FILE) for d in (out, clean)))


def test_ctrl_c_between_checkpoints_saves_the_last_completed_iteration(tmp_path, monkeypatch):
    cfg = TrainConfig(env_id=ENV, n_iter=5, n_traj=2, eval_every=0, eval_episodes=1,
                      checkpoint_every=4, policy=PolicyConfig(hidden_sizes=(8,)),
                      progress=False)
    _ctrl_c_after(monkeypatch, 2 * 60 + 10)  # in iteration 2; no checkpoint until iteration 3
    with pytest.raises(ex.Interrupted) as info:
        train(cfg, tmp_path / "run", env_factory=make_pointmass)
    assert info.value.iteration == 1
    assert info.value.checkpoint == tmp_path / "run" / "checkpoints" / "ckpt_000001.pt"
    monkeypatch.undo()
    train(cfg, tmp_path / "run", resume=True, env_factory=make_pointmass)
    train(cfg, tmp_path / "clean", env_factory=make_pointmass)
    _assert_same_metrics(*(ex.read_metrics(d / ex.METRICS_FILE)
                           for d in (tmp_path / "run", tmp_path / "clean")))


def test_ctrl_c_before_the_first_checkpoint_leaves_nothing(tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    _ctrl_c_after(monkeypatch, 10)
    code, _, err = _train(capsys, "npg", out)
    assert code == INTERRUPTED and "Traceback" not in err
    assert "before the first checkpoint; nothing to resume" in err
    assert not out.exists()


def test_ctrl_c_in_a_real_process_exits_130_with_the_resume_command(tmp_path):
    """SIGINT to a training process, as a terminal's Ctrl-C sends it."""
    script = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        import gymnasium as gym
        import pointmass
        gym.register({ENV!r}, entry_point="pointmass:PointMass", max_episode_steps=30)
        step = pointmass.PointMass.step
        pointmass.PointMass.step = lambda self, a: (time.sleep(0.002), step(self, a))[1]
        from lowcostdex.cli import main
        sys.exit(main(sys.argv[1:]))
        """)
    (tmp_path / "cli.py").write_text(script)
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, str(tmp_path / "cli.py"), "train", "npg", "--env", ENV, "--out",
         str(out), *TINY, "--n-iter", "50"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # as at a
    # terminal: a background job (`pytest ... &`) passes SIGINT on ignored, and Python then
    # never raises KeyboardInterrupt
    latest = out / "checkpoints" / "latest.json"
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None and not latest.exists():
        time.sleep(0.05)
    time.sleep(0.1)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == INTERRUPTED, err
    assert "Traceback" not in err
    words = _resume_command(err)
    assert words[words.index("--out") + 1] == str(out) and "--n-iter" in words
    saved = ex.read_json(latest)["iteration"]
    assert f"saved the state after iteration {saved} " in err


# ----------------------------------------------------------------------------------------------
# 4. Demo files and numbers validated where they enter: one line naming the file, field and
#    value; nothing written


def _set(name: str, value) -> Callable[[h5py.File], None]:
    def edit(f):
        f[name][value[0]] = value[1]
    return edit


def _drop(name: str) -> Callable[[h5py.File], None]:
    def edit(f):
        del f[name]
    return edit


def _attr(name: str, value) -> Callable[[h5py.File], None]:
    def edit(f):
        f.attrs[name] = value
    return edit


def _wider_observations(f) -> None:
    """Demos of an env with a 4-wide observation (the file consistent in itself)."""
    f.attrs["obs_dim"] = 4
    for k in range(int(f.attrs["total_episodes"])):
        obs = f[f"episode_{k}/observations"][()]
        del f[f"episode_{k}/observations"]
        f[f"episode_{k}/observations"] = np.hstack([obs, np.zeros((len(obs), 1))])


DEMO_CASES = {  # what is done to a good 2-episode file: the line names these
    "truncated file": (lambda path: path.write_bytes(path.read_bytes()[:1500]),
                       ["cannot be read as HDF5"]),
    "not HDF5": (lambda path: path.write_bytes(b"obs,act\n0.1,0.2\n"), ["not an HDF5 file"]),
    "missing field": (_drop("episode_1/actions"), ["episode_1/actions is missing"]),
    "NaN action": (_set("episode_0/actions", ((5, 0), np.nan)),
                   ["episode_0/actions[5, 0] = nan is not finite"]),
    "inf observation": (_set("episode_1/observations", ((2, 1), np.inf)),
                        ["episode_1/observations[2, 1] = inf is not finite"]),
    "1e6 action": (_set("episode_1/actions", ((3, 0), 1e6)),
                   ["episode_1/actions[3, 0] = 1000000.0", "action bounds [-1.0, 1.0]"]),
    "action beyond the bounds": (_set("episode_0/actions", ((0, 0), -1.2)),
                                 ["episode_0/actions[0, 0] = -1.2", "action bounds"]),
    "another env's id": (_attr("env_id", "lowcostdex/DClawTurnValve-v0"),
                         ["env_id is 'lowcostdex/DClawTurnValve-v0'", f"trains '{ENV}'"]),
    "another env's shapes": (_wider_observations, ["obs_dim/act_dim are 4/1", "has 3/1"]),
    "actions of the wrong width": (_attr("act_dim", 2),
                                   ["episode_0/actions has shape (30, 1)", "act_dim is 2"]),
}


@pytest.mark.parametrize("case", list(DEMO_CASES))
def test_a_bad_demo_file_is_refused_naming_file_field_and_value(tmp_path, capsys, case):
    edit, needles = DEMO_CASES[case]
    demos = _demos(tmp_path / "demos.h5")
    if case in ("truncated file", "not HDF5"):
        edit(demos)
    else:
        with h5py.File(demos, "r+") as f:
            edit(f)
    data, out = demos.read_bytes(), tmp_path / "run"
    code, _, err = _train(capsys, "dapg", out, "--demos", str(demos))
    _assert_refused(code, err, str(demos), *needles)
    assert demos.read_bytes() == data and not out.exists()


def test_a_folder_given_as_demo_file_is_refused(tmp_path, capsys):
    code, _, err = _train(capsys, "dapg", tmp_path / "run", "--demos", str(tmp_path))
    _assert_refused(code, err, str(tmp_path), "is a folder")


NUMBER_CASES = [  # (trainer, option, value, what the line says)
    ("npg", "--damping", "nan", "damping=nan must be a finite number in [0, inf)"),
    ("npg", "--damping", "-0.1", "damping=-0.1 must be a finite number in [0, inf)"),
    ("npg", "--step-size", "0", "step_size=0.0 must be a finite number in (0, inf)"),
    ("npg", "--step-size", "-0.05", "step_size=-0.05 must be a finite number in (0, inf)"),
    ("npg", "--step-size", "inf", "step_size=inf must be a finite number in (0, inf)"),
    ("npg", "--gamma", "1.5", "gamma=1.5 must be a finite number in [0, 1]"),
    ("npg", "--gae-lambda", "nan", "gae_lambda=nan must be a finite number in [0, 1]"),
    ("npg", "--init-log-std", "nan", "init_log_std=nan must be a finite number in [-3, inf)"),
    ("npg", "--n-traj", "0", "n_traj=0 must be an integer in [1, inf)"),
    ("npg", "--n-iter", "-3", "n_iter=-3 must be an integer in [1, inf)"),
    ("npg", "--workers", "0", "n_workers=0 must be an integer in [1, inf)"),
    ("npg", "--eval-episodes", "0", "eval_episodes=0 must be an integer in [1, inf)"),
    ("npg", "--eval-every", "-1", "eval_every=-1 must be an integer in [0, inf)"),
    ("npg", "--seed", "-1", "seed=-1 must be an integer in [0, inf)"),
    ("dapg", "--bc-epochs", "-1", "BC epochs=-1 must be an integer in [0, inf)"),
    ("npg", "--hidden", "0", "hidden_sizes=(0,) must be positive integers"),
    ("dapg", "--lam0", "inf", "lam0=inf must be a finite number in [0, inf)"),
    ("dapg", "--lam1", "nan", "lam1=nan must be a finite number in [0, 1]"),
    ("dapg", "--n-demos", "0", "n_demos=0 must be an integer in [1, inf) or None"),
    ("ppo", "--lr", "nan", "lr=nan must be a finite number in (0, inf)"),
    ("ppo", "--lr", "-0.001", "lr=-0.001 must be a finite number in (0, inf)"),
    ("ppo", "--num-minibatches", "0", "num_minibatches=0 must be an integer in [1, inf)"),
    ("ppo", "--num-envs", "0", "num_envs=0 must be an integer in [1, inf)"),
    ("ppo", "--clip-coef", "inf", "clip_coef=inf must be a finite number in (0, inf)"),
    ("ppo", "--ent-coef", "-0.01", "ent_coef=-0.01 must be a finite number in [0, inf)"),
    ("ppo", "--gamma", "0", "gamma=0.0 must be a finite number in (0, 1]"),
]


@pytest.mark.parametrize("algo,option,value,message", NUMBER_CASES,
                         ids=[f"{a} {o} {v}" for a, o, v, _ in NUMBER_CASES])
def test_a_bad_number_is_refused_with_its_valid_range(tmp_path, capsys, algo, option, value,
                                                      message):
    out = tmp_path / "run"
    extra = ["--demos", str(tmp_path / "d.h5")] if algo == "dapg" else []
    argv = (["train", "ppo", "--out", str(out), "--no-progress", option, value] if algo == "ppo"
            else ["train", algo, "--env", ENV, "--out", str(out), *TINY, *extra, option, value])
    code = main(argv)
    _assert_refused(code, capsys.readouterr().err, message)
    assert not out.exists()
