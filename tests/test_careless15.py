"""Careless calls and bad inputs, session 20 (careless15). Each test of a defect fails on the code
before its fix (main 3bd40a3).

- ``--out=~/runs`` or ``--out "~/runs"`` (the shell leaves a quoted ``~``, and one after ``=``,
  unexpanded): the output went to a folder literally named ``~`` in the working folder.
- every file written atomically (``model --out``, a run's ``config.json`` / ``policy.pt`` /
  checkpoints, a report's files, an output folder's marker) was mode 0600, and every output
  folder written whole (``gap analyze --out``) 0700: ``tempfile`` makes them so, and the file
  moved into place kept it, so the user's group (a lab's shared runs) could not read them.
- a port of the other hand: ``record-log --port can0`` (the D'Claw's default hand, the Allegro's
  CAN channel) passed the port check, wrote its output folder, then failed "could not open port
  can0"; ``--port ttyUSB0`` (no ``/dev/``) the same; ``--hand allegro --port /dev/ttyUSB0`` was
  told to run ``sudo ip link set /dev/ttyUSB0 up type can``.

The truths: the HOME the test sets, the files in the folders before and after.
"""

from __future__ import annotations

import os
import stat
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
from cli_check import run_cli  # noqa: E402

_run = run_cli


# ------------------------------------------------------------------------------------------------
# a '~' the shell did not expand


MODEL = ["model", "dclaw", "--station", "none", "--fingers", "ff", "--no-thermal"]


@pytest.mark.parametrize("out", [["--out=~/finger.xml"], ["--out", "~/finger.xml"]])
def test_a_file_out_under_tilde_goes_to_the_home_folder(home_and_cwd, capsys, out):
    home, cwd = home_and_cwd
    code, err = _run([*MODEL, *out], capsys)
    assert code == 0, err
    assert (home / "finger.xml").read_text().startswith("<mujoco")
    assert list(cwd.iterdir()) == []  # no folder named '~' beside the user's files


def test_a_folder_out_under_tilde_goes_to_the_home_folder(home_and_cwd, capsys):
    home, cwd = home_and_cwd
    code, err = _run(["record-log", "--port", "emulated", "--logs", "1", "--seconds", "0.1",
                      "--out=~/my logs"], capsys)
    assert code == 0, err
    assert [p.name for p in (home / "my logs").glob("log_*.csv")] == ["log_0.csv"]
    assert list(cwd.iterdir()) == []
    # the command it offers to paste next names the home folder, not a quoted '~'
    assert str(home / "my logs") in capsys.readouterr().out + err


def test_a_demo_script_out_under_tilde(home_and_cwd):
    from lowcostdex.argtypes import path

    home, _ = home_and_cwd
    assert path("~/runs/npg") == str(home / "runs" / "npg")
    assert path("runs/~npg") == "runs/~npg"  # only a leading '~' is the home folder


# ------------------------------------------------------------------------------------------------
# outputs readable as the user's umask says


@pytest.fixture(params=[0o022, 0o027])
def user_umask(request):
    old = os.umask(request.param)
    yield request.param
    os.umask(old)


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_a_written_file_has_the_mode_open_gives(tmp_path, capsys, user_umask):
    (tmp_path / "plain.txt").write_text("x")  # what the user's own tools make
    expected = _mode(tmp_path / "plain.txt")
    assert expected == 0o666 & ~user_umask
    code, err = _run([*MODEL, "--out", str(tmp_path / "finger.xml")], capsys)
    assert code == 0, err
    assert _mode(tmp_path / "finger.xml") == expected

    from lowcostdex.algos.run_files import write_json
    from lowcostdex.outdir import write_bytes_atomic

    write_bytes_atomic(tmp_path / "policy.pt", b"weights")
    write_json(tmp_path / "config.json", {"seed": 0})
    assert _mode(tmp_path / "policy.pt") == _mode(tmp_path / "config.json") == expected


def test_a_folder_written_whole_has_the_mode_mkdir_gives(tmp_path, user_umask):
    from lowcostdex.outdir import MARKER, staged_output

    (tmp_path / "plain").mkdir()
    expected = _mode(tmp_path / "plain")
    assert expected == 0o777 & ~user_umask
    with staged_output(tmp_path / "report", "gap analyze") as tmp:
        (tmp / "report.md").write_text("# report")
    assert _mode(tmp_path / "report") == expected
    assert _mode(tmp_path / "report" / MARKER) == 0o666 & ~user_umask
    with staged_output(tmp_path / "report", "gap analyze") as tmp:  # a second run: old kept
        (tmp / "report.md").write_text("# report 2")
    assert _mode(tmp_path / "report") == expected
    (old,) = (tmp_path / "report" / "previous").iterdir()
    assert (old / "report.md").read_text() == "# report"


# ------------------------------------------------------------------------------------------------
# a port of the other hand


@pytest.mark.parametrize("port, words", [
    ("can0", "--port can0 is a CAN channel (the Allegro hand's bus), not the serial device of a "
             "Dynamixel bus (e.g. /dev/ttyUSB0); the commands that drive the Allegro take it "
             "with --hand allegro"),
    ("vcan1", "--port vcan1 is a CAN channel"),
    ("ttyUSB0", "--port ttyUSB0: no such file here; the serial device is /dev/ttyUSB0"),
])
def test_a_dclaw_command_refuses_a_port_of_the_other_kind_before_writing(
        tmp_path, monkeypatch, capsys, port, words):
    monkeypatch.chdir(tmp_path)
    for argv in (["record-log", "--port", port, "--out", "logs"],
                 ["record-demos", "--port", port, "--episodes", "1", "--out", "d.h5"],
                 ["main", "--port", port, "--out", "runs/main"]):
        code, err = _run(argv, capsys)
        assert code == 2, err
        assert words in err
        assert list(tmp_path.iterdir()) == []  # nothing written


def test_the_allegro_refuses_a_serial_device_as_its_can_channel(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, err = _run(["record-log", "--hand", "allegro", "--port", "/dev/ttyUSB0", "--out",
                      "logs"], capsys)
    assert code == 2
    assert err == ("lowcostdex record-log: error: CAN channel '/dev/ttyUSB0' is a device path, "
                   "not a CAN network interface (e.g. can0; `ip link` lists them); a serial "
                   "device such as /dev/ttyUSB0 is a D'Claw's Dynamixel bus, not the Allegro's")
    assert list(tmp_path.iterdir()) == []


def test_a_windows_port_name_is_still_left_to_the_bus():
    from lowcostdex.hardware.dynamixel.ports import check_port

    check_port("COM3")  # careless13's transfer test relies on it: no refusal here
    check_port("emulated")


# ------------------------------------------------------------------------------------------------
# JSON logs of other layouts


def _finger_log_rows() -> list[dict]:
    """A 3 s log of the bench joint 'arm' as rows of the project's columns."""
    import math

    return [{"time": k / 100, "goal:arm": 0.3 * math.sin(k / 30),
             "qpos:arm": 0.27 * math.sin((k - 3) / 30)} for k in range(300)]


def _analyze(tmp_path, capsys, *logs: str) -> tuple[int, str]:
    from test_bad_inputs import bench_model

    (tmp_path / "bench.xml").write_text(bench_model())
    return _run(["gap", "analyze", "--model", str(tmp_path / "bench.xml"), "--log",
                 *(str(tmp_path / name) for name in logs), "--out", str(tmp_path / "report")],
                capsys)


def _columns(rows: list[dict]) -> dict[str, list]:
    return {k: [r[k] for r in rows] for k in rows[0]}


@pytest.mark.parametrize("layout, data", [
    ("a list of rows", lambda rows: rows),
    ("an object of columns", _columns),
    ("pandas' split layout",  # DataFrame.to_json(orient="split")
     lambda rows: {"columns": list(rows[0]), "index": list(range(len(rows))),
                   "data": [list(r.values()) for r in rows]}),
])
def test_a_json_log_in_the_projects_columns_is_told_how_to_be_read(tmp_path, capsys, layout,
                                                                     data):
    import csv
    import json

    rows = _finger_log_rows()
    (tmp_path / "log.json").write_text(json.dumps(data(rows)))
    code, err = _analyze(tmp_path, capsys, "log.json")
    assert code == 2
    assert f"holds the project's log columns ({layout}: goal:arm, qpos:arm, time) as JSON" in err
    assert "the project's logs are CSV or NPZ. Write it as a CSV with the same columns" in err
    assert not (tmp_path / "report").exists()
    # beside CSV logs: the same words, not "mixing BAM JSON logs and project logs"
    with open(tmp_path / "log.csv", "w", newline="") as f:  # what the message says to do
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    code, err = _analyze(tmp_path, capsys, "log.csv", "log.json")
    assert code == 2 and "holds the project's log columns" in err
    from lowcostdex.gap.dataset import load_dataset

    (traj,) = load_dataset([tmp_path / "log.csv"], model=tmp_path / "bench.xml").trajectories
    assert traj.time.tolist() == [r["time"] for r in rows]


def test_lerobot_frames_and_a_list_of_bam_logs_are_named(tmp_path, capsys):
    import json

    from test_bad_inputs import bam_log

    frames = [{"timestamp": k / 30, "frame_index": k, "episode_index": 0,
               "observation.state": [0.1, 0.2], "action": [0.1, 0.25]} for k in range(90)]
    (tmp_path / "episode_000000.json").write_text(json.dumps(frames))
    code, err = _analyze(tmp_path, capsys, "episode_000000.json")
    assert code == 2
    assert "looks like LeRobot-style frames ('observation.state' / 'action' vectors" in err
    assert "'goal:<actuator>' (each action element: the command)" in err
    (tmp_path / "episode_000000.parquet").write_bytes(b"PAR1" + bytes(64) + b"PAR1")
    code, err = _analyze(tmp_path, capsys, "episode_000000.parquet")
    assert code == 2 and "a LeRobot dataset's episode file? write each episode as a CSV" in err
    (tmp_path / "two.json").write_text(json.dumps([bam_log(), bam_log()]))
    code, err = _run(["gap", "identify", "--log", str(tmp_path / "two.json")], capsys)
    assert code == 2
    assert "must be a JSON object, got list; it is a list of BAM logs: give each its own" in err


# ------------------------------------------------------------------------------------------------
# GapConfig.test_logs from Python, counting files


def _gap_logs(tmp_path) -> Path:
    """bench.xml, a.csv (8 s with logging paused 2 s after 4 s: two pieces) and b.csv (8 s)."""
    from test_bad_inputs import bench_model, csv_text, servo_log

    (tmp_path / "bench.xml").write_text(bench_model())
    paused = servo_log()
    paused["time"] = paused["time"] + 2.0 * (paused["time"] >= 4.0)
    (tmp_path / "a.csv").write_text(csv_text(paused))
    (tmp_path / "b.csv").write_text(csv_text(servo_log()))
    return tmp_path


def test_test_logs_that_hold_out_part_of_a_paused_log_are_refused(tmp_path):
    import numpy as np

    from lowcostdex.gap.dataset import episodes, load_dataset, split_episodes
    from lowcostdex.gap.trajectory import LogError

    d = _gap_logs(tmp_path)
    ds = load_dataset([d / "a.csv", d / "b.csv"], model=d / "bench.xml")
    assert [Path(s).name for s in ds.sources] == ["a.csv", "a.csv", "b.csv"]  # a.csv: 2 pieces
    eps = episodes(ds, None)

    def split(test):
        return split_episodes(ds, eps, np.random.default_rng(0), test)

    # (1,) meant "the second file", b.csv: it is a.csv's second piece, and a.csv's first piece
    # would have been fitted while its second was scored as held out
    with pytest.raises(LogError, match=r"test_logs holds out trajectory 1 of .*a\.csv but not 0: "
                       r"that log is trajectories 0, 1 of ds\.trajectories \(split at a time gap"):
        split((1,))
    with pytest.raises(LogError, match=r"test_logs \(3,\): the data set has 3 trajectories "
                       r"\(indices 0\.\.2\)"):
        split((3,))
    held = split((2,)).test  # b.csv whole, and a.csv whole: the roles --holdout gives
    assert {eps[i].traj for i in held} == {2}
    assert {eps[i].traj for i in split((0, 1)).test} == {0, 1}


# ------------------------------------------------------------------------------------------------
# env_kwargs written as for gym.make


def test_a_backend_in_env_kwargs_is_refused_not_trained_on_behind_the_configs_back():
    """TrainConfig(env_kwargs={"backend": "emulated"}) (gym.make's keyword, where the config has
    a field of its own) trained on the emulated robot while config.json said backend 'sim'."""
    from lowcostdex.algos.configs import TrainConfig
    from lowcostdex.algos.local_models.train_config import TVLGTrainConfig
    from lowcostdex.errors import ConfigError

    words = ("env_kwargs holds 'backend': 'emulated'; the backend is the config's own field (it "
             "decides how samples are drawn and counted): give backend='emulated' and leave it "
             "out of env_kwargs")
    for cls in (TrainConfig, TVLGTrainConfig):
        with pytest.raises(ConfigError) as err:
            cls(env_kwargs={"backend": "emulated"})
        assert str(err.value) == words
    assert TrainConfig(backend="emulated", env_kwargs={"motor": "XM430-W350"}).backend == "emulated"


@pytest.mark.parametrize("item, words", [("backend=emulated", "give --backend emulated instead"),
                                         ("port=/dev/ttyUSB0", "give --port /dev/ttyUSB0 instead")])
def test_train_env_kwarg_backend_or_port_names_the_option(tmp_path, capsys, item, words):
    code, err = _run(["train", "npg", "--env-kwarg", item, "--out", str(tmp_path / "run"),
                      "--n-iter", "1"], capsys)
    assert code == 2
    assert err == f"lowcostdex train npg: error: --env-kwarg {item}: {words}"
    assert not (tmp_path / "run").exists()


# ------------------------------------------------------------------------------------------------
# policies from other checkpoints


def _a_policy():
    import torch

    from lowcostdex.algos.configs import PolicyConfig
    from lowcostdex.algos.policy import GaussianMLPPolicy

    return GaussianMLPPolicy(6, 2, PolicyConfig(hidden_sizes=(8,)), torch.Generator().manual_seed(3))


def test_a_ppo_checkpoint_loads_its_actor(tmp_path):
    """A `train ppo` checkpoint keeps the policy as 'actor' (ppo._Agent.state): load_policy
    said 'lacks policy'. Measured on a real PPO run (rl13's flip ppo_2): its newest
    checkpoint's actor acts as its final_policy.pt to 0.0."""
    import numpy as np
    import torch

    from lowcostdex.algos.train import load_policy

    policy = _a_policy()
    (tmp_path / "checkpoints").mkdir()
    torch.save({"actor": policy.to_checkpoint(), "critic": {}, "optimizer": {},
                "counters": {"samples": 10, "wall_seconds": 1.0}},
               tmp_path / "checkpoints" / "ckpt_000004.pt")
    loaded = load_policy(tmp_path / "checkpoints" / "ckpt_000004.pt")
    obs = np.random.default_rng(0).normal(size=(4, 6))
    assert np.array_equal(np.asarray(loaded.act(obs, deterministic=True)),
                          np.asarray(policy.act(obs, deterministic=True)))


def test_a_checkpoint_folder_and_a_bare_state_dict_say_what_to_give(tmp_path):
    import torch

    from lowcostdex.algos.train import load_policy
    from lowcostdex.errors import InputError

    ckpts = tmp_path / "run" / "checkpoints"
    ckpts.mkdir(parents=True)
    for k in (1, 2):
        torch.save({"policy": _a_policy().to_checkpoint()}, ckpts / f"ckpt_00000{k}.pt")
    with pytest.raises(InputError) as err:
        load_policy(ckpts)
    assert str(err.value) == (
        f"{ckpts} is a run's checkpoint folder: give the run folder {str(ckpts.parent)!r} (its "
        f"policy.pt, the best evaluated policy) or one checkpoint file, e.g. "
        f"{str(ckpts / 'ckpt_000002.pt')!r} (the newest)")
    torch.save(_a_policy().state_dict(), tmp_path / "mine.pt")  # what a torch user saves
    with pytest.raises(InputError, match=r"mine\.pt: lacks policy \(its keys: act_scale, "
                       r"act_shift, log_std, .*\); a bare state_dict has no sizes or settings "
                       r"to build the policy from: save \{'policy': policy.to_checkpoint\(\)\}"):
        load_policy(tmp_path / "mine.pt")


# ------------------------------------------------------------------------------------------------
# the same run written by two processes at once


HOLDER = """
import sys, time
from lowcostdex.algos.experiment import Run
Run.open(sys.argv[1], {"algo": "npg", "seed": 0}, tensorboard=False)
print("open", flush=True)
time.sleep(120)
"""


def test_a_run_being_trained_by_another_process_is_not_written_into(tmp_path):
    """`lowcostdex train ... --out runs/npg` started twice (a second terminal), or `--resume`
    while the run still trains: both processes wrote the run's config.json, metrics.csv and
    checkpoints in turn (a start with no checkpoint yet is replaced by a new start)."""
    import json
    import subprocess

    from lowcostdex.algos.experiment import Run
    from lowcostdex.outdir import OutputRefused

    run = tmp_path / "runs" / "npg"
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(run)], stdout=subprocess.PIPE,
                              text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        assert holder.stdout.readline().strip() == "open"
        with pytest.raises(OutputRefused) as err:
            Run.open(run, {"algo": "npg", "seed": 1}, tensorboard=False)
        assert str(err.value) == (
            f"{run} is being written by another process right now (a training run); it is left "
            "to it. Wait for it to end, or stop it first (Ctrl-C saves the run's state; then "
            "--resume)")
        assert json.loads((run / "config.json").read_text()) == {"algo": "npg", "seed": 0}
    finally:
        holder.kill()
        holder.wait()
    again = Run.open(run, {"algo": "npg", "seed": 1}, tensorboard=False)  # the writer is gone
    assert Run.open(run, {"algo": "npg", "seed": 1}, tensorboard=False).path == again.path
    again.close()


def test_record_log_into_a_folder_another_recording_is_writing_is_refused(tmp_path, capsys):
    """Two `record-log --out logs` at once: the second moved the first's finished logs into
    previous/ while the first went on writing log_<k>.csv beside the second's."""
    import subprocess

    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "log_0.csv").write_text("time,goal:ff_top,qpos:ff_top\n")  # the first's, so far
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time; from lowcostdex.outdir import claim, "
         "write_marker; write_marker(sys.argv[1], 'record-log'); claim(sys.argv[1], "
         "'record-log'); print('open', flush=True); time.sleep(120)", str(logs)],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "open"
        code, err = _run(["record-log", "--port", "emulated", "--logs", "1", "--seconds", "0.1",
                          "--out", str(logs)], capsys)
        assert code == 2
        assert err == (f"lowcostdex record-log: error: {logs} is being written by another "
                       "process right now (record-log); it is left to it. Wait for it to end, "
                       "or stop it first (Ctrl-C keeps its finished logs), or give another --out")
        assert sorted(p.name for p in logs.iterdir()) == [".lowcostdex.json", "log_0.csv"]
    finally:
        holder.kill()
        holder.wait()


def test_a_resume_with_other_settings_says_where_the_runs_own_are(tmp_path):
    """`lowcostdex train npg --out RUN --resume` typed without the run's other options (their
    defaults differ from the run's) was told only which settings differ."""
    import torch

    from lowcostdex.algos.experiment import CHECKPOINT_DIR, Run
    from lowcostdex.errors import ConfigError

    run = tmp_path / "run"
    Run.open(run, {"algo": "npg", "n_traj": 2, "n_iter": 3}, tensorboard=False).close()
    (run / CHECKPOINT_DIR).mkdir()
    torch.save({"iteration": 0}, run / CHECKPOINT_DIR / "ckpt_000000.pt")
    with pytest.raises(ConfigError) as err:
        Run.open(run, {"algo": "npg", "n_traj": 50, "n_iter": 3}, resume=True,
                 mutable_keys=("n_iter",), tensorboard=False)
    assert str(err.value) == (
        f"cannot resume {run}: configuration differs (n_traj: 2 -> 50); only ['n_iter'] may "
        f"change. Give the settings the run was started with (they are in {run / 'config.json'}; "
        "a stopped run printed the command that resumes it)")
