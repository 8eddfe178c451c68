"""Careless calls, session 27 (issues 13, 11): each test failed on the code before its fix. The
physics a test needs is written out here in plain MuJoCo; a command is run as a user types it."""

from __future__ import annotations

import pytest

from lowcostdex.cli import USER_ERROR, main


@pytest.mark.parametrize("extra,named", [(["--bc-epochs", "50"], "--bc-epochs"),
                                         (["--bc-log-std", "keep"], "--bc-log-std")])
def test_npg_refuses_clone_settings_without_a_clone(tmp_path, capsys, extra, named):
    # before: npg without --demos --bc-init made no clone and dropped the option unsaid
    out = tmp_path / "run"
    code = main(["train", "npg", "--out", str(out), "--n-iter", "1", "--no-progress", *extra])
    err = capsys.readouterr().err
    assert code == USER_ERROR, err
    assert f"{named}: settings of the behaviour clone, which npg makes only with --demos PATH " \
           "--bc-init" in err
    assert "Traceback" not in err and not out.exists()

