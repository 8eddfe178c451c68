"""Careless calls and bad inputs, session 22 (careless19): each test's truth is the user's own
input written here (the command line typed, a file saved by the user); the code must refuse it
saying what to type, or say what it is about to do."""

from __future__ import annotations

import pytest

from lowcostdex.cli import main

# ------------------------------------------------------------------------------------------------
# comma-separated names with an empty item or a repeat (careless18 found-not-fixed)


@pytest.mark.parametrize("argv,said", [
    # before: ran dapg and npg without a word about the missing name
    (["transfer", "--algos", "dapg,,npg"],
     "--algos 'dapg,,npg' has an empty name (two commas together: a name left out?); type "
     "--algos dapg,npg"),
    # before: ('dapg', 'dapg') went into the size as typed
    (["transfer", "--algos", "dapg,dapg"],
     "--algos 'dapg,dapg' names dapg more than once; name each once; type --algos dapg"),
    (["transfer", "--conditions", ",nominal"], "--conditions ',nominal' has an empty name"),
    # before: 'ff,,mf' handed build_dclaw an empty finger name
    (["model", "dclaw", "--fingers", "ff,,mf"], "--fingers 'ff,,mf' has an empty name"),
    (["model", "dclaw", "--fingers", "ff,ff"], "--fingers 'ff,ff' names ff more than"),
    (["main", "--stages", "bus,bus"], "--stages 'bus,bus' names bus more than once"),
])
def test_a_list_option_with_an_empty_name_or_a_repeat_is_refused_before_anything_runs(
        argv, said, tmp_path, capsys):
    out = tmp_path / ("m.xml" if argv[0] == "model" else "out")
    assert main([*argv, "--out", str(out)]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert said in err
    assert not out.exists()  # nothing written


def test_a_trailing_comma_is_still_read_as_the_names_before_it():
    from lowcostdex.argtypes import names

    assert names("latency, backlash,", "--candidates") == ("latency", "backlash")
    assert names(",", "--algos") == ()  # the caller says "empty" in its own words


# ------------------------------------------------------------------------------------------------
# a bare `reset-test` says what it runs before the first trial (careless17 found-not-fixed)


def test_a_bare_reset_test_says_what_it_runs_before_the_first_trial(monkeypatch, capsys):
    """Before: the first output was the progress bar of 20 trials; nothing said they run on the
    emulated hand, nor how to run them on the user's D'Claw. The trials are stopped here as
    Ctrl-C would stop them."""
    import lowcostdex.hardware.robot.reset_trials as trials

    def ctrl_c(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(trials, "reset_trials", ctrl_c)
    assert main(["reset-test"]) == 130
    err = " ".join(capsys.readouterr().err.split())
    assert ("lowcostdex reset-test: 20 trials of the lowcostdex reset (tangle the fingers, then "
            "reset) on the emulated D'Claw (virtual time, the default servo effects), seed 0; "
            "--trials N, --backend hardware --port DEVICE for your D'Claw") in err
