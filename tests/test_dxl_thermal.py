"""Thermal: a stalled servo heats to its Temperature Limit; the firmware latches Overheating, sets
the alert bit and drops torque, as real X-series firmware does; only a reboot clears it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.hardware.bus import MotorFault
from lowcostdex.hardware.dynamixel.control_table import Reg
from lowcostdex.hardware.dynamixel.driver import DynamixelBus
from lowcostdex.hardware.dynamixel.protocol import ALERT, HardwareError
from lowcostdex.hardware.emulated.chain import emulated_bench
from lowcostdex.sim import servo


def test_stall_heats_to_the_limit_then_overheating_shuts_the_motor_down():
    chain = emulated_bench()  # XL330-M288 on an arm with hard stops at +-2.6 rad; limit 70 C
    motor = chain.motors[1]
    act = int(chain.drive.acts[motor.index])
    with DynamixelBus.from_hand(chain.hand, chain.port(), handle_signals=False) as bus:
        assert bus.read_register(1, Reg.TEMPERATURE_LIMIT) == 70
        bus.write_register(1, Reg.POSITION_P_GAIN, 3000)  # stiff: full PWM against the stop
        bus.set_torque(True)
        bus.write_goal_positions([2 * math.pi - 0.05])  # joint 3.09 rad: beyond the 2.6 stop
        temps, currents = [], []
        for _ in range(200):
            bus.sleep(1.0)  # keeps the 100 ms bus watchdog fed
            s = bus.read_state()
            temps.append(s.temperature[0])
            currents.append(s.current[0])
            if s.hardware_error[0]:
                break
        assert 20 < len(temps) < 200
        assert temps[0] < 30 and np.all(np.diff(temps[:-1]) >= 0)  # steady heating
        assert temps[-2] >= 60  # it got there under load ...
        assert np.median(currents[:-1]) > 0.9  # ... near stall current (V/R = 1.12 A)
        assert s.hardware_error[0] == HardwareError.OVERHEATING
        assert bus.faults == {1: ("overheating",)}
        (heat, shutdown) = [e for e in chain.events if e.kind in ("hardware_error", "shutdown")]
        assert heat.detail == shutdown.detail == "overheating"
        # the device side: latched at the limit, alert in every status, torque off, no current
        assert motor.hardware_error == HardwareError.OVERHEATING and motor.error_byte == ALERT
        assert not motor.torque_on and not chain.plant.torque_enabled()[act]
        assert servo.winding_temperature(chain.plant.model, chain.plant.data)[act] < 71
        bus.sleep(2.0)
        cooling = bus.read_state()
        assert cooling.current[0] == pytest.approx(0.0, abs=0.01)
        assert cooling.temperature[0] < temps[-1]
        with pytest.raises(MotorFault, match="overheating"):
            bus.set_torque(True)  # latched until reboot
        bus.sleep(60.0)
        bus.reboot(1)
        assert bus.read_state().hardware_error[0] == 0 and not bus.faults
        bus.set_torque(True)
        assert motor.torque_on
