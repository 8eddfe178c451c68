"""Careless command lines, session 16 (issue 13). Each test fails on the code before it.

- ``lowcostdex main --out "$OUT"`` with OUT unset meant the current folder (``type=Path``
  made "" into "."), where every other command says the option is empty.
- ``model bench --station valve`` wrote a bench model without a word about the station.
- ``gap analyze --candidates ""`` considered every effect, as if the option were absent.
- ``gap generate --effect gain_error --effect gain_error`` hid the effect twice, compounded,
  and truth.json listed it twice.
- ``train npg --env Pendulum-v1`` (any gymnasium env without a ``backend`` keyword) died in
  gym.make with a TypeError traceback; ``--env CartPole-v1`` (discrete actions) with an
  AssertionError traceback from inside the first rollout, after the run folder was written.
- ``train npg --env DClawTurnValve-v0`` (no ``lowcostdex/``) listed the envs without naming the
  one meant; a motor typed ``XM430`` or in lower case the same.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from lowcostdex.cli import main

sys.path.insert(0, str(Path(__file__).parent))
from cli_check import run_cli  # noqa: E402

_run = run_cli


def test_main_with_an_empty_out_says_it_is_empty(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "thesis.tex").write_text("mine")
    code, err = _run(["main", "--out", "", "--size", "smoke"], capsys)
    assert code == 2
    assert err == "lowcostdex main: error: --out is empty (an unset shell variable?); give a path"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["thesis.tex"]


def test_a_station_for_the_bench_is_refused(tmp_path, capsys):
    out = tmp_path / "bench.xml"
    code, err = _run(["model", "bench", "--station", "valve", "--out", str(out)], capsys)
    assert code == 2
    assert err == ("lowcostdex model: error: --station valve: the bench has no station (one "
                   "servo and its arm); --station is for dclaw and allegro")
    assert not out.exists()


@pytest.mark.parametrize("value", ["", ",", " , "])
def test_empty_candidates_are_refused_before_the_logs_are_read(value, tmp_path, capsys):
    out = tmp_path / "report"
    code, err = _run(["gap", "analyze", "--log", str(tmp_path / "absent.csv"), "--model",
                      str(tmp_path / "absent.xml"), "--candidates", value, "--out", str(out)],
                     capsys)
    assert code == 2
    assert err == ("lowcostdex gap analyze: error: --candidates is empty; name the effects "
                   "(e.g. --candidates latency,backlash), or leave it out for every effect the "
                   "logs support")
    assert not out.exists()


def test_an_effect_hidden_twice_is_refused(tmp_path, capsys):
    out = tmp_path / "gen"
    code, err = _run(["gap", "generate", "--rig", "finger", "--effect", "gain_error",
                      "--effect", "gain_error", "--out", str(out)], capsys)
    assert code == 2
    assert err == ("lowcostdex gap generate: error: hidden effect 'gain_error' given twice; "
                   "each effect is hidden once (on every joint of the rig)")
    assert not out.exists()


def test_two_random_effects_still_generate(tmp_path, capsys):
    out = tmp_path / "gen"
    code, _ = _run(["gap", "generate", "--effect", "random", "--effect", "latency", "--logs",
                    "1", "--duration", "1", "--seed", "3", "--out", str(out)], capsys)
    assert code == 0
    assert len(json.loads((out / "truth.json").read_text())["hidden"]) == 2


def test_train_npg_on_a_plain_gymnasium_env(tmp_path, capsys):
    """Pendulum-v1 takes no ``backend`` keyword: the sim backend is every env's default."""
    out = tmp_path / "run"
    code, err = _run(["train", "npg", "--env", "Pendulum-v1", "--n-iter", "1", "--n-traj", "2",
                      "--eval-every", "0", "--no-progress", "--out", str(out)], capsys)
    assert code == 0, err
    assert (out / "config.json").exists()


@pytest.mark.parametrize("argv, message", [
    (["--env", "CartPole-v1"], "npg trains envs with continuous actions (a Box space); "
                               "CartPole-v1 has Discrete(2)"),
    (["--env", "Pendulum-v1", "--backend", "emulated"],
     "backend 'emulated' drives a lowcostdex robot; Pendulum-v1 is not a lowcostdex env "
     "(lowcostdex/...): train it with backend 'sim'"),
], ids=["discrete", "robot-backend"])
def test_train_npg_on_an_env_it_cannot_train_says_why(argv, message, tmp_path, capsys):
    out = tmp_path / "run"
    code, err = _run(["train", "npg", *argv, "--n-iter", "1", "--n-traj", "2", "--out",
                      str(out)], capsys)
    assert code == 2
    assert err == f"lowcostdex train npg: error: {message}"
    assert not out.exists()


@pytest.mark.parametrize("env, meant", [
    ("DClawTurnVlave-v0", "'lowcostdex/DClawTurnValve-v0'"),
    ("lowcostdex/DClawTurnVlave-v0", "'lowcostdex/DClawTurnValve-v0'"),
])
def test_a_mistyped_env_names_the_closest(env, meant, tmp_path, capsys):
    code, err = _run(["train", "npg", "--env", env, "--out", str(tmp_path / "run")], capsys)
    assert code == 2
    assert err.startswith(f"lowcostdex train npg: error: unknown env {env!r}; lowcostdex envs: ")
    assert f"; did you mean {meant}" in err


@pytest.mark.parametrize("motor, meant", [("xm430-w350", "'XM430-W350'"),
                                          ("XM430", "'XM430-W350' or 'XM430-W210'")])
def test_a_mistyped_motor_names_the_closest(motor, meant, tmp_path, capsys):
    code, err = _run(["model", "bench", "--motor", motor, "--out", str(tmp_path / "m.xml")],
                     capsys)
    assert code == 2
    assert err.endswith(f"; did you mean {meant}?")
    from lowcostdex.errors import ConfigError
    from lowcostdex.hands import dclaw_spec

    with pytest.raises(ConfigError) as exc:
        dclaw_spec(motor)
    assert str(exc.value).endswith(f"; did you mean {meant}?")


# ------------------------------------------------------------------------------------------------
# a folder with a space in its name: the commands a message offers paste as they are printed


def test_the_command_main_offers_is_quoted_for_a_folder_with_a_space(tmp_path, capsys):
    """Before: "run `lowcostdex main --out my run --stages demos,train`", which the shell
    reads as --out my and a stray argument."""
    out = tmp_path / "my run"
    code, err = _run(["main", "--out", str(out), "--stages", "train", "--size", "smoke"], capsys)
    assert code == 2
    assert f"run `lowcostdex main --out '{out}' --stages demos,train`" in err


def test_the_fresh_folder_offered_is_quoted(tmp_path, capsys):
    theirs = tmp_path / "my data"
    theirs.mkdir()
    (theirs / "paper.tex").write_text("mine")
    code, err = _run(["gap", "generate", "--out", str(theirs)], capsys)
    assert code == 2
    assert f"e.g. --out '{theirs}/generate-" in err
    assert (theirs / "paper.tex").read_text() == "mine"


def test_record_log_offers_a_gap_command_that_reads_its_folder(tmp_path, capfd):
    """Before: "--log my logs/*.csv", three words to the shell."""
    import shlex

    out = tmp_path / "my logs"
    code = main(["record-log", "--logs", "1", "--seconds", "0.5", "--out", str(out)])
    captured = capfd.readouterr()
    printed = " ".join((captured.out + captured.err).split())
    assert code == 0
    assert f"--log {shlex.quote(str(out))} --out DIR" in printed


# ------------------------------------------------------------------------------------------------
# the demos: an empty --out (an unset shell variable) was the current folder

DEMO_EMPTY = [
    ("npg_valve.py", ["--out", ""], "--out"),
    ("flip_keypoints_vs_quaternion.py", ["--out", ""], "--out"),
    ("dapg_kinesthetic_valve.py", ["--out", ""], "--out"),
    ("dapg_kinesthetic_valve.py", ["--demos", "", "--out", "run"], "--demos"),
    ("gap_own_mjcf.py", ["--out", ""], "--out"),
    ("tvlg_turn_valve.py", ["--out", ""], "--out"),
    ("tvlg_turn_valve.py", ["--demos", "", "--out", "run"], "--demos"),
]


@pytest.mark.parametrize("script, argv, option", DEMO_EMPTY,
                         ids=[f"{s.removesuffix('.py')}:{o}" for s, _, o in DEMO_EMPTY])
def test_a_demo_given_an_empty_path_writes_nothing_in_the_current_folder(
        script, argv, option, tmp_path, monkeypatch, capsys):
    """Before: ``npg_valve.py --out ""`` trained into the current folder, its checkpoints and
    config.json beside the user's own files; ``tvlg_turn_valve.py --demos ""`` recorded the
    default demonstration instead of the user's; ``dapg --demos ""`` said '--demos .: no
    such file'."""
    import runpy
    import sys
    from pathlib import Path

    demos = Path(__file__).resolve().parents[1] / "demos"
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("mine")
    monkeypatch.setattr(sys, "argv", [script, *argv])
    with pytest.raises(SystemExit) as exc:
        runpy.run_path(str(demos / script), run_name="__main__")
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert exc.value.code == 2
    assert err == (f"{script}: error: argument {option}: '' is an empty path (an unset shell "
                   "variable?); give a path")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_an_env_id_without_its_prefix_is_the_lowcostdex_one():
    """``train npg --env DClawTurnValve-v0`` was refused ("unknown env") where ``train tvlg``
    took it; one vocabulary now (a gymnasium id of its own, Pendulum-v1, stays itself)."""
    from lowcostdex.options import env_id

    assert env_id("DClawTurnValve-v0") == "lowcostdex/DClawTurnValve-v0"
    assert env_id("lowcostdex/DClawTurnValve-v0") == "lowcostdex/DClawTurnValve-v0"
    assert env_id("Pendulum-v1") == "Pendulum-v1"
    assert env_id("DClawTurnVlave-v0") == "DClawTurnVlave-v0"  # named by check_env_id


@pytest.mark.parametrize("option, value, message", [
    ("--algos", "", "--algos is empty; name at least one algo (dapg, npg), or leave it out for "
                    "the default"),
    ("--conditions", ",", "--conditions is empty; name at least one condition (nominal, "
                          "randomized, identified, identified_randomized, on_robot), or leave it "
                          "out for the default"),
])
def test_transfer_with_an_empty_list_names_the_option(option, value, message, tmp_path, capsys):
    """Before: "size: give at least one algo and one condition", no option named."""
    out = tmp_path / "t"
    code, err = _run(["transfer", "--out", str(out), option, value], capsys)
    assert code == 2
    assert err == f"lowcostdex transfer: error: {message}"
    assert not out.exists()
