"""DynamixelBus on the real dynamixel_sdk against the emulated chain, checked on the device side."""

from __future__ import annotations

import dataclasses
import math
import os
import sys

import numpy as np
import pytest

from lowcostdex import motion
from lowcostdex.hands import Calibration, dclaw_spec
from lowcostdex.hardware.bus import BusError, CommandError, MotorFault
from lowcostdex.hardware.dynamixel.config import (
    LatencyWarning,
    PositionOutOfLimits,
    WatchdogTripped,
)
from lowcostdex.hardware.dynamixel.control_table import Reg
from lowcostdex.hardware.dynamixel.driver import DynamixelBus
from lowcostdex.hardware.dynamixel.protocol import HardwareError
from lowcostdex.hardware.emulated.chain import emulated_dclaw
from lowcostdex.hardware.emulated.firmware import FirmwareOptions
from lowcostdex.hardware.robot.calibration import calibrate_offsets

TICK = 2 * math.pi / 4096


def true_motor_angles(chain):
    """Motor angles [rad] the encoders see, from the physics and the true mounting."""
    m = chain.plant.model
    out = []
    for j in chain.hand.all_joints:
        fw = chain.motors[j.motor_id]
        q = chain.plant.qpos[m.jnt_qposadr[m.joint(j.name).id]]
        out.append(fw.calibration.to_motor(q) + fw.turn_offset * TICK)
    return np.array(out)


@pytest.fixture
def dclaw():
    chain = emulated_dclaw(rng=np.random.default_rng(0))
    bus = DynamixelBus.from_hand(chain.hand, chain.port(), handle_signals=False)
    bus.connect()
    yield chain, bus
    bus.disconnect()


def test_connect_configures_the_motors(dclaw):
    chain, bus = dclaw
    hand = chain.hand
    for j in hand.all_joints:
        m = chain.motors[j.motor_id]
        assert m.get(Reg.RETURN_DELAY_TIME) == 0
        assert m.get(Reg.OPERATING_MODE) == 3
        lo, hi = sorted((j.calibration.to_motor(j.low), j.calibration.to_motor(j.high)))
        assert m.get(Reg.MIN_POSITION_LIMIT) == max(0, math.ceil(lo / TICK - 1e-9))
        assert m.get(Reg.MAX_POSITION_LIMIT) == min(4095, math.floor(hi / TICK + 1e-9))
        assert not m.torque_on and m.get(Reg.BUS_WATCHDOG) == 0
    assert bus.fast_read and bus.firmware == {i: 52 for i in bus.ids}


def test_the_block_read_every_step_is_the_one_the_simulations_motion_bound_assumes(dclaw):
    """The simulation narrows its motion bound by a clean bus's time computed from
    ``motion.PRESENT_BLOCK_BYTES``; the driver reads its block from the control table: e-Manual
    X-series Present Current (address 126) .. Present Temperature (146, 1 byte) = 21 bytes."""
    chain, bus = dclaw
    assert bus._block_len == motion.PRESENT_BLOCK_BYTES == 146 + 1 - 126
    assert bus._block_addr == 126 and bus.config.baudrate == motion.DEFAULT_BAUDRATE


def test_model_mismatch_and_missing_ids_are_listed():
    chain = emulated_dclaw(motor="XM430-W210", missing=(21, 32))
    bus = DynamixelBus.from_hand(dclaw_spec("XH430-W350"), chain.port(), handle_signals=False,
                                 retries=0)
    with pytest.raises(BusError) as info:
        bus.connect()
    text = str(info.value)
    for i in (10, 11, 12, 20, 22, 30, 31, 50):
        assert f"\n   {i}  XH430-W350   found XM430-W210 (1030)" in text
    assert "\n   21  XH430-W350   no reply" in text and "\n   32  XH430-W350   no reply" in text
    assert not bus.connected and not bus.port.is_open


def test_read_state_units_match_the_physics(dclaw):
    chain, bus = dclaw
    bus.set_torque(True)
    goal = bus.read_state().position.copy()
    goal[[1, 7]] += 0.5  # two middle joints lift against gravity, one the other way:
    goal[4] -= 0.5  # holding currents of both signs
    bus.write_goal_positions(goal)
    bus.sleep(0.15)
    moving = bus.read_state()
    assert np.abs(moving.velocity[[1, 4, 7]]).min() > 0.2  # still on the way
    bus.sleep(1.5)
    s = bus.read_state()  # at rest: what the device latched is what the physics holds now
    assert s.valid.all() and (s.hardware_error == 0).all()
    np.testing.assert_allclose(s.position, true_motor_angles(chain), atol=0.6 * TICK)
    d = chain.drive.state()
    idx = [chain.motors[i].index for i in bus.ids]
    spec = chain.motors[10].spec
    np.testing.assert_allclose(s.velocity, np.array(d.qd)[idx], atol=1.5 * spec.velocity_unit)
    np.testing.assert_allclose(s.current, np.array(d.current)[idx], atol=1.5 * spec.current_unit)
    assert s.current[[1, 7]].max() < -0.01 < 0.01 < s.current[4] or \
        s.current[[1, 7]].min() > 0.01 > -0.01 > s.current[4]
    np.testing.assert_array_equal(s.voltage, 12.0)
    assert np.all((s.temperature >= 25) & (s.temperature < 30))
    # stamped when the motors sampled: the sync read's arrival at the devices, before its
    # ten status packets came back (2.6 ms at 1 Mbit/s)
    assert s.timestamp == pytest.approx(chain._last_rx_time)
    assert 1e-3 < chain.now - s.timestamp < 5e-3


def test_goal_is_present_before_torque_on_even_with_a_stale_goal_register(dclaw):
    chain, bus = dclaw
    for m in chain.motors.values():  # a previous session left far goals in RAM
        m.mem[116:120] = (3000 if m.id % 10 else 1300).to_bytes(4, "little")
    before = bus.read_state().position
    n0 = len(chain.goal_log)
    bus.set_torque(True)
    bus.sleep(0.5)
    after = bus.read_state().position
    assert np.max(np.abs(after - before)) < 10 * TICK  # no jump
    for k, i in enumerate(bus.ids):
        m = chain.motors[i]
        assert m.torque_on and m.get(Reg.BUS_WATCHDOG) == 5  # armed at 100 ms
        _, values = chain.goal_log.positions(i)
        assert abs(values[-1] - before[k] / TICK) <= 2  # the write just before torque on
    assert len(chain.goal_log) - n0 == len(bus.ids)


def test_goals_are_clipped_and_nonfinite_goals_send_nothing(dclaw):
    chain, bus = dclaw
    bus.set_torque(True)
    goal = bus.read_state().position + 5.0  # far beyond every upper limit
    sent = bus.write_goal_positions(goal)
    for k, i in enumerate(bus.ids):
        _, values = chain.goal_log.positions(i)
        assert values[-1] == chain.motors[i].get(Reg.MAX_POSITION_LIMIT)
        assert sent[k] == pytest.approx(values[-1] * TICK)
    n = len(chain.goal_log)
    bad = goal.copy()
    bad[3] = np.nan
    with pytest.raises(CommandError, match="non-finite"):
        bus.write_goal_positions(bad)
    with pytest.raises(CommandError):
        bus.write_goal_positions(goal[:3])
    assert len(chain.goal_log) == n


def test_negative_positions_decode_exactly():
    chain = emulated_dclaw(station="none")
    bus = DynamixelBus.from_hand(chain.hand, chain.port(), handle_signals=False,
                                 position_limits=None)
    with bus:
        bus.sleep(0.5)  # the limp fingers settle
        k = bus.ids.index(11)
        raw = round(bus.read_state().position[k] / TICK)
        for present in (-1, -2, -3000):  # Homing Offset moves Present Position below zero
            bus.write_register(11, Reg.HOMING_OFFSET, present - raw)
            assert chain.motors[11].get(Reg.HOMING_OFFSET) == present - raw
            assert bus.read_register(11, Reg.HOMING_OFFSET) == present - raw
            assert bus.read_state().position[k] == pytest.approx(present * TICK)
            assert bus.read_register(11, Reg.PRESENT_POSITION) == present


def test_alert_is_reported_by_name_and_reboot_clears_it(dclaw):
    chain, bus = dclaw
    bus.set_torque(True)
    chain.inject_hardware_error(21, HardwareError.OVERLOAD)
    s = bus.read_state()
    k = bus.ids.index(21)
    assert s.valid.all()  # the alert bit is not an instruction failure: data is used
    assert s.hardware_error[k] == HardwareError.OVERLOAD
    assert (np.delete(s.hardware_error, k) == 0).all()
    assert bus.faults == {21: ("overload",)}
    assert not chain.motors[21].torque_on  # shutdown (overload is in the default Shutdown mask)
    with pytest.raises(MotorFault) as info:
        bus.set_torque(True, [21])
    assert info.value.motor_id == 21 and info.value.flags == ("overload",)
    bus.reboot(21)
    assert chain.motors[21].hardware_error == 0 and bus.faults == {}
    assert bus.read_state().hardware_error[k] == 0
    bus.set_torque(True, [21])
    assert chain.motors[21].torque_on


def test_dead_motor_is_invalid_not_stale_and_the_others_stay_valid(dclaw):
    chain, bus = dclaw
    first = bus.read_state()
    chain.kill(20)
    for _ in range(5):
        s = bus.read_state()
        k = bus.ids.index(20)
        assert not s.valid[k] and np.isnan(s.position[k]) and s.hardware_error[k] == -1
        assert np.delete(s.valid, k).all()
    assert first.valid[k]
    bus.config = dataclasses.replace(bus.config, max_invalid_reads=8)
    with pytest.raises(BusError, match=r"\[20\].*8 consecutive"):
        for _ in range(10):
            bus.read_state()


def test_torque_off_on_exit_and_on_exceptions():
    chain = emulated_dclaw()
    with pytest.raises(RuntimeError, match="policy blew up"):
        with DynamixelBus.from_hand(chain.hand, chain.port(), handle_signals=False) as bus:
            bus.set_torque(True)
            assert all(m.torque_on for m in chain.motors.values())
            raise RuntimeError("policy blew up")
    assert not any(m.torque_on for m in chain.motors.values())
    assert not bus.connected


def test_position_outside_limits_refuses_torque():
    hand = dclaw_spec()
    chain = emulated_dclaw(hand=hand)
    ff_middle = chain.plant.model.joint("ff_middle").qposadr[0]
    chain.plant.data.qpos[ff_middle] = 1.5  # bent by hand beyond the +-pi/3 limit
    chain.drive._state = None
    with DynamixelBus.from_hand(hand, chain.port(), handle_signals=False) as bus:
        with pytest.raises(PositionOutOfLimits, match="motor 11"):
            bus.set_torque(True)
        assert not any(m.torque_on for m in chain.motors.values())


def test_watchdog_trip_is_detected_and_resumed(dclaw):
    chain, bus = dclaw
    bus.set_torque(True)
    goal = bus.read_state().position
    bus.sleep(1.0)  # sleep() keeps the watchdog fed ...
    assert not [e for e in chain.events if e.kind == "watchdog"]
    bus.port.sleep(0.3)  # ... a silent host does not
    assert {e.motor_id for e in chain.events if e.kind == "watchdog"} == set(bus.ids)
    with pytest.raises(WatchdogTripped):
        bus.write_goal_positions(goal)
    assert bus.watchdog_tripped == set(bus.ids)
    bus.set_torque(True)
    bus.write_goal_positions(goal)
    assert all(m.get(Reg.BUS_WATCHDOG) == 5 for m in chain.motors.values())


def test_fast_read_falls_back_when_the_firmware_lacks_it():
    chain = emulated_dclaw(options=FirmwareOptions(fast_read=False))
    with DynamixelBus.from_hand(chain.hand, chain.port(), handle_signals=False) as bus:
        assert not bus.fast_read
        assert bus.read_state().valid.all()


def test_latency_timer_is_read_and_warned_about(tmp_path):
    chain = emulated_dclaw(station="none", clock="realtime", wire_time=False)
    with chain.serve_pty() as server:
        tty = tmp_path / server.path.rsplit("/", 1)[1]
        tty.mkdir()
        (tty / "latency_timer").write_text("16\n")
        bus = DynamixelBus.from_hand(chain.hand, server.path, handle_signals=False,
                                     fast_read="off")
        bus.sysfs = tmp_path
        with pytest.warns(LatencyWarning, match="16 ms.*echo 1"):
            bus.connect()
        try:
            assert bus.port.latency_ms == 16.0
        finally:
            bus.disconnect()


def test_calibration_recovers_the_true_mounting():
    hand = dclaw_spec()
    rng = np.random.default_rng(5)
    true = dataclasses.replace(hand, joints=tuple(
        dataclasses.replace(j, calibration=Calibration(
            offset=j.calibration.offset + float(rng.uniform(-0.1, 0.1))))
        for j in hand.joints), aux_joints=hand.aux_joints)
    chain = emulated_dclaw(hand=hand, mounting=true)
    with DynamixelBus.from_hand(hand, chain.port(), handle_signals=False,
                                position_limits=None) as bus:
        bus.sleep(0.3)
        m = chain.plant.model
        pose = {j.name: float(chain.plant.qpos[m.jnt_qposadr[m.joint(j.name).id]])
                for j in hand.all_joints}
        new = calibrate_offsets(bus, hand, reference=pose, samples=5)
    for a, b in zip(new.all_joints, true.all_joints, strict=True):
        assert a.calibration.offset == pytest.approx(b.calibration.offset, abs=0.6 * TICK)


def test_4mbps_works_and_a_baud_mismatch_is_reported():
    fast = emulated_dclaw(station="none", baudrate=4_000_000)
    with DynamixelBus.from_hand(fast.hand, fast.port(), handle_signals=False,
                                baudrate=4_000_000) as bus:
        t0 = fast.now
        assert bus.read_state().valid.all()
        # 9 x 21 B fast sync read at 4 Mbps: (23 + 233) bytes x 2.5 us
        assert fast.now - t0 == pytest.approx(256 * 2.5e-6, rel=0.05)
        assert all(m.get(Reg.BAUD_RATE) == 6 for m in fast.motors.values())
    slow = emulated_dclaw(station="none", baudrate=1_000_000)
    bus = DynamixelBus.from_hand(slow.hand, slow.port(), handle_signals=False,
                                 baudrate=4_000_000, retries=0)
    with pytest.raises(BusError, match="at 4000000 bps") as info:
        bus.connect()
    assert str(info.value).count("no reply") == 9


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux pty")
def test_a_missed_reply_names_the_latency_budget_it_waited():
    """A unicast write to a motor that never answers (a raw pty nobody reads): with the driver's
    1 ms budget the error says what the timeouts assumed and what a pty needs (``--latency-ms
    16``); with 16 ms given there is nothing to advise."""
    import tty

    from lowcostdex.hardware.robot.backend import make_dynamixel_bus

    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        for extra, advice in (({}, True), ({"latency_ms": 16}, False)):
            bus = make_dynamixel_bus(dclaw_spec(), os.ttyname(slave), None, retries=0, **extra)
            bus.port.baudrate = 1_000_000
            assert bus.port.openPort()
            try:
                with pytest.raises(BusError, match="no status packet") as err:
                    bus.write_register(10, Reg.TORQUE_ENABLE, 0)
            finally:
                bus.port.closePort()
            assert ("latency timer of 1 ms" in str(err.value)
                    and "--latency-ms 16" in str(err.value)) == advice
    finally:
        os.close(master)
        os.close(slave)
