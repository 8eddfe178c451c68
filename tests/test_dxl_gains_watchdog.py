"""The driver reads the motors' gains at connect and checks the firmware before arming the Bus
Watchdog; the emulated motors boot with their model's factory gains and the simulated D'Claw uses
the same numbers. Checked on the device side of the emulated chain."""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
import pytest

from lowcostdex.hardware.dynamixel.config import GainMismatchWarning, WatchdogUnavailableWarning
from lowcostdex.hardware.dynamixel.control_table import Reg
from lowcostdex.hardware.dynamixel.driver import DynamixelBus
from lowcostdex.hardware.emulated.chain import emulated_dclaw
from lowcostdex.hardware.emulated.firmware import FirmwareOptions
from lowcostdex.sim import servo
from lowcostdex.sim.models.dclaw import build_dclaw

# ROBOTIS e-Manual, docs/en/dxl/x/xh430-w350.md control table: Position P Gain (84) 900,
# Position I (82) 0, Position D (80) 0, PWM Limit (36) 885 (the D'Claw's default motor).
XH430_W350_PID = (900, 0, 0)


def _set_register(chain, motor_id, reg, value):
    """Write a register on the device side (as a person with DYNAMIXEL Wizard would)."""
    m = chain.motors[motor_id]
    err = m.write(m.table.address(reg), value.to_bytes(m.table[reg].size, "little"),
                  chain.drive.state())
    assert err == 0


def _connect(chain, **kwargs):
    bus = DynamixelBus.from_hand(chain.hand, chain.port(), handle_signals=False, **kwargs)
    bus.connect()
    return bus


def test_gains_are_read_at_connect_and_are_the_factory_gains():
    chain = emulated_dclaw(rng=np.random.default_rng(0))
    with warnings.catch_warnings():
        warnings.simplefilter("error", GainMismatchWarning)
        bus = _connect(chain)
    try:
        for i in bus.ids:
            g = bus.gains[i]
            assert (g.position_p, g.position_i, g.position_d) == XH430_W350_PID
            assert g.pwm_limit == 885
    finally:
        bus.disconnect()


def test_the_simulated_dclaw_uses_the_gains_the_motors_report():
    chain = emulated_dclaw(rng=np.random.default_rng(0))
    bus = _connect(chain)
    try:
        gains = {bus.gains[i] for i in bus.ids}
    finally:
        bus.disconnect()
    assert len(gains) == 1
    (read,) = gains
    model = build_dclaw("valve").compile()  # the nominal simulation, default gains
    motor = servo.motor_spec("XH430-W350")
    kp = servo.dcmotor_params(motor, read).kp
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, j.name)
           for j in chain.hand.all_joints if j.name != "valve"]
    ids = [a for a in ids if a >= 0]
    assert ids and np.allclose(model.actuator_gainprm[ids, servo.GAIN_KP], kp, rtol=1e-12)


def test_a_motor_with_other_gains_is_named_and_can_be_set_at_connect():
    chain = emulated_dclaw(rng=np.random.default_rng(0))
    _set_register(chain, 21, Reg.POSITION_P_GAIN, 800)
    with pytest.warns(GainMismatchWarning, match=r"21: 800/0/0 \(factory 900/0/0\)"):
        bus = _connect(chain)
    assert bus.gains[21].position_p == 800 and bus.gains[20].position_p == 900
    bus.disconnect()
    with warnings.catch_warnings():
        warnings.simplefilter("error", GainMismatchWarning)
        bus = _connect(chain, position_gains=XH430_W350_PID)
    try:
        assert chain.motors[21].get(Reg.POSITION_P_GAIN) == 900  # device side
        assert bus.gains[21].position_p == 900
    finally:
        bus.disconnect()


# ROBOTIS e-Manual, _includes/en/dxl/control_table_buswatchdog.md (ROBOTIS-GIT/emanual): "NOTE:
# Bus Watchdog (98) is available from firmware v38." (every X page but XL330's); "1 ~ 127 Activate
# Bus Watchdog (Unit: 20 [msec])": 100 ms is the register value 5.
@pytest.mark.parametrize("firmware, armed", [(37, False), (38, True)])
def test_bus_watchdog_is_written_only_to_firmware_38_or_newer(firmware, armed):
    chain = emulated_dclaw(rng=np.random.default_rng(0),
                           options=FirmwareOptions(firmware_version=firmware))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        bus = _connect(chain, watchdog_ms=100)
    told = [w for w in caught if issubclass(w.category, WatchdogUnavailableWarning)]
    try:
        assert bool(told) != armed
        if told:
            assert "v37" in str(told[0].message) and "Firmware Update" in str(told[0].message)
        bus.set_torque(True)
        for i in bus.ids:  # device side: the register the firmware would act on
            assert chain.motors[i].get(Reg.BUS_WATCHDOG) == (5 if armed else 0)
            assert chain.motors[i].torque_on
    finally:
        bus.disconnect()
