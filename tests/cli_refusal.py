"""One check for a command line the CLI must refuse: exit code 2, one error line naming the
problem, no traceback, and the user's folder exactly as it was (nothing written where it
refuses). Shared by the careless-input tests of `gap analyze` on users' rigs."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from lowcostdex.cli import main


def assert_refused(args: Sequence[str], folder: Path, capsys, words: Sequence[str],
                   prog: str = "lowcostdex gap analyze") -> None:
    """Run ``lowcostdex args`` and check the refusal; ``words`` must all be in its one line."""
    before = sorted(p.name for p in folder.rglob("*"))
    code = main(list(args))
    out, err = capsys.readouterr()
    assert code == 2, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), err
    for w in words:
        assert w in lines[0], (w, lines[0])
    assert "Traceback" not in out + err
    assert sorted(p.name for p in folder.rglob("*")) == before
