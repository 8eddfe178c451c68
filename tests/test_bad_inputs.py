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
    assert case.message in err, err
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
