"""Careless calls of the Python API and hardware settings (session 21, careless18).

Each case's truth is the user's own input written here (a misspelt joint, degrees for radians, a
count of zero); the code must refuse it with a message that says what to type.
"""

from __future__ import annotations

import json
import math

import pytest

from lowcostdex.errors import ConfigError, InputError
from lowcostdex.hands import HandSpec, dclaw_spec
from lowcostdex.hardware.dynamixel.driver import DynamixelBus
from lowcostdex.hardware.emulated.chain import emulated_dclaw
from lowcostdex.hardware.robot.calibration import calibrate_offsets
from lowcostdex.hardware.robot.robot import Robot


@pytest.fixture(scope="module")
def dclaw_bus():
    hand = dclaw_spec()
    chain = emulated_dclaw(hand=hand)
    with DynamixelBus.from_hand(hand, chain.port(), handle_signals=False,
                                position_limits=None) as bus:
        yield hand, bus


def test_calibration_reference_with_a_misspelt_joint_is_refused(dclaw_bus):
    # before: "ff_tpo" was ignored and ff_top calibrated as if held at 0 rad
    hand, bus = dclaw_bus
    with pytest.raises(ConfigError, match=r"no joint 'ff_tpo'.*did you mean 'ff_top'"):
        calibrate_offsets(bus, hand, reference={"ff_tpo": 0.3}, samples=1)


def test_calibration_reference_in_degrees_is_refused(dclaw_bus):
    # the user holds ff_middle at 30 deg and types 30: every later goal would be off by 29.5 rad
    hand, bus = dclaw_bus
    with pytest.raises(ConfigError, match=r"ff_middle.*outside.*in degrees\? 30 deg = 0\.5236"):
        calibrate_offsets(bus, hand, reference={"ff_middle": 30.0}, samples=1)
    assert math.radians(30.0) == pytest.approx(0.5236, abs=1e-4)


@pytest.mark.parametrize("samples", [0, -3, 2.5, True])
def test_calibration_samples_not_a_positive_count_is_refused(dclaw_bus, samples):
    # before: samples=0 crashed with an IndexError on an empty array
    hand, bus = dclaw_bus
    with pytest.raises(ConfigError, match=r"samples=.* must be an integer >= 1"):
        calibrate_offsets(bus, hand, samples=samples)


def test_calibration_valid_reference_still_calibrates(dclaw_bus):
    hand, bus = dclaw_bus
    new = calibrate_offsets(bus, hand, reference={"ff_middle": 0.5}, samples=2)
    assert new.joint_names == hand.joint_names


def _spec_dict():
    return json.loads(dclaw_spec().to_json())


def test_hand_spec_json_without_a_motor_id_names_the_joint_and_key(tmp_path):
    # before: "not a hand spec JSON (TypeError: JointSpec.__init__() missing 1 required
    # positional argument: 'motor_id')", naming neither the joint nor what to add
    d = _spec_dict()
    del d["joints"][1]["motor_id"]
    path = tmp_path / "hand.json"
    path.write_text(json.dumps(d))
    with pytest.raises(InputError, match=r"joint ff_middle: missing key 'motor_id'"):
        HandSpec.load(path)


def test_hand_spec_json_without_the_motor_model_says_so():
    d = _spec_dict()
    del d["motor"]
    with pytest.raises(ConfigError, match=r"missing key 'motor'"):
        HandSpec.from_json(json.dumps(d))


def test_robot_with_a_dict_config_says_what_to_type(dclaw_bus):
    # before: AttributeError: 'dict' object has no attribute 'control_period'
    hand, bus = dclaw_bus
    with pytest.raises(ConfigError, match=r"RobotConfig\(\*\*settings\)"):
        Robot(hand, bus, {"control_period": 0.1})


def test_robot_with_a_spec_path_says_how_to_load_it(dclaw_bus, tmp_path):
    hand, bus = dclaw_bus
    path = tmp_path / "hand.json"
    hand.save(path)
    with pytest.raises(ConfigError, match=r"HandSpec\.load\(path\)"):
        Robot(str(path), bus)


def test_transfer_resume_with_another_start_range_is_refused(tmp_path):
    # before: a folder trained from the task's own starts (start_range 0, left out of its
    # settings) resumed with --start-range 0.5 reused its policies as 'found done' and the marker
    # then claimed 0.5
    from lowcostdex.outdir import OutputRefused
    from lowcostdex.transfer.loop import open_out, size_with

    out = tmp_path / "run"
    size = size_with("smoke")
    assert open_out(out, size, "valve", 0, None) is False
    (out / "runs").mkdir()  # a piece of the first run
    with pytest.raises(OutputRefused, match=r"start_range=0\.0; this run has start_range=0\.5"):
        open_out(out, size, "valve", 0, None, start_range=0.5)
    assert open_out(out, size, "valve", 0, None) is True  # the same flags still resume


def test_transfer_resume_with_another_budget_names_the_setting_that_differs(tmp_path):
    # before: both whole budget dicts were printed; the user had to find valve_episodes in them
    from lowcostdex.outdir import OutputRefused
    from lowcostdex.transfer.loop import open_out, size_with

    out = tmp_path / "run"
    open_out(out, size_with("smoke", valve_episodes=2), "valve", 0, None)
    (out / "runs").mkdir()
    with pytest.raises(OutputRefused) as exc:
        open_out(out, size_with("smoke", valve_episodes=5), "valve", 0, None)
    msg = str(exc.value)
    assert "budget differing in valve_episodes=2 (this run: 5)" in msg, msg
    assert "n_iter" not in msg, msg  # the settings that agree are not listed


def test_transfer_latency_on_the_emulated_robots_is_refused(tmp_path, capsys):
    # before: --latency-ms 5 without --port was accepted and ignored (a smoke run started)
    from lowcostdex.cli import main

    code = main(["transfer", "--out", str(tmp_path / "t"), "--size", "smoke", "--latency-ms", "5"])
    err = capsys.readouterr().err
    assert code == 2 and "--latency-ms" in err and "--port DEVICE" in err, err
    assert not (tmp_path / "t").exists()


def test_port_emulated_with_backend_hardware_names_the_contradiction():
    # before: "--backend hardware needs --port" although the user gave --port emulated
    from lowcostdex.options import robot_port

    with pytest.raises(ConfigError, match=r"--port emulated is the emulated robot.*drop "
                                          r"--backend hardware"):
        robot_port("hardware", "emulated")


@pytest.mark.parametrize("motor,baud", [("XH430-W350", 19200), ("XH430-W350", 38400),
                                        ("XL330-M288", 921600)])
def test_a_baud_rate_the_servo_cannot_be_set_to_is_refused_before_connecting(motor, baud):
    # the ROBOTIS e-Manual's Baud Rate (8) table of the X series: 9600, 57600, 115200, 1M, 2M,
    # 3M, 4M, 4.5M bps. before: 19200 was accepted and every motor then reported "no reply"
    from lowcostdex.hardware.dynamixel.config import DynamixelConfig

    with pytest.raises(ConfigError, match=rf"baud rate {baud}: a {motor} cannot be set to it.*"
                                          r"9600, 57600, 115200, 1000000"):
        DynamixelConfig(ids=(1,), models=(motor,), baudrate=baud)
    for ok in (57600, 1_000_000, 4_000_000):  # e-Manual rates still accepted
        DynamixelConfig(ids=(1,), models=(motor,), baudrate=ok)


@pytest.mark.parametrize("kwargs,match", [
    ({"n": 2.5}, r"integer number of hidden robots >= 1, got n=2\.5"),
    ({"n": 1, "seed": None}, r"seed=None: the hidden robots' seed must be an integer >= 0"),
    ({"n": 1, "seed": "gen"}, r"a Generator cannot name them"),
])
def test_hidden_robots_with_a_non_integer_count_or_seed_say_so(kwargs, match):
    # before: TypeErrors ("'float' object cannot be interpreted as an integer", "unsupported
    # operand type(s) for +: 'numpy.random._generator.Generator' and 'int'")
    import numpy as np

    from lowcostdex.hardware.emulated.hidden_robots import hidden_robot, hidden_robots

    if kwargs.get("seed") == "gen":
        kwargs = {**kwargs, "seed": np.random.default_rng(0)}
    with pytest.raises(ConfigError, match=match):
        hidden_robots(**kwargs)
    with pytest.raises(ConfigError, match=r"seed must be an integer >= 0"):
        hidden_robot(None)


def test_transfer_run_takes_a_size_name_and_checks_it(tmp_path):
    # before: run(out, "smoke") -> AttributeError: 'str' object has no attribute 'robots'
    from lowcostdex.transfer.loop import run

    with pytest.raises(ConfigError, match=r"unknown size 'smok'.*did you mean 'smoke'"):
        run(tmp_path / "t", "smok")
    assert not (tmp_path / "t").exists()


def test_randomization_ranges_of_an_effect_left_out_of_effects_are_refused():
    # before: the latency range was accepted and never drawn (only backlash was randomized)
    from lowcostdex.sim.effects import DomainRandomization

    with pytest.raises(ConfigError, match=r"ranges for latency, which is not in effects "
                                          r"\('backlash',\): add it"):
        DomainRandomization(("backlash",), ("ff_top",), {"latency": {"delay": (0.01, 0.02)}})


def test_randomization_range_given_as_one_number_says_how_to_hold_it_fixed():
    # before: TypeError: cannot unpack non-iterable float object
    from lowcostdex.sim.effects import DomainRandomization

    with pytest.raises(ConfigError, match=r"latency\.delay: 0\.01 must be a \(low, high\) pair; "
                                          r"to hold it fixed give \(0\.01, 0\.01\)"):
        DomainRandomization(("latency",), ("ff_top",), {"latency": {"delay": 0.01}})


def test_robot_send_with_a_joint_named_twice_is_refused_before_anything_is_sent(dclaw_bus):
    # before: send([0.1, -0.1], joints=["ff_top", "ff_top"]) was accepted: two goals, one motor
    import numpy as np

    hand, bus = dclaw_bus
    robot = Robot(hand, bus)
    robot.connect()
    with pytest.raises(ConfigError, match=r"joint ff_top named twice"):
        robot.send(np.array([0.1, -0.1]), joints=["ff_top", "ff_top"])
    assert np.all(np.isnan(robot.last_sent))  # nothing went out


def test_robot_enable_takes_one_joint_name_as_send_does(dclaw_bus):
    # before: enable("ff_top") iterated the letters: "unknown joint 'f'"
    hand, bus = dclaw_bus
    robot = Robot(hand, bus)
    robot.connect()
    try:
        assert robot.enable("ff_top") == []
        assert robot.torque_enabled[robot.index("ff_top")].all()
    finally:
        robot.torque(False)


def test_hand_spec_save_and_load_read_a_leading_tilde_as_home(tmp_path, monkeypatch):
    # before: save("~/hand.json") -> FileNotFoundError (a folder named '~' was looked for)
    monkeypatch.setenv("HOME", str(tmp_path))
    dclaw_spec().save("~/hand.json")
    assert (tmp_path / "hand.json").exists()
    assert HandSpec.load("~/hand.json") == dclaw_spec()


def test_hand_spec_load_of_a_missing_file_or_a_folder_is_an_input_error(tmp_path):
    # before: a bare FileNotFoundError / IsADirectoryError from pathlib
    with pytest.raises(InputError, match=r"missing\.json: cannot read it"):
        HandSpec.load(tmp_path / "missing.json")
    with pytest.raises(InputError, match=r"cannot read it"):
        HandSpec.load(tmp_path)
    with pytest.raises(InputError, match=r"is a folder; give a file name"):
        dclaw_spec().save(tmp_path)


def test_reset_qpos_in_degrees_is_refused():
    # before: options={"qpos": [30.0] * 10} started every finger joint at 30 rad (ff_top's
    # range is +-0.48 rad in the model): the observation read 30
    import gymnasium as gym
    import numpy as np

    import lowcostdex  # noqa: F401  (registers the ids)

    env = gym.make("lowcostdex/DClawTurnValve-v0")
    try:
        with pytest.raises(ValueError, match=r"past their range: ff_top=30 .*degrees\?"):
            env.reset(seed=0, options={"qpos": [30.0] * 10})
        ok = np.radians([0, -60, 60, 0, -60, 60, 0, -60, 60, 90])  # the same pose in radians
        obs, _ = env.reset(seed=0, options={"qpos": ok})
        assert np.allclose(obs[:9], ok[:9], atol=1e-6)
    finally:
        env.close()


def test_write_report_with_swapped_arguments_says_so_and_writes_nothing(tmp_path):
    # before: AttributeError: 'NoneType' object has no attribute 'to_dict' (or, swapped, an
    # error about a GapResult path) from inside the staged output
    from lowcostdex.gap import write_report

    with pytest.raises(TypeError, match=r"takes the GapResult analyze\(\) returned.*not NoneType"):
        write_report(None, tmp_path / "report")
    with pytest.raises(TypeError, match=r"takes the GapResult.*not str"):
        write_report(str(tmp_path / "report"), tmp_path / "r2")
    assert list(tmp_path.iterdir()) == []


def test_an_emulated_dclaw_at_a_baud_rate_no_x_series_servo_offers_is_a_config_error():
    # careless18 found-not-fixed: the emulated chain raised a bare ValueError where the driver
    # raises ConfigError. The X-series Baud Rate register (address 8) offers 9600, 57600, 115200,
    # 1M, 2M, 3M, 4M and 4.5M bit/s (ROBOTIS e-Manual, XM430-W350 control table).
    from lowcostdex.errors import ConfigError
    from lowcostdex.hardware.emulated.chain import emulated_dclaw

    with pytest.raises(ConfigError, match=r"12345.*9600, 57600, 115200, 1000000"):
        emulated_dclaw(baudrate=12345)
