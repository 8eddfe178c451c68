"""Careless command lines (issue 13 item 6, one option vocabulary), session 15."""

from __future__ import annotations

import gymnasium as gym
import pytest

import lowcostdex  # noqa: F401  (registers the ids)
from lowcostdex.cli import main
from lowcostdex.errors import ConfigError


@pytest.mark.parametrize("backend", ["emulated", "hardware"])
def test_train_ppo_on_a_robot_backend_says_which_trainers_take_it(backend, tmp_path, capsys):
    """`train npg|dapg|tvlg` take --backend; `train ppo` said 'unrecognized arguments'."""
    out = tmp_path / "run"
    code = main(["train", "ppo", "--backend", backend, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    assert err.strip() == (f"lowcostdex train ppo: error: train ppo runs on the batched simulator "
                           f"only (--backend sim); on the {backend} robot train npg or dapg "
                           f"(`lowcostdex train npg --backend {backend} ...`)")
    assert not out.exists()


def test_train_ppo_takes_backend_sim(tmp_path, capsys):
    # the option is taken; the run stops at the next check (--n-iter 0), before any work
    code = main(["train", "ppo", "--backend", "sim", "--n-iter", "0", "--out", str(tmp_path / "r")])
    assert code == 2
    assert "n_iter=0 must be an integer" in capsys.readouterr().err


def test_gym_make_hardware_with_the_port_emulated_names_the_emulated_backend():
    """The CLI's `--port emulated` given to gym.make's hardware backend tried to open a serial
    port named 'emulated'."""
    with pytest.raises(ConfigError, match="port='emulated' names no serial port: for the "
                                          "emulated D'Claw use backend='emulated'"):
        gym.make("lowcostdex/DClawTurnValve-v0", backend="hardware", port="emulated")


def test_a_gap_report_s_effects_json_is_taken_by_the_effects_options(tmp_path, capsys):
    """README: the extended model's effects.json is what the emulator loads. `emulate --effects`
    and `record-log --effects` refused it ('must hold a JSON list of effects, got dict'): they
    read a bare list only. The file here is written by the gap analysis's own writer."""
    from lowcostdex.gap.extension import save_extended
    from lowcostdex.sim.effects import AppliedEffect
    from lowcostdex.sim.effects.randomization import read_effects
    from lowcostdex.sim.models.dclaw import build_dclaw

    named = [AppliedEffect.from_dict({"effect": "latency", "joints": ["ff_top", "ff_middle"],
                                      "params": {"delay": [0.01, 0.02]}}),
             AppliedEffect.from_dict({"effect": "coulomb_friction", "joints": ["ff_top"],
                                      "params": {"frictionloss": [0.05]}})]
    folder = save_extended(tmp_path / "report" / "extended",
                           {"model": build_dclaw("none").to_xml()}, named)
    path = folder / "effects.json"
    assert [e.to_dict() for e in read_effects(str(path))] == [e.to_dict() for e in named]
    out = tmp_path / "logs"
    code = main(["record-log", "--effects", str(path), "--logs", "1", "--seconds", "0.5",
                 "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    assert (out / "log_0.csv").is_file()
    # and gym.make's effects= takes the file's path (was "must be a list of effects")
    env = gym.make("lowcostdex/DClawTurnValve-v0", backend="emulated", effects=str(path))
    try:
        assert [e.to_dict() for e in env.unwrapped.backend.effects] == [e.to_dict() for e in named]
    finally:
        env.close()


def test_gym_make_a_dclaw_on_hardware_with_a_can_channel_names_the_port():
    """The Allegro's keyword on a D'Claw said 'needs the task and port=...'."""
    with pytest.raises(ConfigError, match="channel='can0' is the Allegro's CAN channel; a "
                                          "D'Claw is on a serial port"):
        gym.make("lowcostdex/DClawTurnValve-v0", backend="hardware", channel="can0")
