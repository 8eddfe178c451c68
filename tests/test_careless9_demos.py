"""Careless calls on the scripts in demos/ (issue 13): a user's mistake there is one line
``<script>: error: ...`` with exit code 2, as for the ``lowcostdex`` commands, never a traceback
from deep inside a config, numpy or the serial port, and nothing is left on disk.

Before session 15 every demo raised its ConfigError (``--n-iter 0``, an unknown ``--env``,
``--backend hardware`` without ``--port``), numpy's ValueError (``gap_own_mjcf.py --seed -1``), the
serial port's error or ``os.mkdir``'s as a traceback with exit code 1, and
``dapg_kinesthetic_valve.py`` asked ``record-demos`` to write into an ``--out`` folder it had not
made, so its documented first command failed in a fresh clone (no ``runs/`` yet).
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import pytest

DEMOS = Path(__file__).resolve().parents[1] / "demos"

# (script, arguments ({out} is a folder that must stay absent), a fragment of the one line)
CASES = [
    ("npg_valve.py", ["--n-iter", "0"], "argument --n-iter/--iters: '0' is not an integer >= 1"),
    ("npg_valve.py", ["--seed", "-1"], "argument --seed: '-1' is not an integer >= 0"),
    ("npg_valve.py", ["--n-traj", "-4"], "argument --n-traj: '-4' is not an integer >= 1"),
    ("npg_valve.py", ["--env", "DClawValve"], "unknown env 'DClawValve'; lowcostdex envs: "),
    ("npg_valve.py", ["--backend", "hardware"], "--backend hardware needs --port"),
    ("npg_valve.py", ["--port", "/dev/ttyUSB0"], "--port /dev/ttyUSB0 is for --backend hardware"),
    ("npg_valve.py", ["--backend", "hardware", "--port", "{tmp}/ttyNOPE"], "ttyNOPE"),
    ("flip_keypoints_vs_quaternion.py", ["--seed", "-3"], "argument --seed: '-3'"),
    ("flip_keypoints_vs_quaternion.py", ["--backend", "hardware"], "needs --port"),
    ("dapg_kinesthetic_valve.py", ["--n-traj", "0"], "argument --n-traj: '0' is not an integer"),
    ("dapg_kinesthetic_valve.py", ["--demos", "0"], "argument --demos: '0': record at least 1"),
    ("dapg_kinesthetic_valve.py", ["--demos", "{tmp}/mine.h5"],
     "mine.h5: no such file (give a demonstration file, or a number of demonstrations"),
    ("dapg_kinesthetic_valve.py", ["--backend", "hardware"], "needs --port"),
    ("dapg_kinesthetic_valve.py", ["--env", "Foo-v0"], "unknown env 'Foo-v0'"),
    ("tvlg_turn_valve.py", ["--noise", "nan"], "argument --noise: 'nan' is not a finite number > 0"),
    ("tvlg_turn_valve.py", ["--noise", "-0.1"], "argument --noise: '-0.1'"),
    ("tvlg_turn_valve.py", ["--n-iter", "0"], "argument --n-iter: '0' is not an integer >= 1"),
    ("tvlg_turn_valve.py", ["--seed", "-2"], "argument --seed: '-2' is not an integer >= 0"),
    ("tvlg_turn_valve.py", ["--backend", "hardware"], "--backend hardware needs --port"),
    ("tvlg_turn_valve.py", ["--demos", "{tmp}/none.h5"], "demonstration file"),
    ("gap_own_mjcf.py", ["--seed", "-1"], "argument --seed: '-1' is not an integer >= 0"),
    # --resume where no run is (a typo in --out): refused, as `lowcostdex train --resume` does;
    # the demos started a new run from scratch as if resumed
    ("npg_valve.py", ["--resume"], "--resume: {out} does not exist, so there is nothing to "
                                   "resume"),
    ("tvlg_turn_valve.py", ["--resume"], "--resume: {out} does not exist"),
]


def _run(script: str, argv: list[str], monkeypatch) -> int:
    monkeypatch.setattr(sys, "argv", [script, *argv])
    with pytest.raises(SystemExit) as exc:
        runpy.run_path(str(DEMOS / script), run_name="__main__")
    return exc.value.code


@pytest.mark.parametrize("script, args, message", CASES,
                         ids=[f"{s.removesuffix('.py')}:{' '.join(a)}" for s, a, _ in CASES])
def test_a_careless_demo_call_is_one_line_and_writes_nothing(script, args, message, tmp_path,
                                                             capsys, monkeypatch):
    out = tmp_path / "out"
    argv = [a.format(tmp=tmp_path) for a in args] + ["--out", str(out)]
    code = _run(script, argv, monkeypatch)
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"{script}: error: "), err
    assert message.format(tmp=tmp_path, out=out) in last, last
    assert not out.exists(), sorted(p.name for p in out.iterdir())


def test_debug_shows_the_traceback_of_a_demo_s_error(tmp_path, capsys, monkeypatch):
    code = _run("npg_valve.py", ["--backend", "hardware", "--debug", "--out", str(tmp_path / "o")],
                monkeypatch)
    err = capsys.readouterr().err
    assert code == 2
    assert "Traceback" in err and err.strip().splitlines()[-1].startswith("npg_valve.py: error:")


def test_a_gap_demo_out_that_is_a_file_is_refused_and_kept(tmp_path, capsys, monkeypatch):
    mine = tmp_path / "notes.txt"
    mine.write_text("mine")
    code = _run("gap_own_mjcf.py", ["--out", str(mine)], monkeypatch)
    assert code == 2
    assert "--out" in capsys.readouterr().err and mine.read_text() == "mine"


def test_the_dapg_demo_records_into_an_out_folder_it_makes(tmp_path, monkeypatch, capsys):
    """In a fresh clone ``runs/`` does not exist: the demo makes its --out folder before it asks
    record-demos to write the demonstrations there (record-demos refuses a missing folder)."""
    import lowcostdex.cli as cli

    asked = []

    def record_demos(argv):  # stands in for `lowcostdex record-demos`: no minutes of recording
        out = Path(argv[argv.index("--out") + 1])
        asked.append((argv[0], out.parent.is_dir(), argv[argv.index("--episodes") + 1]))
        return 3  # stop the script here

    monkeypatch.setattr(cli, "main", record_demos)
    out = tmp_path / "runs" / "dapg"
    code = _run("dapg_kinesthetic_valve.py", ["--demos", "4", "--out", str(out)], monkeypatch)
    assert code == 3
    assert asked == [("record-demos", True, "4")]


@pytest.mark.parametrize("script, how", [
    ("npg_valve.py", "the same command with --resume continues it"),
    ("dapg_kinesthetic_valve.py", "the same command continues it (it resumes the run in --out)"),
])
def test_ctrl_c_in_a_demo_says_what_is_kept_and_how_to_go_on(script, how, tmp_path, capsys,
                                                            monkeypatch):
    """Ctrl-C during training: one line with the run's checkpoint (the trainer's message) and
    how to continue, exit 130. Before: a KeyboardInterrupt traceback."""
    import lowcostdex.algos.train as train_module
    from lowcostdex.algos.experiment import Interrupted

    out = tmp_path / "out"
    ckpt = out / "checkpoints" / "ckpt_000003.pt"

    def ctrl_c(config, run_dir, *args, **kwargs):  # the trainer, stopped after iteration 3
        raise Interrupted(Path(run_dir), 3, ckpt)

    monkeypatch.setattr(train_module, "train", ctrl_c)
    argv = ["--out", str(out)]
    if script.startswith("dapg"):  # a demo file of the user's: no recording first
        demos = tmp_path / "mine.h5"
        demos.write_bytes(b"")
        argv += ["--demos", str(demos)]
    code = _run(script, argv, monkeypatch)
    err = capsys.readouterr().err
    assert code == 130 and "Traceback" not in err
    line = err.strip().splitlines()[-1]
    assert line.startswith(f"{script}: error: interrupted (Ctrl-C); training in ")
    assert f"interrupted; checkpoint after iteration 3: {ckpt}; {how}" in line
