"""Control tables loaded from the SDK's .model files; device-side defaults and ranges."""

from __future__ import annotations

import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.hardware.dynamixel.control_table import (
    SUPPORTED_MODELS,
    Reg,
    factory_defaults,
    load_control_table,
    model_name,
    model_numbers,
    value_range,
)
from lowcostdex.sim.servo import MOTORS

REQUIRED = ("XM430-W210", "XM430-W350", "XH430-V350", "XH430-W350", "XL330-M288")


@pytest.mark.parametrize("model", REQUIRED)
def test_tables_load_with_model_numbers_that_match_the_servo_catalogue(model):
    table = load_control_table(model)
    assert table.model == model
    assert table.model_number == MOTORS[model].model_number
    assert load_control_table(table.model_number) is table
    assert model_name(table.model_number) == model


@pytest.mark.parametrize("model", REQUIRED)
def test_present_block_is_contiguous_126_to_146(model):
    t = load_control_table(model)
    expect = [(Reg.PRESENT_CURRENT, 126, 2), (Reg.PRESENT_VELOCITY, 128, 4),
              (Reg.PRESENT_POSITION, 132, 4), (Reg.VELOCITY_TRAJECTORY, 136, 4),
              (Reg.POSITION_TRAJECTORY, 140, 4), (Reg.PRESENT_INPUT_VOLTAGE, 144, 2),
              (Reg.PRESENT_TEMPERATURE, 146, 1)]
    for reg, addr, size in expect:
        assert (t[reg].address, t[reg].size) == (addr, size)
    assert t[Reg.PRESENT_TEMPERATURE].end - t[Reg.PRESENT_CURRENT].address == 21
    assert (t[Reg.GOAL_POSITION].address, t[Reg.TORQUE_ENABLE].address,
            t[Reg.BUS_WATCHDOG].address, t[Reg.HARDWARE_ERROR_STATUS].address) == (116, 64, 98, 70)


def test_x430_table_has_the_indirect_area_and_size():
    t = load_control_table("XM430-W210")
    assert t.size == 662 and t.raw_start == 168
    assert t.item_at(132).name == "Present Position"
    assert t.item_at(133) is None  # inside an item


def test_model_number_map_is_from_the_sdk_file():
    numbers = model_numbers()
    assert numbers[1030] == "XM430-W210" and numbers[1020] == "XM430-W350"
    assert numbers[1000] == "XH430-W350" and numbers[1040] == "XH430-V350"
    assert numbers[1200] == "XL330-M288"
    assert model_name(4242) == "unknown(4242)"


def test_unknown_model_lists_the_choices():
    with pytest.raises(ConfigError, match="XM430-W210"):
        load_control_table("XM999-Z000")


@pytest.mark.parametrize("model", SUPPORTED_MODELS)
def test_factory_defaults_share_the_servo_models_p_gain(model):
    d = factory_defaults(model)
    assert d[Reg.POSITION_P_GAIN] == MOTORS[model].default_p
    # Shutdown 52 on the X430 pages, 53 on the XL330 pages (e-Manual; tests/test_vendor_units.py)
    assert d[Reg.RETURN_DELAY_TIME] == 250 and d[Reg.SHUTDOWN] in (52, 53)
    assert d[Reg.OPERATING_MODE] == 3 and d[Reg.TORQUE_ENABLE] == 0
    assert d[Reg.CURRENT_LIMIT] == value_range(Reg.CURRENT_LIMIT, d, model)[1]


def test_dependent_ranges_follow_the_limits():
    values = {Reg.PWM_LIMIT: 500, Reg.CURRENT_LIMIT: 600, Reg.VELOCITY_LIMIT: 100}
    assert value_range(Reg.GOAL_PWM, values, "XM430-W210") == (-500, 500)
    assert value_range(Reg.GOAL_CURRENT, values, "XM430-W210") == (-600, 600)
    assert value_range(Reg.GOAL_VELOCITY, values, "XM430-W210") == (-100, 100)
    assert value_range(Reg.BUS_WATCHDOG, values, "XM430-W210") == (0, 127)
    assert value_range(Reg.GOAL_POSITION, values, "XM430-W210") is None  # mode dependent
