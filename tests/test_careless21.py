"""Careless calls, session 24 (issues 13, 11): each test failed on the code before its fix.
Expected bounds are ROBEL's D'Claw joint ranges, written out here (its MJCF: top -0.5..1.35,
middle and bottom -2.0..2.0 rad), and a log's motion written out by hand."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.gap.logs import read_log
from lowcostdex.gap.trajectory import LogError
from lowcostdex.hands import Calibration, HandSpec, dclaw_spec
from lowcostdex.sim.effects import AppliedEffect

HAND = dclaw_spec()


def with_joint(hand: HandSpec, name: str, **changes) -> HandSpec:
    return dataclasses.replace(hand, joints=tuple(
        dataclasses.replace(j, **changes) if j.name == name else j for j in hand.joints))


@pytest.mark.parametrize("joint,low,high,stop", [
    ("ff_middle", -2.5, 2.5, r"\[-2.0, 2.0\]"),   # fits the motor's turn (pi -+ 2.5), not the finger
    ("mf_top", -0.48, 1.5, r"\[-0.5, 1.35\]"),      # motor angles [1.09, 3.07]: inside the turn
    ("th_bottom", -2.2, 1.0, r"\[-2.0, 2.0\]"),
])
def test_a_dclaw_spec_with_limits_past_the_fingers_stops_is_refused_where_it_is_built(
        joint, low, high, stop):
    # a Robot is built from a spec and a bus, with no model: before, only a backend given the
    # model checked the stops, so Robot(spec, bus) drove the finger into them
    with pytest.raises(ConfigError, match=rf"joint {joint}: limits \[{low}, {high}\] rad leave "
                                          rf"the D'Claw's joint range {stop}.*type limits"):
        with_joint(HAND, joint, low=low, high=high)


def test_a_dclaw_spec_inside_the_stops_still_passes():
    with_joint(HAND, "ff_middle", low=-2.0, high=2.0)
    with_joint(HAND, "mf_top", low=-0.5, high=1.35)


def _sine_log(path, amplitude, hz=1.0, rate=100.0, seconds=4.0):
    """One joint, no velocities: a goal sine and the reading 30 ms behind it."""
    rows = ["time,goal:j,qpos:j"]
    for i in range(int(rate * seconds)):
        t = i / rate
        rows.append(f"{t:.4f},{amplitude * math.sin(2 * math.pi * hz * t):.6f},"
                    f"{amplitude * math.sin(2 * math.pi * hz * (t - 0.03)):.6f}")
    path.write_text("\n".join(rows) + "\n")
    return path


def test_a_smooth_degrees_log_without_velocities_is_refused_by_its_speed(tmp_path):
    # 12 deg at 1 Hz: values inside 4 pi (12.6) and no encoder grid, so before only the 100
    # rad/s limit stood; its peak speed 2 pi * 12 = 75.4 "rad/s" (deg/s) is past any servo's
    # 50 rad/s (the motor table's fastest, XL330-M077, 40.1 rad/s unloaded): a silent x57
    with pytest.raises(LogError, match=r"'qpos:j' moves at up to 7[45]\.\d+ rad/s .*below 50 "
                                       r"rad/s.*degrees.*numpy.radians"):
        read_log(_sine_log(tmp_path / "deg.csv", 12.0))
    log = read_log(_sine_log(tmp_path / "rad.csv", math.radians(12.0)))  # the same in rad
    assert np.ptp(log.qpos) == pytest.approx(2 * math.radians(12.0), rel=1e-3)


def test_a_hand_spec_built_from_numpy_numbers_saves_and_loads(tmp_path):
    # an offset from np.mean of readings, ids and limits from arrays: every check passed them,
    # then save() failed in json ("Object of type float32 is not JSON serializable")
    hand = with_joint(HAND, "ff_top", motor_id=np.int64(10), low=np.float32(-0.25),
                      high=np.float64(0.25), max_velocity=np.float32(2.0),
                      calibration=Calibration(offset=np.mean(np.array([-1.5, -1.6])),
                                              sign=np.int64(1), scale=np.float32(1.0)))
    hand.save(tmp_path / "hand.json")
    back = HandSpec.load(tmp_path / "hand.json")
    j = back.joint("ff_top")
    assert (j.motor_id, j.low, j.high, j.max_velocity) == (10, float(np.float32(-0.25)), 0.25, 2.0)
    assert (j.calibration.offset, j.calibration.sign, j.calibration.scale) == (-1.55, 1, 1.0)
    assert back == hand


def test_an_effect_on_one_joint_typed_as_a_string_is_that_joint():
    # before: AppliedEffect("latency", "elbow") acted on five joints 'e', 'l', 'b', 'o', 'w'
    one = AppliedEffect("latency", "elbow", {"delay": 0.02})
    assert one.joints == ("elbow",) and one.values["delay"].shape == (1,)
    assert one == AppliedEffect("latency", ["elbow"], {"delay": [0.02]})
    with pytest.raises(ConfigError, match=r"joints must be joint names, got 3 .*joints=\('elbow',\)"):
        AppliedEffect("latency", ("elbow", 3))


@pytest.mark.parametrize("env,setting", [("lowcostdex/DClawTurnValve-v0", "success_tol"),
                                         ("lowcostdex/AllegroTurnValve-v0", "success_tol")])
def test_a_success_tolerance_of_zero_is_refused(env, setting):
    # success is |error| < tolerance: at 0 no episode ever succeeds, and training reported 0 %
    import gymnasium as gym

    import lowcostdex  # noqa: F401 (registers the ids)

    with pytest.raises(ConfigError, match=rf"{setting}=0 must be a finite number in \(0, 3.14159\]"):
        gym.make(env, **{setting: 0})
    with pytest.raises(ConfigError, match=rf"{setting}=0.0 must be .*\(0, "):
        gym.make(env, **{setting: 0.0})


def test_the_screw_and_flip_tasks_refuse_a_zero_success_tolerance_too():
    from lowcostdex.sim.envs.dclaw_tasks import FlipConfig, ScrewConfig

    with pytest.raises(ConfigError, match=r"ScrewConfig.success_tol=0 must be .*\(0, "):
        ScrewConfig(success_tol=0)
    with pytest.raises(ConfigError, match=r"FlipConfig.success_angle=0 must be .*\(0, "):
        FlipConfig(success_angle=0)
    ScrewConfig(success_tol=0.05)


def test_gap_servo_periods_typed_carelessly_are_named_or_taken():
    from lowcostdex.gap import GapConfig

    # before: "servo_periods must be in (0, 0.1] s, got 0.001" for the string '0.001' (0.001
    # is in it), a float32 period refused with the same words, one number a bare TypeError
    assert GapConfig(servo_periods=(np.float32(0.002),)).servo_periods == (np.float32(0.002),)
    with pytest.raises(ConfigError, match=r"servo_periods='0.001' must be a tuple .*e.g. \(0.001,\)"):
        GapConfig(servo_periods="0.001")
    with pytest.raises(ConfigError, match=r"servo_periods=0.002 must be a tuple"):
        GapConfig(servo_periods=0.002)
    with pytest.raises(ConfigError, match=r"servo_periods entry=0.5 must be a finite number in "
                                          r"\(0, 0.1\]"):
        GapConfig(servo_periods=(0.001, 0.5))


def test_numpy_integers_are_counts_and_model_numbers_too():
    from lowcostdex.hardware.dynamixel.control_table import load_control_table
    from lowcostdex.teachers.flip_pinch import PinchFlipConfig
    from lowcostdex.teachers.flip_plan import FlipPlanConfig

    # before: np.int64 counts refused as "must be an integer >= 1" (they are integers) while
    # True was taken as 1; a model number from a numpy array was looked up as a model name
    assert PinchFlipConfig(wait=np.int64(3), carry_steps=np.int64(2),
                           square_steps=np.int64(0)).wait == 3
    assert FlipPlanConfig(horizon=np.int64(40)).horizon == 40
    with pytest.raises(ConfigError, match=r"PinchFlipConfig.wait=True must be an integer"):
        PinchFlipConfig(wait=True)
    assert load_control_table(np.int64(1020)) is load_control_table(1020)  # XM430-W350


def test_gap_generate_refuses_careless_arguments_before_any_simulation():
    from lowcostdex.gap.generate import generate

    rng = np.random.default_rng(0)
    # before: "unknown hidden effect 'l'" for "latency", n_logs 0 or -1 gave no logs without a
    # word, 2.0 / duration 0 / an int seed ended in TypeError, ValueError, AttributeError, and
    # level 5 hid an effect five times its plausible range
    cases = [({"hidden": "nonsense"}, r"unknown hidden effect 'nonsense'"),
             ({"n_logs": 0}, r"n_logs=0 must be an integer in \[1, inf\)"),
             ({"n_logs": -1}, r"n_logs=-1 must be an integer"),
             ({"n_logs": 2.0}, r"n_logs=2.0 must be an integer"),
             ({"duration": 0}, r"duration=0 must be a finite number in \[1, 3600\]"),
             ({"rng": 0}, r"rng=0 must be a numpy Generator, e.g. numpy.random.default_rng\(0\)"),
             ({"level": 5}, r"level=5 must be a finite number in \[0, 1\]")]
    for change, words in cases:
        kw = {"rig": "bench", "hidden": None, "rng": rng, "n_logs": 1, "duration": 1.0, **change}
        with pytest.raises(ConfigError, match=words):
            generate(kw.pop("rig"), kw.pop("hidden"), kw.pop("rng"), **kw)
    syn = generate("bench", "latency", rng, n_logs=1, duration=1.0)  # one name: that effect
    assert [e.name for e in syn.hidden] == ["latency"] and len(syn.trajectories) == 1
