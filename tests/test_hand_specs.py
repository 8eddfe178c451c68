"""Hand specs are checked where they are built or loaded: one message naming the joint, the field
and the value (issue 12 item 3). Expected bounds are worked out here by hand."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest

from lowcostdex.cli import main
from lowcostdex.errors import ConfigError, InputError, LowcostdexError
from lowcostdex.hands import Calibration, HandSpec, JointSpec, dclaw_spec
from lowcostdex.hardware.emulated.chain import emulated_dclaw
from lowcostdex.hardware.robot.backend import make_dynamixel_bus

HAND = dclaw_spec()  # XH430-W350 servos


def with_joint(hand: HandSpec, name: str, **changes) -> HandSpec:
    return dataclasses.replace(hand, joints=tuple(
        dataclasses.replace(j, **changes) if j.name == name else j for j in hand.joints))


def test_the_built_in_specs_pass():
    from lowcostdex.hands import HANDS

    for make in HANDS.values():
        make()


def test_limits_wider_than_the_motors_turn_are_refused():
    # +-4 rad is 8 rad of motor travel; position mode covers one turn, 2 pi = 6.283 rad
    with pytest.raises(ConfigError, match=r"ff_middle: limits \[-4.0, 4.0\].*more than its one"):
        with_joint(HAND, "ff_middle", low=-4.0, high=4.0)


def test_limits_outside_the_motors_range_are_refused():
    # offset 0: joint [-0.5, 0.5] rad is motor angle [-0.5, 0.5], below tick 0
    with pytest.raises(ConfigError, match=r"ff_top: .*motor 10 angles \[-0.5000, 0.5000\]"):
        with_joint(HAND, "ff_top", low=-0.5, high=0.5, calibration=Calibration(offset=0.0))
    # with ROBEL's offset -pi/2 the same limits are motor angles [1.07, 2.07]: fine
    with_joint(HAND, "ff_top", low=-0.5, high=0.5)


def test_limits_outside_the_models_joint_range_are_refused_before_the_eeprom():
    # the D'Claw model's middle joints stop at +-2.0 rad; +-2.5 fits the motor's turn
    # (motor angles pi -+ 2.5 = [0.64, 5.64]) but not the finger. A spec named "dclaw" is
    # refused where it is built (test_careless21); one under another name meets the bus's check
    hand = with_joint(dataclasses.replace(HAND, name="my_claw"), "ff_middle", low=-2.5, high=2.5)
    chain = emulated_dclaw("valve", hand=HAND)
    with pytest.raises(ConfigError, match=r"ff_middle: limits \[-2.5, 2.5\].*\[-2.0, 2.0\]"):
        make_dynamixel_bus(hand, chain.port(), chain.plant.model)
    assert not any(m.torque_on for m in chain.motors.values())


@pytest.mark.parametrize("value", [1e6, 0.0, -1.0, math.nan, math.inf])
def test_implausible_max_velocity_is_refused(value):
    with pytest.raises(ConfigError, match=rf"ff_top: max_velocity.*{value}"):
        with_joint(HAND, "ff_top", max_velocity=value)


def test_max_velocity_faster_than_the_motor_is_refused():
    # XH430-W350: 30 rpm no-load at 12 V = 30 * 2 pi / 60 = 3.1416 rad/s at the joint
    with_joint(HAND, "ff_top", max_velocity=3.1)
    with pytest.raises(ConfigError, match=r"ff_top: max_velocity 3.2 .*3.142 rad/s"):
        with_joint(HAND, "ff_top", max_velocity=3.2)


@pytest.mark.parametrize("field,value", [("offset", math.nan), ("offset", math.inf),
                                         ("scale", math.inf), ("scale", math.nan)])
def test_non_finite_calibration_is_refused(field, value):
    with pytest.raises(ConfigError, match=rf"calibration {field}.*{value}"):
        Calibration(**{field: value})


def test_non_finite_limits_are_refused():
    with pytest.raises(ConfigError, match=r"joint a: low must be a finite number, got -inf"):
        JointSpec("a", 1, -math.inf, 1.0)
    with pytest.raises(ConfigError, match=r"joint a: high .*nan"):
        JointSpec("a", 1, 0.0, math.nan)


def test_two_joints_on_one_motor_id_are_refused():
    with pytest.raises(ConfigError, match=r"ff_top and ff_middle are both on motor id 10"):
        with_joint(HAND, "ff_middle", motor_id=10)
    with pytest.raises(ConfigError, match=r"ff_top and valve are both on motor id 10"):
        dataclasses.replace(HAND, aux_joints=(dataclasses.replace(HAND.aux_joints[0],
                                                                   motor_id=10),))


def spec_file(tmp_path, edit) -> str:
    raw = json.loads(HAND.to_json())
    edit(raw)
    path = tmp_path / "hand.json"
    path.write_text(json.dumps(raw))  # json writes NaN as NaN, and reads it back
    return str(path)


def test_a_loaded_spec_is_checked_and_the_file_named(tmp_path):
    path = spec_file(tmp_path, lambda r: r["joints"][1]["calibration"].update(offset=math.nan))
    with pytest.raises(InputError, match=rf"{path}: calibration offset .*nan"):
        HandSpec.load(path)
    path = spec_file(tmp_path, lambda r: r["joints"][2].update(max_velocity=1e6))
    with pytest.raises(InputError, match=rf"{path}: joint ff_bottom: max_velocity 1000000.0"):
        HandSpec.load(path)
    path = spec_file(tmp_path, lambda r: r["joints"][2].update(max_velocity="fast"))
    with pytest.raises(InputError, match=rf"{path}: joint ff_bottom: max_velocity.*'fast'"):
        HandSpec.load(path)
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(InputError, match="junk.json: not a hand spec JSON"):
        HandSpec.load(tmp_path / "junk.json")
    assert issubclass(InputError, LowcostdexError)


def test_the_cli_prints_one_line_for_a_bad_spec(tmp_path, capsys):
    path = spec_file(tmp_path, lambda r: r["joints"][4].update(motor_id=10))
    code = main(["calibrate", "--spec", path, "--port", "emulated", "--out",
                 str(tmp_path / "out.json"), "--yes"])
    err = capsys.readouterr().err
    assert code == 2
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "ff_top and mf_middle are both on motor id 10" in err and path in err
    assert not (tmp_path / "out.json").exists()


def test_an_unknown_motor_model_is_refused_with_the_known_ones(tmp_path):
    """A typo in the motor model ("XM430-W530", or the Dynamixel easy SDK's lower-case
    "xm430-w350") used to pass unchecked, skipping the motor-range checks; now it is refused
    and the message lists the models the project has data sheets for."""
    for typo in ("XM430-W530", "xm430-w350", ""):
        with pytest.raises(ConfigError, match=rf"hand dclaw: unknown motor model '{typo}'; "
                                              r"valid choices: .*XH430-W350.*STS3032"):
            dclaw_spec(typo)
    path = spec_file(tmp_path, lambda r: r.update(motor="XM430-W530"))
    with pytest.raises(LowcostdexError, match=rf"{path}: .*unknown motor model 'XM430-W530'"):
        HandSpec.load(path)
