"""Every unit and factory default the project uses for a Dynamixel model, checked against the
vendor's own published numbers typed in below (never against the project's constants).

Sources, one row per model:
  * the ROBOTIS e-Manual model page's control table, ROBOTIS-GIT/emanual
    ``docs/en/dxl/x/<model>.md`` (commit named per row): the "Initial/Default Value" and "Unit"
    columns of rows Model Number (0), ID (7), Baud Rate (8), Return Delay Time (9),
    Operating Mode (11), Moving Threshold (24), Temperature Limit (31), Max/Min Voltage Limit
    (32/34), PWM Limit (36), Current Limit (38, unit = the current unit), Velocity Limit (44),
    Max/Min Position Limit (48/52), Shutdown (63), Velocity I/P Gain (76/78), Position D/I/P
    Gain (80/82/84), Present Current (126) and Present Velocity (128) units;
  * the e-Manual's spec data ``_data/dxl_x_info.yml`` (commit 0028038): resolution
    "4096 [pulse/rev]" (0.088 deg), gear ratio, the bold (recommended-voltage) stall torque and
    no-load speed;
  * the Baud Rate table include (``_includes/en/dxl/control_table_baudrate_2.md``, quoted in
    05-dynamixel-protocol.md section 4): value 1 = 57,600 bps, 3 = 1 Mbps;
  * as an independent second source, the control-table files dynamixel-sdk 4.1 ships
    (``dynamixel_easy_sdk/control_table/*.model``), read directly here: model number map, item
    addresses, the velocity unit (rad/s per count) and the tick of 0 rad.
"""

from __future__ import annotations

import math
from importlib import resources

import numpy as np
import pytest

from lowcostdex.hardware.dynamixel.control_table import Reg, factory_defaults, load_control_table
from lowcostdex.hardware.dynamixel.protocol import BAUD_CODES, ErrorNumber
from lowcostdex.hardware.emulated.chain import emulated_bench
from lowcostdex.sim.servo import MOTORS

RPM = 2 * math.pi / 60  # rad/s per rev/min

# e-Manual rows common to the X430 and XL330 pages (identical on every page below).
COMMON = {
    "id": 1,  # ID(7) initial value
    "baud_index": 1,  # Baud Rate(8) initial value (= 57,600 bps)
    "return_delay": 250,  # Return Delay Time(9), unit 2 us
    "operating_mode": 3,  # Operating Mode(11): position control
    "moving_threshold": 10,  # Moving Threshold(24)
    "pwm_limit": 885,  # PWM Limit(36), unit 0.113 %
    "max_position": 4095, "min_position": 0,  # Max/Min Position Limit(48/52)
    "velocity_rpm": 0.229,  # Present Velocity(128) unit [rev/min]
    "pulse_per_rev": 4096,  # dxl_x_info.yml resolution "4096 [pulse/rev]"
    "degree": 0.088,  # "Degree of Precision 0.088 deg" / 360 / 4096
}

EMANUAL = {
    # docs/en/dxl/x/xm430-w210.md @8bb7656; dxl_x_info.yml xm430-w210
    "XM430-W210": dict(model_number=1030, current_ma=2.69, current_limit=1193,
                       velocity_limit=330, temperature_limit=80, max_voltage=160,
                       min_voltage=95, shutdown=52, velocity_i=1920, velocity_p=100,
                       position_d=0, position_i=0, position_p=800, volts=12.0,
                       stall_torque=3.0, no_load_rpm=77, gear_ratio=212.6),
    # docs/en/dxl/x/xm430-w350.md @0855172
    "XM430-W350": dict(model_number=1020, current_ma=2.69, current_limit=1193,
                       velocity_limit=200, temperature_limit=80, max_voltage=160,
                       min_voltage=95, shutdown=52, velocity_i=1920, velocity_p=100,
                       position_d=0, position_i=0, position_p=800, volts=12.0,
                       stall_torque=4.1, no_load_rpm=46, gear_ratio=353.5),
    # docs/en/dxl/x/xh430-w210.md @1cf2abe (2.69 mA; 1.34 mA is the XH430-V value)
    "XH430-W210": dict(model_number=1010, current_ma=2.69, current_limit=648,
                       velocity_limit=210, temperature_limit=80, max_voltage=160,
                       min_voltage=95, shutdown=52, velocity_i=1920, velocity_p=100,
                       position_d=0, position_i=0, position_p=900, volts=12.0,
                       stall_torque=2.5, no_load_rpm=50, gear_ratio=212.6),
    # docs/en/dxl/x/xh430-w350.md @028a13d and @6aca77e agree (the D'Claw's default motor)
    "XH430-W350": dict(model_number=1000, current_ma=2.69, current_limit=648,
                       velocity_limit=130, temperature_limit=80, max_voltage=160,
                       min_voltage=95, shutdown=52, velocity_i=1920, velocity_p=100,
                       position_d=0, position_i=0, position_p=900, volts=12.0,
                       stall_torque=3.4, no_load_rpm=30, gear_ratio=353.5),
    # docs/en/dxl/x/xh430-v210.md @00fc361 (the newest stored page; older layout with an
    # Acceleration Limit row; its Current Limit unit "about 1.34 [mA]")
    "XH430-V210": dict(model_number=1050, current_ma=1.34, current_limit=689,
                       velocity_limit=380, temperature_limit=80, max_voltage=300,
                       min_voltage=110, shutdown=52, velocity_i=1920, velocity_p=100,
                       position_d=0, position_i=0, position_p=800, volts=24.0,
                       stall_torque=2.6, no_load_rpm=52, gear_ratio=212.6),
    # docs/en/dxl/x/xh430-v350.md @6058d27
    "XH430-V350": dict(model_number=1040, current_ma=1.34, current_limit=689,
                       velocity_limit=135, temperature_limit=80, max_voltage=300,
                       min_voltage=110, shutdown=52, velocity_i=1920, velocity_p=100,
                       position_d=0, position_i=0, position_p=800, volts=24.0,
                       stall_torque=3.3, no_load_rpm=31, gear_ratio=353.5),
    # docs/en/dxl/x/xl330-m288.md @c72095b
    "XL330-M288": dict(model_number=1200, current_ma=1.0, current_limit=1750,
                       velocity_limit=445, temperature_limit=70, max_voltage=70,
                       min_voltage=35, shutdown=53, velocity_i=1600, velocity_p=180,
                       position_d=0, position_i=0, position_p=400, volts=5.0,
                       stall_torque=0.52, no_load_rpm=103, gear_ratio=288.4),
    # docs/en/dxl/x/xl330-m077.md @296754a
    "XL330-M077": dict(model_number=1190, current_ma=1.0, current_limit=1750,
                       velocity_limit=1620, temperature_limit=70, max_voltage=70,
                       min_voltage=35, shutdown=53, velocity_i=400, velocity_p=40,
                       position_d=0, position_i=400, position_p=400, volts=5.0,
                       stall_torque=0.215, no_load_rpm=383, gear_ratio=77.5),
    # Protocol 2.0 MX pages: docs/en/dxl/mx/mx-64-2.md @07a9912 (Current Limit and Goal
    # Current unit "about 3.36[mA]", Position P 850, "5.5Nm @ 11.1V / 6.0Nm @ 12V", "63rpm @
    # 12V", "Gear Ratio 200 : 1", "Resolution 0.088 deg", "Recommended : 12V")
    "MX-64": dict(model_number=311, current_ma=3.36, current_limit=1941,
                  velocity_limit=435, temperature_limit=80, max_voltage=160, min_voltage=95,
                  shutdown=52, velocity_i=1920, velocity_p=100, position_d=0, position_i=0,
                  position_p=850, volts=12.0, stall_torque=6.0, no_load_rpm=63,
                  gear_ratio=200.0),
    # docs/en/dxl/mx/mx-106-2.md @07fe860 ("8.4Nm @ 12V", "45rpm @ 12V", "225 : 1")
    "MX-106": dict(model_number=321, current_ma=3.36, current_limit=2047,
                   velocity_limit=360, temperature_limit=80, max_voltage=160, min_voltage=95,
                   shutdown=52, velocity_i=1920, velocity_p=100, position_d=0, position_i=0,
                   position_p=850, volts=12.0, stall_torque=8.4, no_load_rpm=45,
                   gear_ratio=225.0),
}

# dynamixel-sdk 4.1's dynamixel_easy_sdk/control_table/<model>.model "[control table]" rows
# the driver uses (address, size).
SDK_ITEMS = {Reg.ID: (7, 1), Reg.BAUD_RATE: (8, 1), Reg.TEMPERATURE_LIMIT: (31, 1),
             Reg.CURRENT_LIMIT: (38, 2), Reg.TORQUE_ENABLE: (64, 1),
             Reg.POSITION_D_GAIN: (80, 2), Reg.POSITION_I_GAIN: (82, 2),
             Reg.POSITION_P_GAIN: (84, 2), Reg.BUS_WATCHDOG: (98, 1),
             Reg.GOAL_POSITION: (116, 4), Reg.PRESENT_CURRENT: (126, 2),
             Reg.PRESENT_VELOCITY: (128, 4), Reg.PRESENT_POSITION: (132, 4),
             Reg.PRESENT_TEMPERATURE: (146, 1)}


def _sdk_text(name: str) -> str:
    return resources.files("dynamixel_easy_sdk").joinpath("control_table", name).read_text()


def _sdk_model_numbers() -> dict[int, str]:
    """The SDK's dynamixel.model: model number -> control-table file name."""
    rows = (line.split("\t") for line in _sdk_text("dynamixel.model").splitlines())
    return {int(cols[0]): cols[1] for cols in rows if len(cols) == 2 and cols[0].isdigit()}


def _sdk_model_file(name: str) -> dict[str, dict[str, list[str]]]:
    """Sections of an SDK .model file: {section: {name: columns}}; control-table rows are keyed
    by their item name in lower case, the other sections by their first column."""
    sections: dict[str, dict[str, list[str]]] = {}
    current = None
    for line in _sdk_text(name).splitlines():
        line = line.strip()
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], {})
        elif line and current is not None:
            cols = line.split("\t")
            # control-table names lower-cased: the MX files write "BUS Watchdog"
            key = cols[2].lower() if len(cols) == 3 and cols[0].isdigit() else cols[0]
            current.setdefault(key, cols)
    return sections


@pytest.mark.parametrize("model", sorted(EMANUAL))
def test_units_and_factory_defaults_match_the_vendor(model):
    row = {**COMMON, **EMANUAL[model]}
    motor = MOTORS[model]
    defaults = factory_defaults(model)

    # units the driver decodes with and the emulator encodes with
    assert motor.current_unit == pytest.approx(row["current_ma"] * 1e-3, rel=1e-12)
    assert motor.velocity_unit == pytest.approx(row["velocity_rpm"] * RPM, rel=1e-12)
    assert motor.ticks_per_rev == row["pulse_per_rev"]
    assert round(360.0 / motor.ticks_per_rev, 3) == row["degree"]
    assert motor.pwm_max == row["pwm_limit"]  # PWM full scale = factory PWM Limit (100 %)

    # the motor's physics at its recommended voltage (the bold row of the spec table)
    assert motor.model_number == row["model_number"]
    assert motor.voltage == row["volts"]
    assert motor.stall_torque == pytest.approx(row["stall_torque"])
    assert motor.no_load_speed == pytest.approx(row["no_load_rpm"] * RPM)
    assert motor.gear_ratio == pytest.approx(row["gear_ratio"])
    assert motor.thermal.limit == row["temperature_limit"]

    # factory gains: the simulated servo's and the emulated firmware's
    assert (motor.default_p, motor.default_i, motor.default_d) == (
        row["position_p"], row["position_i"], row["position_d"])
    g = motor.factory_gains()
    assert (g.position_p, g.position_i, g.position_d) == (
        row["position_p"], row["position_i"], row["position_d"])

    # the control table the emulated motor boots with
    expected = {
        Reg.ID: row["id"], Reg.BAUD_RATE: row["baud_index"],
        Reg.RETURN_DELAY_TIME: row["return_delay"], Reg.OPERATING_MODE: row["operating_mode"],
        Reg.MOVING_THRESHOLD: row["moving_threshold"],
        Reg.TEMPERATURE_LIMIT: row["temperature_limit"],
        Reg.MAX_VOLTAGE_LIMIT: row["max_voltage"], Reg.MIN_VOLTAGE_LIMIT: row["min_voltage"],
        Reg.PWM_LIMIT: row["pwm_limit"], Reg.CURRENT_LIMIT: row["current_limit"],
        Reg.VELOCITY_LIMIT: row["velocity_limit"],
        Reg.MAX_POSITION_LIMIT: row["max_position"],
        Reg.MIN_POSITION_LIMIT: row["min_position"], Reg.SHUTDOWN: row["shutdown"],
        Reg.VELOCITY_I_GAIN: row["velocity_i"], Reg.VELOCITY_P_GAIN: row["velocity_p"],
        Reg.POSITION_D_GAIN: row["position_d"], Reg.POSITION_I_GAIN: row["position_i"],
        Reg.POSITION_P_GAIN: row["position_p"], Reg.TORQUE_ENABLE: 0, Reg.BUS_WATCHDOG: 0,
    }
    assert {r: defaults[r] for r in expected} == expected
    # Baud Rate value 1 is 57,600 bps, value 3 is 1 Mbps (e-Manual Baud Rate table)
    assert BAUD_CODES[row["baud_index"]] == 57_600 and BAUD_CODES[3] == 1_000_000

    # the second source: the SDK's own control-table file for this model
    numbers = _sdk_model_numbers()
    sdk = _sdk_model_file(numbers[row["model_number"]])
    assert numbers[row["model_number"]] == model.lower().replace("-", "_") + ".model"
    table = load_control_table(model)
    for reg, (address, size) in SDK_ITEMS.items():
        cols = sdk["control table"][reg.value.lower()]
        assert (int(cols[0]), int(cols[1])) == (address, size)
        assert (table[reg].address, table[reg].size) == (address, size)
    sdk_velocity = float(sdk["unit info"]["Present Velocity"][1])  # rad/s per count
    assert sdk["unit info"]["Present Velocity"][2] == "rad/s"
    # 0.0239691227 rad/s = 0.22889 rpm: the SDK's value and 0.229 agree to 0.05 %
    assert motor.velocity_unit == pytest.approx(sdk_velocity, rel=1e-3)
    assert int(sdk["type info"]["value_of_zero_radian_position"][1]) == table.zero_tick == 2048


# Range column of the XL330 pages' EEPROM rows, where it differs from the X430 pages'
# (docs/en/dxl/x/xl330-m288.md @028a13d, xl330-m077.md @01ba971; the Baud Rate include
# _includes/en/dxl/control_table_baudrate_2.md lists 0-6 for product group xl330 and 0-7, 7 =
# 4.5M, for the others): Baud Rate(8) 0 ~ 6, Drive Mode(10) 0 ~ 5, Max/Min Voltage Limit(32/34)
# 31 ~ 70, Velocity Limit(44) 0 ~ 2,047. X430 pages (xh430-w350.md): Baud Rate 0 ~ 7, Velocity
# Limit 0 ~ 1,023.
XL330_RANGES = {Reg.BAUD_RATE: (0, 6), Reg.DRIVE_MODE: (0, 5), Reg.MAX_VOLTAGE_LIMIT: (31, 70),
                Reg.MIN_VOLTAGE_LIMIT: (31, 70), Reg.VELOCITY_LIMIT: (0, 2047)}
X430_RANGES = {Reg.BAUD_RATE: (0, 7), Reg.VELOCITY_LIMIT: (0, 1023)}


@pytest.mark.parametrize("model, ranges", [("XL330-M288", XL330_RANGES),
                                           ("XL330-M077", XL330_RANGES),
                                           ("XH430-W350", X430_RANGES)])
def test_the_emulated_motor_accepts_the_e_manuals_ranges_and_refuses_beyond(model, ranges):
    """Device side: the emulated firmware takes each range's ends and answers a Data Range Error
    one past them (an XL330-M077 written its own factory Velocity Limit 1,620 must accept it;
    an XL330 has no 4.5 Mbps)."""
    chain = emulated_bench(model, rng=np.random.default_rng(0))
    fw = chain.motors[1]
    state = chain.drive.state()
    for reg, (lo, hi) in ranges.items():
        size = fw.table[reg].size
        for value, error in ((lo, 0), (hi, 0), (hi + 1, ErrorNumber.DATA_RANGE)):
            assert fw.write(fw.table.address(reg), value.to_bytes(size, "little"), state) == error, \
                (reg, value)
        if lo > 0:
            assert fw.write(fw.table.address(reg), (lo - 1).to_bytes(size, "little"), state) == \
                ErrorNumber.DATA_RANGE
        assert fw.write(fw.table.address(reg), factory_defaults(model)[reg].to_bytes(size, "little"),
                        state) == 0  # its own factory value


# -- MX with Protocol 1.0 firmware (BAM's MX benches) ---------------------------------------------
# docs/en/dxl/mx/mx-64.md @0117956: Model Number(0) 310, P Gain(28) initial 32, Temperature
# Limit(11) 80, CCW Angle Limit 4,095, Moving Speed "the unit is about 0.114rpm", Current(68)
# "I = ( 4.5mA ) * (CURRENT - 2048 )". BAM (Rhoban/bam README @c50ae40, quoted in
# 07-measured-data.md section 4): the P path measured with an oscilloscope at 15 V, H = 2.391 V
# per (P unit * rad) on the MX-64 -> 0.158 duty per (P unit * rad) (2.391 / 15 = 0.159), PWM
# ceiling 0.9625.
MX_P1 = {"MX-64(1.0)": dict(model_number=310, stall_torque=6.0, no_load_rpm=63),
         "MX-106(1.0)": dict(model_number=320, stall_torque=8.4, no_load_rpm=45)}


@pytest.mark.parametrize("model", sorted(MX_P1))
def test_mx_protocol_1_units_and_bams_measured_gain(model):
    motor, row = MOTORS[model], MX_P1[model]
    assert motor.model_number == row["model_number"]
    assert (motor.default_p, motor.default_i, motor.default_d) == (32, 0, 0)
    assert motor.velocity_unit == pytest.approx(0.114 * RPM, rel=1e-12)
    assert motor.current_unit == pytest.approx(4.5e-3, rel=1e-12)
    assert motor.ticks_per_rev == 4095 + 1 and motor.thermal.limit == 80
    assert motor.error_gain == pytest.approx(2.391 / 15.0, rel=0.01)
    assert motor.max_duty == 0.9625
    # the same motor as its Protocol 2.0 twin (same datasheet rows)
    twin = MOTORS[model.removesuffix("(1.0)")]
    assert (motor.stall_torque, motor.no_load_speed) == (twin.stall_torque, twin.no_load_speed)
    assert motor.stall_torque == row["stall_torque"]
    assert motor.no_load_speed == pytest.approx(row["no_load_rpm"] * RPM)


def test_mx_factory_stiffness_agrees_between_the_two_firmwares():
    # Protocol 2.0: K_P = P / 128 (e-Manual control_table_position_pid_gain include) in PWM
    # counts per encoder tick, PWM full scale 885, 4096 ticks per turn, factory P 850:
    p2 = 850 / 128 / 885 * 4096 / (2 * math.pi)  # duty per rad = 4.891
    # Protocol 1.0: BAM's oscilloscope measurement at the factory P 32: 0.158 duty per P rad
    p1 = 32 * 0.158  # = 5.056
    assert p2 == pytest.approx(4.891, abs=1e-3) and abs(p1 / p2 - 1) < 0.04
    for p2_model in ("MX-64", "MX-106"):
        m = MOTORS[p2_model]
        assert m.default_p * m.error_gain == pytest.approx(p2, rel=1e-9)
        m1 = MOTORS[p2_model + "(1.0)"]
        assert m1.default_p * m1.error_gain == pytest.approx(p1, rel=1e-9)


def test_bam_mx_logs_read_with_the_protocol_1_motor():
    from lowcostdex.gap.logs import BAM_MOTORS

    # BAM's MX recorder drives Protocol 1.0 firmware (friction_1.json: "register 36 at 1 Mbps",
    # Present Position's P1 address), so its header kp is the P1 P Gain
    assert BAM_MOTORS["mx64"] == "MX-64(1.0)" and BAM_MOTORS["mx106"] == "MX-106(1.0)"


# -- MX(2.0) on the wire: the SDK's MX files and the driver -----------------------------------------


def test_an_mx64_protocol_2_motor_is_driven_through_the_sdk(recwarn):
    from lowcostdex.hardware.dynamixel.driver import DynamixelBus
    from lowcostdex.hardware.emulated.chain import emulated_bench

    # e-Manual mx-64-2 row "|98|1|[BUS Watchdog]": the SDK file spells it "BUS Watchdog", the X
    # files "Bus Watchdog"; the driver needs it by one name on every motor
    assert "98\t1\tBUS Watchdog" in _sdk_text("mx_64.model")
    assert load_control_table("MX-64")[Reg.BUS_WATCHDOG].address == 98
    chain = emulated_bench("MX-64")
    with DynamixelBus.from_hand(chain.hand, chain.port(), handle_signals=False) as bus:
        assert bus.read_register(1, Reg.MODEL_NUMBER) == 311
        assert bus.gains[1].position_p == 850  # factory gain read back: no mismatch warning
        assert bus.read_register(1, Reg.CURRENT_LIMIT) == 1941
        bus.write_register(1, Reg.BUS_WATCHDOG, 5)  # 100 ms, by its e-Manual name
        assert bus.read_register(1, Reg.BUS_WATCHDOG) == 5
        bus.write_register(1, Reg.BUS_WATCHDOG, 0)
        s = bus.read_state()
        assert s.valid.all() and abs(s.temperature[0] - 25) < 5
    assert not [w for w in recwarn if "gain" in str(w.message).lower()]


def test_an_mx28_protocol_2_motor_is_refused_it_reports_load_not_current():
    from lowcostdex.errors import ConfigError
    from lowcostdex.hardware.dynamixel.config import DynamixelConfig
    from lowcostdex.hardware.dynamixel.driver import DynamixelBus
    from lowcostdex.hardware.emulated.chain import emulated_bench

    # e-Manual mx-28-2.md @07fe860: Model Number 30, "|126|2|[Present Load]" where the X and
    # MX-64/106 pages have Present Current; the SDK's mx_28.model agrees
    assert "126\t2\tPresent Load" in _sdk_text("mx_28.model")
    table = load_control_table(30)
    assert table.model == "MX-28" and Reg.PRESENT_CURRENT not in table
    chain = emulated_bench("MX-64")
    with pytest.raises(ConfigError, match="MX-28.*Present Current"):
        DynamixelBus(chain.port(), DynamixelConfig(ids=(1,), models=("MX-28",)))


def test_mx28_spec_is_the_e_manuals():
    # e-Manual docs/en/dxl/mx/mx-28-2.md @07fe860: "|0|2|[Model Number]...| 30 |", "Gear Ratio |
    # 193 : 1", "Stall Torque | ... 2.5Nm @ 12V", "No Load Speed | ... 55rpm @ 12V",
    # "Recommended : 12V", "|31|1|[Temperature Limit]...|80|", Position D/I/P Gain (80/82/84)
    # initial 0/0/850, and Present Load (126) where the X pages have Present Current
    motor = MOTORS["MX-28"]
    assert motor.model_number == 30 and motor.voltage == 12.0
    assert motor.stall_torque == 2.5 and motor.gear_ratio == 193.0
    assert motor.no_load_speed == pytest.approx(55 * RPM, rel=1e-12)
    assert motor.thermal.limit == 80
    assert (motor.default_p, motor.default_i, motor.default_d) == (850, 0, 0)
    assert motor.velocity_unit == pytest.approx(0.229 * RPM, rel=1e-12)
    assert math.isnan(motor.current_unit)  # no current register: no unit may be invented


# -- Feetech STS ----------------------------------------------------------------------------------
# Feetech's own STS memory table, ftservo/ftservo-wiki docs/en/reference/parameter/memory-sts.md
# @9522ce192f4c7bfd40b0c3f72c0b3bb52cc24630 ("Magnetically Encoded STS Servo - Memory Table", the
# header it names as its source is Feetech's SMS_STS.h):
#   | 13 | 0x0D | Maximum temperature limit | 1 | 70 | R/W | 0~100 | deg C |
#   | 21 | 0x15 | Position loop P (proportional) coefficient | 1 | – |     (per model)
#   | 22 | 0x16 | Position loop D (derivative) coefficient | 1 | – |      (per model)
#   | 23 | 0x17 | Position loop I (integral) coefficient | 1 | 0 |
#   | 46 | 0x2E | Running speed | ... | 0.732RPM/0.0146RPM |  (Phase bit 2 selects the unit)
#   | 69 | 0x45 | Present current | 2 | – | R | – | 6.5mA |
# The P and D initial values the table leaves to the model: lerobot
# src/lerobot/robots/so100_follower/so100_follower.py @0eff8f5ce66f6f7982a2ef25bc2d12611f22ec01,
# configure(): "Set P_Coefficient to lower value to avoid shakiness (Default is 32)", "Set
# I_Coefficient and D_Coefficient to default value 0 and 32" (read from STS3215 motors).
# Model numbers: lerobot src/lerobot/motors/feetech/tables.py @0558acc: MODEL_NUMBER_TABLE
# "sts3215": 777, "sts3250": 2825 (read from the motor's Model_Number at address 3),
# MODEL_RESOLUTION 4096 for both.
STS_TEMPERATURE_LIMIT = 70.0  # deg C, address 13 initial value
STS_PID = (32, 0, 32)  # P (lerobot "Default is 32"), I (memory table 0), D (lerobot "32")
STS_CURRENT_UNIT = 6.5e-3  # A, "6.5mA"
STS_SPEED_UNIT_RPM = 0.0146  # rpm, the fine unit of Running/Present speed
FEETECH = {"STS3215": dict(model_number=777), "STS3250": dict(model_number=2825),
           "STS3032": dict(model_number=None)}


@pytest.mark.parametrize("model", sorted(FEETECH))
def test_feetech_sts_units(model):
    motor = MOTORS[model]
    if FEETECH[model]["model_number"] is not None:
        assert motor.model_number == FEETECH[model]["model_number"]
    else:  # no published number for the STS3032: the spec must not invent one
        assert motor.model_number == 0
    assert motor.ticks_per_rev == 4096
    assert motor.velocity_unit == pytest.approx(2 * math.pi / 4096, rel=1e-12)  # 1 step/s
    # ... which is the table's fine speed unit (0.0146 rpm, printed to 3 significant digits)
    assert motor.velocity_unit == pytest.approx(STS_SPEED_UNIT_RPM * RPM, rel=4e-3)
    assert motor.current_unit == pytest.approx(STS_CURRENT_UNIT, rel=1e-12)
    assert (motor.default_p, motor.default_i, motor.default_d) == STS_PID
    assert motor.thermal.limit == STS_TEMPERATURE_LIMIT


def test_feetech_d_gain_is_a_register_value_the_model_does_not_apply():
    # The factory D (32) is what the motor holds; its scale in duty is unpublished, and the
    # error_gain the model uses (BAM's STS3215 fit, made at the factory gains) already absorbs
    # its effect: the simulated servo must damp exactly as with D = 0.
    from lowcostdex.sim.servo import dcmotor_params

    for model in FEETECH:
        motor = MOTORS[model]
        factory = motor.factory_gains()
        assert factory.position_d == 32
        with_d = dcmotor_params(motor, factory)
        without = dcmotor_params(motor, factory.replace(position_d=0))
        assert with_d.kd == without.kd
        assert with_d.kd == pytest.approx(motor.motorconst ** 2 / motor.resistance, rel=1e-12)


def test_sts3215_physical_numbers_are_feetechs():
    # Feetech's ST-3215-C001 spec table (feetechrc.com, as kept in ftservo/ftservo-wiki
    # docs/en/products/models/st-3215-c001/official-specs.json @9522ce19): "Peak stall torque:
    # 19.5kg.cm@6V", "No load speed: 0.238sec/60°@6V", "Operating Temperature Range: -20~70";
    # gear 1/345: the SO-100/SO-101 parts list (TheRobotStudio/SO-ARM100 README, "STS3215 Servo
    # 7.4V, 1/345 gear (C001)").
    motor = MOTORS["STS3215"]
    assert motor.voltage == 6.0
    assert motor.stall_torque == pytest.approx(19.5 * 9.80665e-2, rel=1e-9)  # kgf cm -> N m
    assert motor.no_load_speed == pytest.approx(math.radians(60) / 0.238, rel=1e-9)
    assert motor.gear_ratio == 345.0
