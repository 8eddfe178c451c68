"""The careless-call tests' one way to call the CLI in-process: exit code and stderr, no traceback."""
from __future__ import annotations

from lowcostdex.cli import main


def run_cli(argv, capsys) -> tuple[int, str]:
    """Run ``lowcostdex argv`` in this process; return (exit code, stripped stderr).

    Fails the calling test when stderr holds a Python traceback: a careless call must get a
    message, never a crash.
    """
    code = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err.strip()
