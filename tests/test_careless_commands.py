"""Every command beyond ``gap`` under a newcomer's careless calls (issue 12): a misspelt env id,
demos of another env, options that would be silently ignored, ``--resume`` of a run that is
not there, angles in degrees, NaN and absurdly large numbers, a user's files given as outputs.

Each row runs the real CLI entry (``lowcostdex.cli.main``, the same error path a process
takes) and must end with exit code 2, ONE line on stderr naming the bad input and the fix, no
traceback, and the folder byte for byte as it was (nothing of the user's touched, nothing new).
The expected lines are written out here; the joint names and ranges come from the D'Claw's
published build (ROBEL: top joints +-0.48 rad, 9 joints), not from the code under test.
``tests/test_train_faults.py`` holds the npg/dapg/ppo rows (demo files, numbers, resume);
``tests/test_bad_inputs.py`` and ``tests/test_careless_cli.py`` the gap rows.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from pointmass import demo_info, expert_action, make_pointmass

from lowcostdex.cli import USER_ERROR, main

POINTMASS = "lowcostdex_test/PointMass-v0"
TINY = ("--n-iter", "1", "--n-traj", "2", "--eval-every", "1", "--eval-episodes", "1",
        "--hidden", "8", "--no-progress")


@pytest.fixture(autouse=True)
def _pointmass_registered():
    if POINTMASS not in gym.registry:
        gym.register(POINTMASS, entry_point="pointmass:PointMass", max_episode_steps=30)


def pointmass_demos(path: Path) -> None:
    """Two successful demonstrations of the point mass (another env than any D'Claw task)."""
    from lowcostdex.demonstrations.dataset import save_demos, teacher_episodes

    episodes = teacher_episodes(make_pointmass(), lambda env, obs: expert_action(obs),
                                seeds=range(1000, 1002))
    save_demos(path, episodes, dataclasses.replace(demo_info(), env_id=POINTMASS))


@dataclass(frozen=True)
class Case:
    id: str
    argv: tuple[str, ...]
    message: str  # a substring of the one line; {tmp} is the test's folder
    files: dict = field(default_factory=dict)  # name -> text, or a callable(path) writing it


def npg(*extra: str) -> tuple[str, ...]:
    return ("train", "npg", "--env", POINTMASS, "--out", "{tmp}/run", *TINY, *extra)


def tvlg(*extra: str) -> tuple[str, ...]:
    return ("train", "tvlg", "--out", "{tmp}/run", "--n-iter", "1", "--no-progress", *extra)


DCLAW_JOINTS = ("ff_top, ff_middle, ff_bottom, mf_top, mf_middle, mf_bottom, th_top, "
                "th_middle, th_bottom")

CASES: list[Case] = [
    # --resume where there is no run: a typo in --out must not start over as if resumed
    Case("npg --resume of a folder that does not exist", npg("--resume"),
         "--resume: {tmp}/run does not exist, so there is nothing to resume; check --out, or "
         "leave out --resume to start a new run"),
    Case("npg --resume of a folder without a run", npg("--resume"),
         "--resume: {tmp}/run holds no run (no config.json)", files={"run/notes.txt": "mine\n"}),
    Case("ppo --resume of a folder that does not exist",
         ("train", "ppo", "--out", "{tmp}/run", "--resume", "--no-progress"),
         "--resume: {tmp}/run does not exist"),
    Case("tvlg --resume of a folder that does not exist", tvlg("--resume"),
         "--resume: {tmp}/run does not exist"),
    # a report folder of another command: the run went in beside report.md
    Case("npg --out a gap report's folder", npg(),
         "{tmp}/run holds the output of 'lowcostdex gap analyze', not a training run; it is left "
         "untouched", files={"run/.lowcostdex.json": '{"command": "gap analyze", "settings": {}}',
                             "run/report.md": "# gap report\n"}),
    # an empty path (an unset shell variable): Path("") is the working directory, so the run
    # was written among the user's files
    Case("npg --out ''", ("train", "npg", "--env", POINTMASS, "--out", "", *TINY),
         "--out is empty (an unset shell variable?); give a path",
         files={"notes.txt": "mine\n"}),
    Case("gap analyze --log a.csv ''", ("gap", "analyze", "--log", "a.csv", "", "--out", "r"),
         "--log has an empty path (an unset shell variable?)", files={"a.csv": lambda p: p.write_text(_log())}),
    Case("scan --port ''", ("scan", "--port", ""), "--port is empty"),
    Case("scan --ids ''", ("scan", "--port", "emulated", "--ids", ""),
         "--ids is empty; name the ids (e.g. --ids 10-12,50), or leave it out"),
    Case("record-log --joints ''", ("record-log", "--port", "emulated", "--joints", "", "--out",
                                    "{tmp}/logs"), "--joints is empty; name the joints"),
    # options that would be ignored without a word
    Case("npg --n-demos without --demos", npg("--n-demos", "3"),
         "--n-demos 3 counts episodes of a demo file: give it with --demos PATH"),
    Case("npg --demos without --bc-init", npg("--demos", "{tmp}/demos.h5"),
         "npg uses demonstrations only with --bc-init (behaviour-clone them first); add "
         "--bc-init, or train dapg", files={"demos.h5": pointmass_demos}),
    Case("tvlg --demos without --init demos", tvlg("--demos", "{tmp}/demos.h5"),
         "is read with --init demos only (this run starts from --init pd); add --init demos",
         files={"demos.h5": pointmass_demos}),
    # tvlg: the env id and the demo file checked like npg/dapg's, before anything is written
    Case("tvlg with a misspelt env", tvlg("--env", "TurnValve"),
         "unknown env 'lowcostdex/TurnValve'; lowcostdex envs: lowcostdex/AllegroTurnValve-v0"),
    Case("tvlg from demos of another env", tvlg("--init", "demos", "--demos", "{tmp}/demos.h5"),
         f"demos.h5: env_id is '{POINTMASS}': these demonstrations are of another env; this run "
         "trains 'lowcostdex/DClawTurnValve-v0'", files={"demos.h5": pointmass_demos}),
    # tvlg --start-hand-qpos: one angle in rad per D'Claw joint, inside its range
    Case("tvlg start pose of 2 joints", tvlg("--start-hand-qpos", "0", "0"),
         f"start_hand_qpos (--start-hand-qpos) has 2 values; the hand has 9 joints, one angle "
         f"each in rad: {DCLAW_JOINTS}"),
    Case("tvlg start pose with a NaN", tvlg("--start-hand-qpos", *["0"] * 8, "nan"),
         "start_hand_qpos (--start-hand-qpos) th_bottom=nan is not finite"),
    Case("tvlg start pose in degrees", tvlg("--start-hand-qpos", *["20"] * 9),
         "ff_top=20 rad is outside the joint's range [-0.48, 0.48] rad (degrees? write rad)"),
    # tvlg optimiser numbers: NaN passes every `<=` check, so it used to train
    Case("tvlg --kl-step nan", tvlg("--kl-step", "nan"),
         "TrajOptConfig.kl_step=nan must be a finite number"),
    Case("tvlg --min-step-mult nan", tvlg("--min-step-mult", "nan"),
         "TrajOptConfig.min_step_mult=nan must be a finite number"),
    Case("tvlg --prior-strength inf", tvlg("--prior-strength", "inf"),
         "DynamicsConfig.prior_strength=inf must be a finite number"),
]


def spec_with(edit) -> callable:
    """A D'Claw hand spec JSON (the built-in one as ``calibrate`` writes it) after ``edit``."""
    def write(path: Path) -> None:
        from lowcostdex.hands import dclaw_spec

        raw = json.loads(dclaw_spec().to_json())
        edit(raw)
        path.write_text(json.dumps(raw))
    return write


def reset_test(*extra: str) -> tuple[str, ...]:
    return ("reset-test", "--trials", "1", *extra)


NOTES = '{"todo": ["buy U2D2", "print the valve"]}'

CASES += [
    # reset-test --json: a user's file was overwritten after the trials; now checked before them
    Case("reset-test --json over a user's file", reset_test("--json", "{tmp}/notes.json"),
         "--json {tmp}/notes.json already exists and is not a 'lowcostdex reset-test' output; it "
         "is left untouched", files={"notes.json": NOTES}),
    Case("reset-test --json into a folder", reset_test("--json", "{tmp}"),
         "--json {tmp} is a folder; give a file path"),
    Case("reset-test --json into a missing folder", reset_test("--json", "{tmp}/no/s.json"),
         "--json {tmp}/no/s.json: the folder {tmp}/no does not exist"),
    Case("reset-test --latency-ms on the emulated robot", reset_test("--latency-ms", "16"),
         "--latency-ms is the serial adapter's latency timer: it needs --backend hardware"),
    # hand specs: a joint missing (StopIteration traceback), misspelt keys (ignored / TypeError)
    Case("a hand spec with 8 of the 9 joints",
         reset_test("--spec", "{tmp}/spec.json"),
         f"hand dclaw: joints ff_top, ff_middle, ff_bottom, mf_top, mf_middle, mf_bottom, "
         f"th_top, th_middle are not the D'Claw's 9 in action order: {DCLAW_JOINTS}",
         files={"spec.json": spec_with(lambda d: d["joints"].pop())}),
    Case("a hand spec with an unknown key", reset_test("--spec", "{tmp}/spec.json"),
         "spec.json: the spec: unknown key 'colour'; valid keys: name, motor, joints, aux_joints",
         files={"spec.json": spec_with(lambda d: d.update(colour="red"))}),
    Case("a hand spec with a misspelt joint key", reset_test("--spec", "{tmp}/spec.json"),
         "spec.json: joint ff_top: unknown key 'lowx'; valid keys: name, motor_id, low, high, "
         "max_velocity, calibration",
         files={"spec.json": spec_with(lambda d: d["joints"][0].update(lowx=-0.4))}),
    Case("a hand spec with a misspelt calibration key", reset_test("--spec", "{tmp}/spec.json"),
         "spec.json: joint ff_top: calibration: unknown key 'ofset'",
         files={"spec.json": spec_with(lambda d: d["joints"][0]["calibration"].update(ofset=1))}),
    Case("a hand spec that is a list", reset_test("--spec", "{tmp}/spec.json"),
         "spec.json: the spec must be a JSON object with keys name, motor, joints, aux_joints; "
         "got list", files={"spec.json": "[1, 2]"}),
    # bit rates: the emulated motors' (traceback before), a real adapter's option on the emulator
    Case("scan the emulated hand at a rate no motor runs at",
         ("scan", "--port", "emulated", "--baud", "12345"),
         "--baud 12345: the emulated motors run at one of 9600, 57600, 115200, 1000000, 2000000, "
         "3000000, 4000000, 4500000 bit/s"),
    Case("record-demos --baud on the emulated hand",
         ("record-demos", "--episodes", "1", "--out", "{tmp}/d.h5", "--baud", "7"),
         "--baud 7 is for a real robot's serial adapter (--port DEVICE); the emulated hand has "
         "none"),
    Case("record-demos --latency-ms on the emulated hand",
         ("record-demos", "--episodes", "1", "--out", "{tmp}/d.h5", "--latency-ms", "16"),
         "--latency-ms 16.0 is for a real robot's serial adapter"),
    Case("record-demos --playbacks with next_position labels",
         ("record-demos", "--episodes", "1", "--out", "{tmp}/d.h5", "--labels", "next_position",
          "--playbacks", "2"),
         "--playbacks 2: playbacks are labelled by the servo response (--labels servo_goal), not "
         "with --labels next_position"),
]

CASES += [
    # model --overwrite replaced ANY file with the MJCF: a demo file, a user's notes
    Case("model --overwrite over a demo file",
         ("model", "dclaw", "--out", "{tmp}/demos.h5", "--overwrite"),
         "--out {tmp}/demos.h5 is not an MJCF model (no <mujoco> root); --overwrite replaces a "
         "model file only, and this file is left untouched", files={"demos.h5": pointmass_demos}),
    Case("model --overwrite over a user's XML",
         ("model", "bench", "--out", "{tmp}/notes.xml", "--overwrite"),
         "is not an MJCF model", files={"notes.xml": "<notes><todo>tune kp</todo></notes>"}),
    Case("model with --fingers ''", ("model", "dclaw", "--fingers", "", "--out", "{tmp}/m.xml"),
         "--fingers is empty; name the fingers (e.g. --fingers ff), or leave it out"),
    Case("model allegro with a servo --motor",
         ("model", "allegro", "--motor", "XM430-W350", "--out", "{tmp}/m.xml"),
         "--motor XM430-W350: the Allegro's joints are torque-driven on CAN (no servo model)"),
    # a port that is not there / not a device: one line, before the output folder is made
    Case("main on a missing port", ("main", "--out", "{tmp}/o", "--port", "/dev/ttyUSB7"),
         "--port /dev/ttyUSB7: no such device"),
    Case("main on a file given as the port",
         ("main", "--out", "{tmp}/o", "--port", "{tmp}/notes.txt", "--stages", "bus"),
         "--port {tmp}/notes.txt: cannot open it as a serial port: it is a regular file, not a "
         "device", files={"notes.txt": "my notes\n"}),
    Case("record-log --effects with a latency in ms",
         ("record-log", "--port", "emulated", "--logs", "1", "--seconds", "1", "--effects",
          "{tmp}/effects.json", "--out", "{tmp}/logs"),
         "effect latency: parameter 'delay' = 20 [s] is outside its limits [0, 0.25] s",
         files={"effects.json": '[{"effect": "latency", "joints": ["ff_top"], '
                                '"params": {"delay": 20}}]'}),
    Case("reset-test on a file given as the port",
         ("reset-test", "--port", "{tmp}/notes.txt", "--trials", "1"),
         "cannot open it as a serial port: it is a regular file", files={"notes.txt": "x\n"}),
]

CASES += [
    # sizes whose memory or time grows without end: ran until killed, or a std::bad_alloc
    # traceback (ppo), or an overflowing exp (init-log-std); NPG's delta of 1e300 trained
    Case("npg --n-traj 1e9", npg("--n-traj", "1000000000"),
         "n_traj=1000000000 is above 10000: more trajectories per iteration than a run needs"),
    Case("npg --eval-episodes 1e9", npg("--eval-episodes", "1000000000"),
         "eval_episodes=1000000000 is above 10000"),
    Case("npg --hidden 1e8", npg("--hidden", "100000000"),
         "hidden_sizes=100000000 is above 4096: a layer that wide holds its width squared"),
    Case("npg --workers 1e5", npg("--workers", "100000"),
         "n_workers=100000 is above 1024: one process each"),
    Case("npg --init-log-std 1e9", npg("--init-log-std", "1e9"),
         "init_log_std=1000000000.0 is above 3: an exploration std of e^3 = 20 in actions "
         "bounded to [-1, 1]"),
    Case("npg --step-size 1e300", npg("--step-size", "1e300"),
         "step_size=1e+300 is above 100: a KL step of delta/2 nats per iteration leaves no trust "
         "region"),
    Case("ppo --num-envs 1e8", ("train", "ppo", "--out", "{tmp}/run", "--num-envs", "100000000",
                                "--no-progress"),
         "num_envs=100000000 is above 16384: every copy's simulator state"),
    Case("tvlg --n-rollouts 1e9", tvlg("--n-rollouts", "1000000000"),
         "n_rollouts=1000000000 is above 1000: episodes per iteration are held in memory"),
    Case("record-demos --episodes 1e9",
         ("record-demos", "--episodes", "1000000000", "--out", "{tmp}/d.h5"),
         "--episodes 1000000000 is above 10000: each is an episode on the robot"),
    Case("record-log --logs 1e9",
         ("record-log", "--port", "emulated", "--logs", "1000000000", "--out", "{tmp}/logs"),
         "--logs 1000000000 is above 10000: each log is a file"),
    Case("reset-test --trials 1e9", reset_test()[:1] + ("--trials", "1000000000"),
         "--trials 1000000000 is above 10000: each trial tangles and resets the robot"),
    Case("ppo --threads 1e5", ("train", "ppo", "--out", "{tmp}/run", "--threads", "100000",
                               "--no-progress"), "nthread=100000 is above 1024"),
]



def _log() -> str:
    from test_bad_inputs import csv_text, servo_log

    return csv_text(servo_log())


def _bench() -> str:
    from test_bad_inputs import bench_model

    return bench_model()


HOLDOUT = ("gap", "analyze", "--model", "bench.xml", "--log", "a.csv", "b.csv", "--out", "rep")
CASES += [
    # --holdout naming the copy that the duplicate rule left out ("must also be given with
    # --log", though it was given)
    Case("--holdout naming a byte-identical copy of another log", (*HOLDOUT, "--holdout", "b.csv"),
         "--holdout b.csv holds the same bytes as the log a.csv, which is used once (a copy would "
         "be fitted and tested at once): hold out a.csv itself",
         files={"bench.xml": _bench, "a.csv": _log, "b.csv": _log}),
    Case("--holdout naming a file not given with --log", (*HOLDOUT, "--holdout", "c.csv"),
         "--holdout c.csv is not among the logs; every --holdout file must also be given with "
         "--log", files={"bench.xml": _bench, "a.csv": _log, "b.csv": _log,
                        "c.csv": lambda p: p.write_text(_log().replace("\n0.0000,", "\n0.0001,"))}),
    Case("identify --holdout naming a byte-identical copy",
         ("gap", "identify", "--log", "a.json", "b.json", "--holdout", "b.json"),
         "--holdout b.json holds the same bytes as the log a.json",
         files={"a.json": lambda p: p.write_text(_bam()), "b.json": lambda p: p.write_text(_bam())}),
]


def _bam() -> str:
    from test_bad_inputs import bam_log

    return json.dumps(bam_log())


def _materialize(case: Case, root: Path) -> list[str]:
    for name, content in case.files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if callable(content):
            content = content() if content.__code__.co_argcount == 0 else content(path)
            if isinstance(content, str):
                path.write_text(content)
        else:
            path.write_text(content)
    return [a.replace("{tmp}", str(root)) for a in case.argv]


def _snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_a_careless_call_is_refused_in_one_line(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = _materialize(case, tmp_path)
    before = _snapshot(tmp_path)
    code = main(argv)
    out, err = capsys.readouterr()
    assert code == USER_ERROR, err
    assert "Traceback" not in err + out
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("[progress]")]
    assert len(lines) == 1, err
    assert ": error: " in lines[0]
    assert case.message.replace("{tmp}", str(tmp_path)) in lines[0], lines[0]
    assert _snapshot(tmp_path) == before


def test_the_controls_run(tmp_path, capsys):
    """The same calls made right run: --resume of a run that is there, npg --bc-init with the
    demos, tvlg from a start pose inside the joint ranges, reset-test from an unedited spec
    replacing its own previous --json (so each refusal comes from its mistake)."""
    out = tmp_path / "run"
    assert main(["train", "npg", "--env", POINTMASS, "--out", str(out), *TINY]) == 0
    assert main(["train", "npg", "--env", POINTMASS, "--out", str(out), *TINY, "--n-iter", "2",
                 "--resume"]) == 0, capsys.readouterr().err
    pointmass_demos(tmp_path / "demos.h5")
    assert main(["train", "npg", "--env", POINTMASS, "--out", str(tmp_path / "bc"), *TINY,
                 "--demos", str(tmp_path / "demos.h5"), "--bc-init", "--bc-epochs", "1",
                 "--n-demos", "1"]) == 0, capsys.readouterr().err
    argv = [a.replace("{tmp}/run", str(tmp_path / "tvlg")) for a in tvlg(
        "--n-rollouts", "2", "--start-hand-qpos", "0.1", *["0"] * 7, "-0.2")]
    assert main(argv) == 0, capsys.readouterr().err
    spec_with(lambda d: None)(tmp_path / "spec.json")
    summary = tmp_path / "summary.json"
    for _ in range(2):  # the second run replaces the first's summary
        code = main(["reset-test", "--trials", "1", "--spec", str(tmp_path / "spec.json"),
                     "--json", str(summary)])
        assert code in (0, 1), capsys.readouterr().err  # 1: a trial failed (not an error)
        assert json.loads(summary.read_text())["trials"] == 1


@pytest.mark.parametrize("written", ["XL330-M288", "xl330-m288-t", "XL330_M288", "XL330"])
def test_a_bam_motor_written_as_its_full_model_name_reads_as_bam_s_name(written, tmp_path):
    """Rhoban/bam's logs say "xl330" for the XL330-M288 (ROBOTIS' name, typed by hand into a log
    header): the same log with either name loads to the same data set."""
    from test_bad_inputs import bam_log

    from lowcostdex.gap.dataset import load_dataset

    datasets = []
    for name in ("xl330", written):
        (tmp_path / "bam.json").write_text(json.dumps(bam_log(motor=name)))
        datasets.append(load_dataset([tmp_path / "bam.json"]))
    a, b = (ds.trajectories[0] for ds in datasets)
    assert np.array_equal(a.time, b.time) and np.array_equal(a.qpos, b.qpos)
    assert datasets[0].models == datasets[1].models and datasets[1].notes == []


def test_resuming_another_trainer_s_run_names_the_trainer(tmp_path, capsys):
    """``--resume`` of an npg run with ppo or tvlg printed a diff of every setting the two
    configurations do not share (hundreds of characters); now one line naming both trainers.
    npg -> dapg keeps the settings' diff (one trainer, ``algo`` differs)."""
    out = tmp_path / "run"
    assert main(["train", "npg", "--env", POINTMASS, "--out", str(out), *TINY]) == 0
    before = _snapshot(tmp_path)
    capsys.readouterr()
    for argv, needle in (
            (["train", "ppo", "--out", str(out), "--no-progress", "--resume"],
             "it is a run of 'train npg/dapg', not of 'train ppo'; resume it with the trainer "
             "that started it"),
            (["train", "tvlg", "--out", str(out), "--no-progress", "--resume"],
             "it is a run of 'train npg/dapg', not of 'train tvlg'")):
        assert main(argv) == USER_ERROR
        err = capsys.readouterr().err
        lines = [ln for ln in err.splitlines() if ln.strip()]
        assert len(lines) == 1 and needle in lines[0] and "Traceback" not in err, err
        assert _snapshot(tmp_path) == before


def test_a_current_read_that_failed_costs_the_current_channel_not_the_rows(tmp_path):
    """A current reading missing in one row of a log whose goal changes at every row: the rows
    were dropped and the log cut in two there (the goal across the gap unknown); the current is
    only checked, never replayed, so now the channel is left out and all 800 rows kept, equal to
    the clean log's. A failed position read still drops its row (the replay needs it)."""
    from test_bad_inputs import bench_model, csv_text, servo_log

    from lowcostdex.gap.dataset import load_dataset

    (tmp_path / "bench.xml").write_text(bench_model())

    def load(cols):
        (tmp_path / "log.csv").write_text(csv_text(cols))
        return load_dataset([tmp_path / "log.csv"], model=tmp_path / "bench.xml")

    clean = load(servo_log()).trajectories[0]
    cols = servo_log()
    cols["current:arm"] = np.where(np.arange(800) == 417, np.nan, cols["current:arm"])
    ds = load(cols)
    assert ds.notes == ["log.csv: 1 row(s) lack only 'current:arm' (first: row 417, 0-based): "
                        "the current channel is left out and the rows kept (it is only checked, "
                        "never replayed)"]
    (tr,) = ds.trajectories
    assert "current" in clean.channels and "current" not in tr.channels
    for k in ("time", "goal", "qpos"):
        assert np.array_equal(getattr(tr, k), getattr(clean, k))
    cols["qpos:arm"] = np.where(np.arange(800) == 200, np.nan, cols["qpos:arm"])
    assert [len(t) for t in load(cols).trajectories] == [200, 599]


def test_ctrl_c_during_record_demos_keeps_the_finished_episodes_and_says_so(tmp_path, capsys,
                                                                             monkeypatch):
    """Ctrl-C in the second episode: exit 130, one line saying what the file holds and how to
    add more; the file holds the first episode and reads as a demo file (it printed only
    "interrupted (Ctrl-C)" before)."""
    import h5py

    from lowcostdex.demonstrations.kinesthetic import KinestheticRecorder
    from lowcostdex.errors import INTERRUPTED

    record, calls = KinestheticRecorder.record_episode, [0]

    def interrupted(self, seed):
        calls[0] += 1
        if calls[0] == 2:
            raise KeyboardInterrupt
        return record(self, seed)

    monkeypatch.setattr(KinestheticRecorder, "record_episode", interrupted)
    out = tmp_path / "demos.h5"
    code = main(["record-demos", "--episodes", "3", "--labels", "next_position", "--out",
                 str(out)])
    err = capsys.readouterr().err
    assert code == INTERRUPTED, err
    lines = [ln for ln in err.splitlines() if "interrupted" in ln]
    assert len(lines) == 1 and lines[0].startswith(
        "lowcostdex record-demos: interrupted (Ctrl-C); the 1 demonstration(s) this run "
        "finished (") and lines[0].endswith(
        f"0 playbacks) are in {out}; run the command again with --seed 1 to add more (it "
        "appends)"), err  # --seed 0 again would record episode 0 again (careless19)
    assert "Traceback" not in err
    with h5py.File(out) as f:
        assert int(f.attrs["total_episodes"]) == 1


def test_fewer_demos_than_n_demos_are_used_and_said(tmp_path, capsys):
    """--n-demos 5 with a file of 2 successful episodes trained on the 2 without a word."""
    pointmass_demos(tmp_path / "demos.h5")
    code = main(["train", "dapg", "--env", POINTMASS, "--out", str(tmp_path / "run"), *TINY,
                 "--bc-epochs", "1", "--demos", str(tmp_path / "demos.h5"), "--n-demos", "5"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert (f"lowcostdex train dapg: note: --n-demos 5, but {tmp_path / 'demos.h5'} holds 2 "
            "successful demonstration(s): all 2 are used") in err
