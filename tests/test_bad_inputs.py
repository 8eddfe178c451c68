"""Bad-input corpus (issue 12): every command on malformed input gives one clear line, exit code 2,
no traceback, and leaves the user's files byte for byte as they were (nothing new written where it
refuses).

``CASES`` is the table: the files a user has (written here as text, with real-world magnitudes and
the odd units real labs produce), the command line, and what must come out. The checks are the
same for every row (``test_bad_input_is_refused_cleanly``).
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass, field

import pytest

from lowcostdex.cli import main

# ------------------------------------------------------------------------------------------------
# the table


@dataclass(frozen=True)
class Case:
    """One bad input. ``argv`` and file contents may use ``{tmp}`` (the user's folder)."""

    id: str
    argv: tuple[str, ...]
    message: str  # a substring of the one-line error
    files: dict[str, str | bytes] = field(default_factory=dict)
    code: int = 2


CASES: list[Case] = [
    Case("unknown option", ("gap", "analyze", "--log", "a.csv", "--out", "{tmp}/o", "--frobnicate"),
         "unrecognized arguments: --frobnicate"),
    Case("number that is not one", ("gap", "analyze", "--log", "a.csv", "--out", "{tmp}/o",
                                    "--max-effects", "three"), "--max-effects: invalid int value"),
    Case("reset-test with 0 trials", ("reset-test", "--trials", "0"), "--trials must be >= 1"),
    # hardware: ports and values
    Case("scan on a missing port", ("scan", "--port", "/dev/does-not-exist"),
         "--port /dev/does-not-exist: no such device"),
    Case("scan on a file that is not a serial port", ("scan", "--port", "{tmp}/notes.txt"),
         "cannot open it as a serial port", files={"notes.txt": "my notes\n"}),
    Case("scan with ids that are not ids", ("scan", "--port", "emulated", "--ids", "10-1x"),
         "'10-1x' is not an id"),
    Case("scan with an id beyond 252", ("scan", "--port", "emulated", "--ids", "250-254"),
         "ids are 0-252, got 253"),
    Case("scan at a negative bit rate", ("scan", "--port", "emulated", "--baud", "-57600"),
         "--baud -57600: the bit rate must be positive"),
    Case("calibrate on a missing port", ("calibrate", "--port", "/dev/ttyUSB7", "--out",
                                         "{tmp}/dclaw.json", "--yes"),
         "--port /dev/ttyUSB7: no such device"),
    Case("calibrate with 0 samples", ("calibrate", "--port", "emulated", "--out", "{tmp}/c.json",
                                      "--yes", "--samples", "0"), "--samples 0"),
    Case("calibrate over a user's file", ("calibrate", "--port", "emulated", "--hand", "bench",
                                          "--out", "{tmp}/notes.json", "--yes"),
         "is not a hand spec; it is left untouched", files={"notes.json": '{"todo": [1, 2]}'}),
    Case("calibrate into a missing folder", ("calibrate", "--port", "emulated", "--out",
                                             "{tmp}/no/such/dir/c.json", "--yes"),
         "give a JSON file path in an existing folder"),
    Case("calibrate from a spec that is a CSV", ("calibrate", "--port", "emulated", "--spec",
                                                 "{tmp}/log.csv", "--out", "{tmp}/c.json", "--yes"),
         "--spec {tmp}/log.csv: not a hand spec JSON", files={"log.csv": "time,qpos:arm\n0,1\n"}),
    Case("calibrate from a missing spec", ("calibrate", "--port", "emulated", "--spec",
                                           "{tmp}/dclaw_calibrated.json", "--out", "{tmp}/c.json",
                                           "--yes"), "No such file or directory"),
    Case("record-log on a missing port", ("record-log", "--port", "/dev/ttyACM3", "--out",
                                          "{tmp}/logs"), "--port /dev/ttyACM3: no such device"),
    Case("emulate with a drop probability of 1.5", ("emulate", "bench", "--drop", "1.5"),
         "drop=1.5 not in [0, 1]"),
]


# ------------------------------------------------------------------------------------------------
# the checks


def _snapshot(root):
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


def _materialize(case: Case, tmp) -> list[str]:
    for name, content in case.files.items():
        path = tmp / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content.replace("{tmp}", str(tmp)))
    return [a.replace("{tmp}", str(tmp)) for a in case.argv]


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input_is_refused_cleanly(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = _materialize(case, tmp_path)
    before = _snapshot(tmp_path)
    code = main(argv)
    out, err = capsys.readouterr()
    assert code == case.code, err
    assert case.message.replace("{tmp}", str(tmp_path)) in err, err
    assert "Traceback" not in err + out
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err  # one line (progress bars are transient and go to stderr too)
    assert ": error: " in lines[0]
    assert _snapshot(tmp_path) == before  # the user's files as they were, nothing new


# ------------------------------------------------------------------------------------------------
# the error path itself


def test_a_bug_keeps_its_traceback(monkeypatch):
    import lowcostdex.hardware.cli as hw

    def bug(args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(hw, "_scan", bug)
    with pytest.raises(ZeroDivisionError):
        main(["scan", "--port", "emulated"])


def test_ctrl_c_is_one_line_and_exit_130(monkeypatch, capsys):
    import lowcostdex.hardware.cli as hw

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(hw, "_scan", interrupted)
    assert main(["scan", "--port", "emulated"]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "lowcostdex scan: error: interrupted (Ctrl-C)"


def test_help_is_not_an_error(capsys):
    assert main(["gap", "analyze", "--help"]) == 0
    assert "--debug" in capsys.readouterr().out


def _run(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lowcostdex.cli", *argv], capture_output=True,
                          text=True, timeout=120)


def test_scan_on_a_missing_port_is_one_line_for_a_user():
    """Issue 12: this was a 35-line pyserial traceback."""
    run = _run("scan", "--port", "/dev/does-not-exist")
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr.count("\n") == 1 and "Traceback" not in run.stderr
    assert "plug in the USB adapter" in run.stderr and "--port emulated" in run.stderr


def test_debug_shows_the_traceback_of_a_user_error():
    """As a user runs it (a process): one line without --debug; the traceback with it, before or
    after the subcommand."""
    plain = _run("reset-test", "--trials", "0")
    assert plain.returncode == 2 and "Traceback" not in plain.stderr
    assert plain.stderr.strip() == "lowcostdex reset-test: error: --trials must be >= 1"
    for argv in (("--debug", "reset-test", "--trials", "0"),
                 ("reset-test", "--trials", "0", "--debug")):
        debug = _run(*argv)
        assert debug.returncode == 2
        assert "Traceback" in debug.stderr and "ConfigError: --trials must be >= 1" in debug.stderr
