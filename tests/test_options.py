"""One option vocabulary: --backend/--port/--env/--seed/--out/--n-iter mean the same in the demos
and the sub-commands, and impossible combinations are refused before anything runs."""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.options import add_robot_options, add_run_options, robot_selection

DEMOS = Path(__file__).resolve().parents[1] / "demos"


def test_robot_selection():
    assert robot_selection("sim", None) == ("sim", {})
    assert robot_selection("emulated", None) == ("emulated", {})
    assert robot_selection("hardware", "/dev/ttyUSB0") == ("hardware", {"port": "/dev/ttyUSB0"})
    with pytest.raises(ConfigError, match="needs --port"):
        robot_selection("hardware", None)
    with pytest.raises(ConfigError, match="leave it out"):
        robot_selection("sim", "/dev/ttyUSB0")
    with pytest.raises(ConfigError, match="valid choices: sim, emulated, hardware"):
        robot_selection("gazebo", None)


def test_iters_is_an_alias_of_n_iter():
    p = argparse.ArgumentParser()
    add_robot_options(p, env="lowcostdex/DClawTurnValve-v0")
    add_run_options(p, out="runs/x", n_iter=5, n_traj=3)
    a = p.parse_args(["--iters", "7", "--backend", "emulated"])
    assert (a.n_iter, a.n_traj, a.backend, a.port, a.env) == (7, 3, "emulated", None,
                                                             "lowcostdex/DClawTurnValve-v0")
    assert p.parse_args(["--n-iter", "9"]).n_iter == 9


@pytest.mark.parametrize("script", ["npg_valve.py", "dapg_kinesthetic_valve.py",
                                    "flip_keypoints_vs_quaternion.py", "tvlg_turn_valve.py"])
def test_every_training_demo_speaks_the_vocabulary(script):
    """Each demo's parser offers --backend with all three backends, --port, --seed and --out."""
    text = (DEMOS / script).read_text()
    tree = ast.parse(text)
    called = {n.func.id for n in ast.walk(tree)
              if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    literal = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)}
    shared = {"add_robot_options", "add_run_options"} <= called
    own = {"--backend", "--port", "--seed", "--out"} <= literal and "hardware" in literal
    assert shared or own, script


def test_robot_commands_take_backend_and_port():
    from lowcostdex.options import robot_port

    assert robot_port(None, None) == "emulated"
    assert robot_port(None, "emulated") == "emulated"          # the older spelling still works
    assert robot_port("emulated", None) == "emulated"
    assert robot_port(None, "/dev/ttyUSB0") == "/dev/ttyUSB0"  # a device implies hardware
    assert robot_port("hardware", "can0") == "can0"
    with pytest.raises(ConfigError, match="needs --port"):
        robot_port("hardware", None)
    with pytest.raises(ConfigError, match="needs no port"):
        robot_port("emulated", "/dev/ttyUSB0")


@pytest.mark.parametrize("command", ["record-log", "record-demos", "reset-test"])
def test_robot_commands_refuse_hardware_without_a_port(command, tmp_path, capsys):
    from lowcostdex.cli import main

    out = tmp_path / "out"
    args = [command, "--backend", "hardware"]
    if command != "reset-test":
        args += ["--out", str(out)]
    if command == "record-demos":
        args += ["--episodes", "1"]
    assert main(args) == 2
    assert "needs --port" in capsys.readouterr().err
    assert not out.exists()
