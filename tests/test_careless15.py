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


@pytest.fixture
def home_and_cwd(tmp_path, monkeypatch):
    home, cwd = tmp_path / "home", tmp_path / "work dir"
    home.mkdir()
    cwd.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(cwd)
    return home, cwd


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

    from lowcostdex.algos.run_files import atomic_write_bytes, write_json

    atomic_write_bytes(tmp_path / "policy.pt", b"weights")
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
