"""Issue 12, a careless new user's fourth pass (session 8): commands nobody had tried that way.

Each test was written against the code before its fix and failed there (the commit message says
how); the expected messages are typed out here, not built from the code under test.
"""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import pytest

from lowcostdex.cli import main
from lowcostdex.errors import INTERRUPTED


def _lines(err: str, word: str) -> list[str]:
    return [ln for ln in err.splitlines() if word in ln]


def test_ctrl_c_in_a_main_stage_says_what_is_kept_and_the_command_that_continues(
        tmp_path, capsys, monkeypatch):
    """Ctrl-C in the main job's demos stage printed only "interrupted (Ctrl-C)": nothing on the
    finished bus stage in results.json, nor on how to go on (running the same command again
    redoes every stage). Now: exit 130, one line naming the stage, what results.json holds and
    the command; that command runs the missing stage on the kept bus stage."""
    from lowcostdex.main_job import job

    def demos_cut(ctx):
        """Record kinesthetic demonstrations (cut short by Ctrl-C here)."""
        (ctx.out / "demos.h5").write_bytes(b"half a file")
        raise KeyboardInterrupt

    stages = dict(job.STAGES)
    monkeypatch.setattr(job, "STAGES", (("bus", stages["bus"]), ("demos", demos_cut)))
    out = tmp_path / "my run"  # a space: the command must quote it
    assert main(["main", "--size", "smoke", "--out", str(out), "--seed", "3"]) == INTERRUPTED
    err = capsys.readouterr().err
    assert "Traceback" not in err
    command = (f"lowcostdex main --out '{out}' --size smoke --seed 3 --task valve-target "
               "--stages demos")
    assert _lines(err, "interrupted") == [
        f"lowcostdex main: error: interrupted (Ctrl-C); stage demos did not finish (its partial "
        f"outputs go to previous/ when it runs again); {out / 'results.json'} holds the finished "
        f"stages (bus). Continue with: {command}"], err
    assert set(json.loads((out / "results.json").read_text())) == {"bus"}
    # the printed command, run as printed: the bus stage is reused, demos runs, the half file
    # is kept in previous/
    recorded = {}

    def demos_done(ctx):
        """Record kinesthetic demonstrations."""
        recorded["hand"] = (ctx.out / "hand.json").is_file()
        (ctx.out / "demos.h5").write_bytes(b"whole")
        return {"n_demos": 4, "successes": 4, "episodes": 4}

    monkeypatch.setattr(job, "STAGES", (("bus", stages["bus"]), ("demos", demos_done)))
    monkeypatch.setattr(job, "stage_summary", lambda name, result: name)
    monkeypatch.setattr(job, "markdown_report", lambda ctx: "report")
    monkeypatch.setattr(job, "write_html", lambda text, path: None)
    assert main(shlex.split(command)[1:]) == 0
    assert recorded == {"hand": True}
    assert set(json.loads((out / "results.json").read_text())) == {"bus", "demos"}
    assert [p.read_bytes() for p in out.glob("previous/*/demos.h5")] == [b"half a file"]


def test_ctrl_c_in_transfer_says_the_same_command_resumes(tmp_path, capsys, monkeypatch):
    """``transfer --help`` says a run cut short resumes in the same --out, but Ctrl-C printed
    only "interrupted (Ctrl-C)". Now the line says the pieces are kept and gives the command
    (the options the user set, --out absolute)."""
    from lowcostdex.transfer import loop

    def cut(out, *args, **kwargs):
        Path(out).mkdir()
        (Path(out) / "identify").mkdir()
        raise KeyboardInterrupt

    monkeypatch.setattr(loop, "run", cut)
    monkeypatch.chdir(tmp_path)
    assert main(["transfer", "--out", "tr", "--size", "smoke", "--seeds", "2"]) == INTERRUPTED
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert _lines(err, "interrupted") == [
        "lowcostdex transfer: error: interrupted (Ctrl-C); the finished pieces are kept in tr "
        "(the table is written when every piece is done); the same command resumes there: "
        f"lowcostdex transfer --out {tmp_path / 'tr'} --size smoke --seeds 2"], err


def test_analyze_a_folder_that_gap_generate_wrote(tmp_path, capsys):
    """`gap generate --out gen` writes its logs, model.xml and truth.json; `gap analyze --log
    gen` (a folder means every log in it) took truth.json for a BAM log and refused: "mixing
    BAM JSON logs and project logs in one analysis is not supported". Now the JSON beside the
    CSV logs is left out with a note, and the three logs are analysed."""
    gen = tmp_path / "gen"
    assert main(["gap", "generate", "--out", str(gen), "--logs", "3", "--duration", "3"]) == 0
    assert sorted(p.name for p in gen.iterdir() if not p.name.startswith(".")) == [
        "log00.csv", "log01.csv", "log02.csv", "model.xml", "truth.json"]
    capsys.readouterr()
    assert main(["gap", "analyze", "--model", str(gen / "model.xml"), "--log", str(gen),
                 "--out", str(tmp_path / "rep"), "--threads", "1", "--max-effects", "1",
                 "--candidates", "latency"]) == 0
    err = capsys.readouterr().err
    assert _lines(err, "note") == [
        f"lowcostdex gap analyze: note: {gen}: left out truth.json (JSON beside project-format "
        "CSV/NPZ logs: not a log of them)"], err
    report = json.loads((tmp_path / "rep" / "report.json").read_text())
    assert "log02.csv" in json.dumps(report) and "truth.json" not in json.dumps(report)


PORT_IS_A_FILE = ("--port notes.txt: cannot open it as a serial port: it is a regular file, not "
                  "a device (`lowcostdex scan` lists the serial ports)")


@pytest.mark.parametrize("argv, expected", [
    (["setup-motors", "--port", "notes.txt"], PORT_IS_A_FILE),
    (["main", "--port", "notes.txt", "--out", "run"], PORT_IS_A_FILE),
    (["record-log", "--port", "notes.txt", "--out", "logs"], PORT_IS_A_FILE),
    (["transfer", "--port", "notes.txt", "--out", "table", "--size", "smoke", "--yes"],
     PORT_IS_A_FILE),
    (["main", "--port", "thesis", "--out", "run"], "--port thesis is a folder, not a serial "
     "device"),
])
def test_a_port_given_as_a_relative_path_to_a_file_is_refused_before_anything(
        tmp_path, capsys, monkeypatch, argv, expected):
    """A relative --port (a file or folder in the working directory) passed the port check,
    which looked at absolute paths only: `main` and `record-log` wrote their output folders,
    `transfer` wrote demos and an identification, and `setup-motors` asked the user to connect
    the first motor, before opening the port failed. Now: exit 2, one line, nothing written,
    nothing asked."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("notes\n")
    (tmp_path / "thesis").mkdir()
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"lowcostdex {argv[0]}: error: {expected}"]
    assert captured.out == ""  # no prompt, no progress
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_users_mjcf_without_actuators(tmp_path, capsys):
    """A user's MJCF with the logged joint but no <actuator> (a model exported for viewing):
    the refusal ended in "actuators: " and nothing after it. Now it says the model has none and
    what to add; exit 2, no report folder."""
    gen = tmp_path / "gen"
    assert main(["gap", "generate", "--out", str(gen), "--logs", "3", "--duration", "3"]) == 0
    model = tmp_path / "arm.xml"
    model.write_text('<mujoco><worldbody><body name="link"><joint name="arm" type="hinge" '
                     'axis="0 1 0"/><geom type="capsule" size="0.01 0.05" mass="0.1"/></body>'
                     '</worldbody></mujoco>')
    capsys.readouterr()
    assert main(["gap", "analyze", "--model", str(model), "--log", str(gen / "log00.csv"),
                 "--out", str(tmp_path / "rep")]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [
        "lowcostdex gap analyze: error: log00.csv: 'goal:arm': the model has no actuators; the "
        "logged goals need one per joint, e.g. <actuator><position name=\"arm\" joint=\"arm\" "
        "kp=\"...\"/></actuator> (the servo's position gain)"], err
    assert not (tmp_path / "rep").exists()
