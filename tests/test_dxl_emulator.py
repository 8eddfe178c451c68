"""The emulated Dynamixel chain answering the real dynamixel_sdk, instruction by instruction.

Every test drives the SDK's own PacketHandler / Group* classes over the in-process port and checks
the effect on the device side (control table, goal log, physics), not just the SDK's return code.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from dynamixel_sdk import (
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupBulkWrite,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
)

from lowcostdex.hardware.dynamixel.control_table import Reg
from lowcostdex.hardware.dynamixel.protocol import (
    ALERT,
    ErrorNumber,
    HardwareError,
    Instruction,
    parse_packets,
    to_signed,
    to_unsigned,
)
from lowcostdex.hardware.emulated.chain import emulated_bench, emulated_dclaw
from lowcostdex.hardware.emulated.firmware import FirmwareOptions
from lowcostdex.hardware.emulated.goal_log import (
    EVENTS_KEPT,
    GOAL_LOG_CAPACITY,
    REPLIES_KEPT,
    GoalLog,
)

E = ErrorNumber
FINGERS = (10, 11, 12, 20, 21, 22, 30, 31, 32)


def open_port(chain, latency_ms=1.0):
    port = chain.port(latency_ms)
    assert port.openPort()
    return port, PacketHandler(2.0)


@pytest.fixture
def dclaw():
    chain = emulated_dclaw(rng=np.random.default_rng(0))
    port, ph = open_port(chain)
    for i in chain.motors:  # answer at once (the factory 500 us would miss 1 ms-latency timeouts)
        assert ph.write1ByteTxRx(port, i, 9, 0) == (COMM_SUCCESS, 0)
    return chain, port, ph


def present_ticks(chain, motor_id):
    """Present Position the device should report, from the physics and the true mounting."""
    m = chain.motors[motor_id]
    q = chain.plant.qpos[chain.plant.model.jnt_qposadr[chain.plant.model.joint(
        _joint_name(chain, motor_id)).id]]
    return round(m.calibration.to_motor(q) * 4096 / (2 * math.pi) + m.turn_offset + m.homing)


def _joint_name(chain, motor_id):
    return next(j.name for j in chain.hand.all_joints if j.motor_id == motor_id)


def test_ping_unicast_missing_and_broadcast(dclaw):
    chain, port, ph = dclaw
    assert ph.ping(port, 21) == (1000, COMM_SUCCESS, 0)  # XH430-W350
    assert ph.ping(port, 99)[1] == COMM_RX_TIMEOUT
    found, result = ph.broadcastPing(port)
    assert result == COMM_SUCCESS
    assert found == {i: [1000, 52] for i in (*FINGERS, 50)}


def test_read_reports_physics_quantized_to_ticks(dclaw):
    chain, port, ph = dclaw
    port.sleep(0.2)  # let the fingers settle under gravity
    for i in (10, 11, 22, 50):
        value, result, err = ph.read4ByteTxRx(port, i, 132)
        assert (result, err) == (COMM_SUCCESS, 0)
        assert to_signed(value, 4) == present_ticks(chain, i)
    assert ph.read1ByteTxRx(port, 10, 146)[0] == 25  # ambient
    assert ph.read2ByteTxRx(port, 10, 144)[0] == 120  # 12.0 V
    # reading past the end of the table is an access error
    _, result, err = ph.readTxRx(port, 10, 660, 4)  # (the SDK returns CRC bytes as data)
    assert result == COMM_SUCCESS and err == E.ACCESS


def test_write_checks_access_eeprom_length_range_and_limits(dclaw):
    chain, port, ph = dclaw
    m = chain.motors[11]
    assert ph.write1ByteTxRx(port, 11, 65, 1) == (COMM_SUCCESS, 0)  # LED, RAM
    assert m.get(Reg.LED) == 1
    assert ph.write2ByteTxRx(port, 11, 0, 1234)[1] == E.ACCESS  # Model Number is read-only
    assert ph.write1ByteTxRx(port, 11, 11, 7)[1] == E.DATA_RANGE  # no operating mode 7
    assert ph.write2ByteTxRx(port, 11, 116, 100)[1] == E.DATA_LENGTH  # 2 of 4 bytes
    assert ph.write4ByteTxRx(port, 11, 52, 1000) == (COMM_SUCCESS, 0)  # Min Position Limit
    before = len(chain.goal_log)
    assert ph.write4ByteTxRx(port, 11, 116, 900)[1] == E.DATA_LIMIT  # below the new limit
    assert len(chain.goal_log) == before  # refused goals never reach the motor
    assert ph.write1ByteTxRx(port, 11, 64, 1) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 11, 9, 5)[1] == E.ACCESS  # EEPROM locked by torque
    assert m.get(Reg.RETURN_DELAY_TIME) == 0
    assert ph.write4ByteTxRx(port, 11, 116, 2100) == (COMM_SUCCESS, 0)
    times, values = chain.goal_log.positions(11)
    assert values[-1] == 2100 and len(values) == 1


def test_status_return_level_zero_still_executes_silently(dclaw):
    chain, port, ph = dclaw
    assert ph.write1ByteTxRx(port, 12, 68, 0) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 12, 65, 1)[0] == COMM_RX_TIMEOUT  # no status packet ...
    assert chain.motors[12].get(Reg.LED) == 1  # ... but executed
    assert ph.ping(port, 12)[1] == COMM_SUCCESS  # PING always answers
    assert ph.read1ByteTxRx(port, 12, 65)[1] == COMM_RX_TIMEOUT  # level 0: no READ status


def test_reg_write_then_action(dclaw):
    chain, port, ph = dclaw
    ph.write1ByteTxRx(port, 20, 64, 1)
    assert ph.regWriteTxRx(port, 20, 116, 4, list(to_unsigned(1100, 4).to_bytes(4, "little"))
                           ) == (COMM_SUCCESS, 0)
    assert chain.motors[20].get(Reg.REGISTERED_INSTRUCTION) == 1
    assert len(chain.goal_log.positions(20)[1]) == 0  # not applied yet
    assert ph.action(port, 20) == COMM_SUCCESS
    assert chain.goal_log.positions(20)[1].tolist() == [1100]
    assert chain.motors[20].get(Reg.REGISTERED_INSTRUCTION) == 0
    # ACTION with nothing registered: Instruction Error (the SDK does not wait; read the bytes)
    port.sleep(0.001)  # the first ACTION's unread status arrives and is cleared by the next tx
    port.rx_trace.clear()
    ph.action(port, 20)
    port.setPacketTimeoutMillis(5)
    while not port.isPacketTimeout():
        port.readPort(64)
    (status,) = parse_packets(bytes(port.rx_trace))
    assert status.id == 20 and status.error == E.INSTRUCTION


def test_overheating_latch_and_reboot(dclaw):
    chain, port, ph = dclaw
    ph.write1ByteTxRx(port, 21, 9, 3)  # an EEPROM value that must survive the reboot
    ph.write1ByteTxRx(port, 21, 65, 1)  # a RAM value that must not
    ph.write1ByteTxRx(port, 21, 64, 1)
    chain.inject_hardware_error(21, HardwareError.OVERHEATING)
    value, result, err = ph.read1ByteTxRx(port, 21, 64)
    assert (value, result, err) == (0, COMM_SUCCESS, ALERT)  # torque dropped, alert set
    assert ph.read1ByteTxRx(port, 21, 70)[0] == HardwareError.OVERHEATING
    assert not chain.plant.torque_enabled()[chain.motors[21].drive.acts[chain.motors[21].index]]
    assert ph.write1ByteTxRx(port, 21, 64, 1) == (COMM_SUCCESS, ALERT | E.RESULT_FAIL)
    assert [e.kind for e in chain.events if e.motor_id == 21] == ["hardware_error", "shutdown"]
    assert ph.reboot(port, 21) == (COMM_SUCCESS, ALERT)
    assert ph.ping(port, 21)[1] == COMM_RX_TIMEOUT  # booting
    port.sleep(0.1)
    assert ph.read1ByteTxRx(port, 21, 70) == (0, COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 21, 65)[0] == 0  # RAM back to defaults
    assert ph.read1ByteTxRx(port, 21, 9)[0] == 3  # EEPROM kept
    assert ph.write1ByteTxRx(port, 21, 64, 1) == (COMM_SUCCESS, 0)


def test_factory_reset_refused_or_performed():
    chain = emulated_dclaw(station="none")
    port, ph = open_port(chain, latency_ms=16)
    ph.write1ByteTxRx(port, 10, 9, 7)
    assert ph.factoryReset(port, 10, 0x02) == (COMM_SUCCESS, E.RESULT_FAIL)
    assert chain.motors[10].get(Reg.RETURN_DELAY_TIME) == 7
    chain2 = emulated_dclaw(station="none", options=FirmwareOptions(factory_reset="reset"))
    port2, ph2 = open_port(chain2, latency_ms=16)
    ph2.write1ByteTxRx(port2, 10, 9, 7)
    assert ph2.factoryReset(port2, 10, 0x02) == (COMM_SUCCESS, 0)
    port2.sleep(0.1)
    assert chain2.motors[10].get(Reg.RETURN_DELAY_TIME) == 250  # defaults, id and baud kept
    assert ph2.ping(port2, 10)[1] == COMM_SUCCESS


def test_sync_read_replies_in_the_instructions_id_order(dclaw):
    chain, port, ph = dclaw
    gsr = GroupSyncRead(port, ph, 132, 4)
    for i in (30, 10, 20, 50):
        gsr.addParam(i)
    port.rx_trace.clear()
    assert gsr.txRxPacket() == COMM_SUCCESS
    assert [p.id for p in parse_packets(bytes(port.rx_trace))] == [30, 10, 20, 50]
    for i in (30, 10, 20, 50):
        assert to_signed(gsr.getData(i, 132, 4), 4) == present_ticks(chain, i)


def test_fast_sync_read_matches_sync_read_and_can_be_unsupported(dclaw):
    chain, port, ph = dclaw
    gsr = GroupSyncRead(port, ph, 126, 21)
    for i in FINGERS:
        gsr.addParam(i)
    for read in (gsr.txRxPacket, gsr.fastSyncRead):
        port.rx_trace.clear()
        assert read() == COMM_SUCCESS
        for i in FINGERS:
            assert to_signed(gsr.getData(i, 132, 4), 4) == present_ticks(chain, i)
            assert gsr.getData(i, 144, 2) == 120 and gsr.getData(i, 146, 1) == 25
    (pkt,) = parse_packets(bytes(port.rx_trace))  # fast: one packet for all nine
    assert pkt.id == 0xFE and len(port.rx_trace) == 8 + 9 * 25
    old = emulated_dclaw(station="none", options=FirmwareOptions(fast_read=False))
    port2, ph2 = open_port(old, latency_ms=16)
    g2 = GroupSyncRead(port2, ph2, 126, 21)
    g2.addParam(10)
    assert g2.txRxPacket() == COMM_SUCCESS
    assert ph2.syncReadTx(port2, 126, 21, [10], 1, True) == COMM_SUCCESS
    assert ph2.fastSyncReadRx(port2, 0xFE, 25)[1] == COMM_RX_TIMEOUT


def test_sync_write_and_bulk_write_reach_the_motors_without_replies(dclaw):
    chain, port, ph = dclaw
    for i in (10, 11):
        ph.write1ByteTxRx(port, i, 64, 1)
    gsw = GroupSyncWrite(port, ph, 116, 4)
    gsw.addParam(10, list((1100).to_bytes(4, "little")))
    gsw.addParam(11, list((2200).to_bytes(4, "little")))
    port.rx_trace.clear()
    assert gsw.txPacket() == COMM_SUCCESS
    port.sleep(0.01)
    assert port.getBytesAvailable() == 0 and not port.rx_trace  # broadcast: no status
    assert chain.goal_log.positions(10)[1].tolist() == [1100]
    assert chain.goal_log.positions(11)[1].tolist() == [2200]
    gbw = GroupBulkWrite(port, ph)
    gbw.addParam(10, 116, 4, list((1200).to_bytes(4, "little")))
    gbw.addParam(12, 65, 1, [1])
    assert gbw.txPacket() == COMM_SUCCESS
    assert chain.goal_log.positions(10)[1].tolist() == [1100, 1200]
    assert chain.motors[12].get(Reg.LED) == 1


def test_bulk_read_different_items_per_motor(dclaw):
    chain, port, ph = dclaw
    gbr = GroupBulkRead(port, ph)
    gbr.addParam(10, 132, 4)
    gbr.addParam(22, 146, 1)
    gbr.addParam(50, 0, 2)
    assert gbr.txRxPacket() == COMM_SUCCESS
    assert gbr.getData(10, 132, 4) == present_ticks(chain, 10)
    assert gbr.getData(22, 146, 1) == 25
    assert gbr.getData(50, 0, 2) == 1000


def test_position_control_moves_the_joint_and_follows_the_profile(dclaw):
    chain, port, ph = dclaw
    gsr = GroupSyncRead(port, ph, 132, 4)
    gsr.addParam(11)
    ph.write4ByteTxRx(port, 11, 112, 20)  # Profile Velocity 20 x 0.229 rpm = 0.48 rad/s
    ph.write1ByteTxRx(port, 11, 64, 1)
    start = present_ticks(chain, 11)
    ph.write4ByteTxRx(port, 11, 116, start + 400)  # 0.61 rad away
    port.sleep(0.5)
    gsr.txRxPacket()
    mid = to_signed(gsr.getData(11, 132, 4), 4)
    assert 100 < mid - start < 250  # ~0.48 rad/s x 0.5 s = 160 ticks: profile-limited
    port.sleep(2.0)
    gsr.txRxPacket()
    assert abs(to_signed(gsr.getData(11, 132, 4), 4) - (start + 400)) < 25


def test_bus_watchdog_stops_a_silent_host_and_refuses_goals(dclaw):
    chain, port, ph = dclaw
    ph.write4ByteTxRx(port, 12, 112, 10)  # slow profile so the motion is long
    ph.write1ByteTxRx(port, 12, 64, 1)
    ph.write1ByteTxRx(port, 12, 98, 5)  # 100 ms
    start = present_ticks(chain, 12)
    ph.write4ByteTxRx(port, 12, 116, start + 1000)
    t_last = chain.now - 10 * 11 / 1e6  # the write's arrival: its 11-byte status took 110 us
    port.sleep(0.5)  # host silent
    (trip,) = [e for e in chain.events if e.kind == "watchdog"]
    # found at the expiry, not at the next 2.5 ms physics step (a real servo checks within its
    # own ~1 ms control period)
    assert trip.motor_id == 12 and 0.1 <= trip.time - t_last <= 0.1 + 0.001
    a = present_ticks(chain, 12)
    port.sleep(0.3)
    b = present_ticks(chain, 12)
    assert abs(b - a) <= 2 and b - start < 500  # stopped well before the goal
    assert to_signed(ph.read1ByteTxRx(port, 12, 98)[0], 1) == -1
    assert ph.write4ByteTxRx(port, 12, 116, start)[1] == E.DATA_RANGE
    assert ph.write1ByteTxRx(port, 12, 98, 0) == (COMM_SUCCESS, 0)  # clears the error
    assert ph.write4ByteTxRx(port, 12, 116, start) == (COMM_SUCCESS, 0)


def test_torque_on_resets_present_position_into_one_turn():
    chain = emulated_dclaw()
    port, ph = open_port(chain, latency_ms=16)
    valve = chain.plant.model.joint("valve").qposadr[0]
    chain.plant.data.qpos[valve] = 2 * math.pi + 0.5  # turned a full revolution by hand
    chain.drive._state = None
    chain.advance_to(chain.now + 0.01)
    before = to_signed(ph.read4ByteTxRx(port, 50, 132)[0], 4)
    assert before > 4096  # continuous while torque is off
    ph.write1ByteTxRx(port, 50, 64, 1)
    after = to_signed(ph.read4ByteTxRx(port, 50, 132)[0], 4)
    assert 0 <= after < 4096 and abs(before - 4096 - after) <= 3


def test_goal_log_and_negative_homing_offset():
    chain = emulated_bench()
    port, ph = open_port(chain, latency_ms=16)
    ph.write4ByteTxRx(port, 1, 20, to_unsigned(-3000, 4))  # Homing Offset -3000
    pos = to_signed(ph.read4ByteTxRx(port, 1, 132)[0], 4)
    assert pos == present_ticks(chain, 1) and pos < 0


def test_dead_motor_is_silent_and_unpowered(dclaw):
    chain, port, ph = dclaw
    ph.write1ByteTxRx(port, 31, 64, 1)
    chain.kill(31)
    assert ph.ping(port, 31)[1] == COMM_RX_TIMEOUT
    k = chain.motors[31]
    assert not chain.plant.torque_enabled()[k.drive.acts[k.index]]
    gsr = GroupSyncRead(port, ph, 132, 4)
    for i in (30, 31, 32):
        gsr.addParam(i)
    port.rx_trace.clear()
    assert gsr.txRxPacket() == COMM_RX_TIMEOUT
    assert [p.id for p in parse_packets(bytes(port.rx_trace))] == [30, 32]  # the others answer
    chain.revive(31)
    port.sleep(0.1)
    assert ph.ping(port, 31)[1] == COMM_SUCCESS


def test_corrupt_instruction_gets_a_crc_error(dclaw):
    chain, port, ph = dclaw
    from lowcostdex.hardware.dynamixel.protocol import instruction_packet

    pkt = bytearray(instruction_packet(10, Instruction.WRITE, bytes((65, 0, 1))))
    pkt[-1] ^= 0xFF
    port.rx_trace.clear()
    port.clearPort()
    port.writePort(pkt)
    port.setPacketTimeoutMillis(5)
    while not port.isPacketTimeout():
        port.readPort(64)
    (status,) = parse_packets(bytes(port.rx_trace))
    assert status.error == E.CRC and chain.motors[10].get(Reg.LED) == 0


def test_virtual_clock_is_bus_time():
    chain = emulated_bench()
    port, ph = open_port(chain)
    ph.write1ByteTxRx(port, 1, 9, 0)
    t0 = chain.now
    ph.read4ByteTxRx(port, 1, 132)
    # READ: 14 bytes out, 15 back, 10 bits each at 1 Mbps
    assert chain.now - t0 == pytest.approx(29e-5, abs=1e-6)
    assert chain.physics_time <= chain.now < chain.physics_time + 0.0025 + 1e-9


def test_fast_bulk_read(dclaw):
    chain, port, ph = dclaw
    gbr = GroupBulkRead(port, ph)
    gbr.addParam(10, 132, 4)
    gbr.addParam(22, 146, 1)
    gbr.addParam(50, 0, 2)
    port.rx_trace.clear()
    assert gbr.fastBulkRead() == COMM_SUCCESS
    assert [p.id for p in parse_packets(bytes(port.rx_trace))] == [0xFE]  # one packet
    assert gbr.getData(10, 132, 4) == present_ticks(chain, 10)
    assert gbr.getData(22, 146, 1) == 25 and gbr.getData(50, 0, 2) == 1000


def test_present_pwm_current_and_voltage_sag_under_load():
    chain = emulated_dclaw(station="none", supply_resistance=5.0)
    port, ph = open_port(chain, latency_ms=16)
    gsr = GroupSyncRead(port, ph, 124, 23)  # Present PWM .. Present Temperature
    for i in FINGERS:
        gsr.addParam(i)
    gsr.txRxPacket()
    assert all(to_signed(gsr.getData(i, 124, 2), 2) == 0 for i in FINGERS)  # torque off
    assert all(gsr.getData(i, 144, 2) == 120 for i in FINGERS)  # no load, no sag
    for i in (11, 21, 31):  # lift three fingers against gravity, hold
        ph.write1ByteTxRx(port, i, 64, 1)
        goal = present_ticks(chain, i) - 500
        assert ph.write4ByteTxRx(port, i, 116, goal) == (COMM_SUCCESS, 0)
    port.sleep(1.0)
    gsr.txRxPacket()
    d = chain.drive.state()
    total = sum(abs(c) for c in d.current)
    for i in (11, 21, 31):
        pwm = to_signed(gsr.getData(i, 124, 2), 2)
        cur = to_signed(gsr.getData(i, 126, 2), 2)
        assert cur != 0 and np.sign(pwm) == np.sign(cur)  # holding: drive and current agree
        assert abs(pwm) < 885
    volts = {gsr.getData(i, 144, 2) for i in FINGERS}
    assert len(volts) == 1  # one supply for the chain
    (v,) = volts
    assert abs(v - 10 * (12.0 - 5.0 * total)) <= 1 and v < 120  # sags with the total current


def test_effects_of_the_emulated_robot_reach_the_wire():
    from lowcostdex.sim.effects import AppliedEffect

    offset = 40 * 2 * math.pi / 4096
    plain = emulated_dclaw(station="none")
    shifted = emulated_dclaw(station="none", effects=[
        AppliedEffect("position_offset", ("mf_middle",), {"offset": offset})])
    reads = []
    for chain in (plain, shifted):
        port, ph = open_port(chain, latency_ms=16)
        port.sleep(0.2)
        reads.append(to_signed(ph.read4ByteTxRx(port, 21, 132)[0], 4))
    assert reads[1] - reads[0] == 40  # the encoder reports the offset the plant applies


def test_clear_multi_turn_and_unknown_instruction():
    chain = emulated_dclaw()
    port, ph = open_port(chain, latency_ms=16)
    assert ph.write1ByteTxRx(port, 50, 11, 4) == (COMM_SUCCESS, 0)  # extended position mode
    valve = chain.plant.model.joint("valve").qposadr[0]
    chain.plant.data.qpos[valve] = 4 * math.pi + 0.25  # two turns by hand
    chain.drive._state = None
    chain.advance_to(chain.now + 0.005)
    assert to_signed(ph.read4ByteTxRx(port, 50, 132)[0], 4) > 2 * 4096
    assert ph.clearMultiTurn(port, 50) == (COMM_SUCCESS, 0)
    assert 0 <= to_signed(ph.read4ByteTxRx(port, 50, 132)[0], 4) < 4096
    from lowcostdex.hardware.dynamixel.protocol import instruction_packet

    port.rx_trace.clear()
    port.clearPort()
    port.writePort(instruction_packet(50, 0x77))  # no such instruction
    port.setPacketTimeoutMillis(5)
    while not port.isPacketTimeout():
        port.readPort(64)
    (status,) = parse_packets(bytes(port.rx_trace))
    assert status.id == 50 and status.error == E.INSTRUCTION


def test_goal_log_keeps_the_newest_writes_in_bounded_memory_over_a_long_run():
    """A long run's goals (10k sync writes of 9 Goal Positions through the SDK: 90k entries,
    2.5 h of a D'Claw at 10 Hz) leave the device-side goal log at its capacity: memory stops
    growing once it is full, the newest writes are kept in order and every write is counted."""
    chain = emulated_dclaw(rng=np.random.default_rng(0))
    chain.goal_log = GoalLog(capacity=4096)
    port, ph = open_port(chain)
    write = GroupSyncWrite(port, ph, 116, 4)
    sizes = []
    for k in range(10_000):
        write.clearParam()
        for j, i in enumerate(FINGERS):
            write.addParam(i, list((1000 + (k * 9 + j) % 2000).to_bytes(4, "little")))
        assert write.txPacket() == COMM_SUCCESS
        if k in (999, 4999, 9999):
            sizes.append(chain.goal_log.nbytes)
    log = chain.goal_log
    assert log.total == 90_000 and len(log) == 4096 and log.dropped == 90_000 - 4096
    assert sizes[0] == sizes[1] == sizes[2] <= 4096 * 19  # full after 456 writes: flat since
    # the kept entries are the last 4096 writes, oldest first, as the bus sent them
    expected = [1000 + n % 2000 for n in range(90_000 - 4096, 90_000)]
    assert log.value.tolist() == expected
    assert log.motor_id.tolist() == [FINGERS[n % 9] for n in range(90_000 - 4096, 90_000)]
    assert np.all(np.diff(log.time) >= 0) and set(log.reg) == {Reg.GOAL_POSITION.value}
    times, values = log.positions(32)
    kept = range(90_000 - 4096, 90_000)
    assert values.tolist() == [v for n, v in zip(kept, expected, strict=True) if n % 9 == 8]
    assert len(times) == len(values)
    # the default keeps about 3 h of a D'Claw (9 goals at 10 Hz) in under 20 MB
    assert GOAL_LOG_CAPACITY >= 3 * 3600 * 10 * 9 and GOAL_LOG_CAPACITY * 19 < 20e6


def test_events_and_replies_keep_the_newest_in_bounded_memory_over_a_long_run():
    """An hours-long run must not grow the emulator's logs without end: reboots (one event
    each) and sync reads (one recorded reply per motor) through the SDK past the logs' sizes
    leave each log at its size, every entry counted, the newest kept in order, as the wire
    carried them."""
    chain = emulated_dclaw(rng=np.random.default_rng(0), record_replies=True, events_kept=64,
                           replies_kept=500, options=FirmwareOptions(reboot_time=0.002))
    port, ph = open_port(chain)
    for i in chain.motors:  # answer at once, as in the dclaw fixture
        assert ph.write1ByteTxRx(port, i, 9, 0) == (COMM_SUCCESS, 0)
    times = []
    for _ in range(300):  # a motor rebooted again and again: 300 "reboot" events
        times.append(chain.now)
        assert ph.reboot(port, 20)[0] == COMM_SUCCESS
        port.sleep(0.003)
    events = chain.events
    assert (events.total, len(events), events.dropped) == (300, 64, 236)
    assert all(e.kind == "reboot" and e.motor_id == 20 for e in events)
    kept = np.array([e.time for e in events])  # the last 64 reboots, oldest first
    assert np.all(np.array(times[-64:]) <= kept)
    assert np.all(kept < np.array(times[-63:] + [chain.now]))

    before = chain.reply_log.total  # the reboots' status packets
    gsr = GroupSyncRead(port, ph, 132, 4)  # Present Position of the 9 fingers
    for i in FINGERS:
        gsr.addParam(i)
    for _ in range(200):  # 1800 replies
        assert gsr.txRxPacket() == COMM_SUCCESS
    log = chain.reply_log
    assert log.total == before + 1800 and len(log) == 500 and log.dropped == log.total - 500
    # the last 500 replies: 55 whole sync reads and the last 5 of the one before, in wire order
    last = chain.instruction_count
    assert [r[0] for r in log] == [last - (499 - k) // 9 for k in range(500)]
    assert [r[1] for r in log] == [FINGERS[(k + 4) % 9] for k in range(500)]
    assert {r[2] for r in log} == {Instruction.SYNC_READ}
    for r, i in zip(list(log)[-9:], FINGERS, strict=True):  # what the host read last
        assert r[3] == bytes((0,)) + gsr.getData(i, 132, 4).to_bytes(4, "little")
    # the defaults: events a few hundred bytes each, replies ~170 (tuple, header, payload)
    assert EVENTS_KEPT == 10_000 and REPLIES_KEPT == 1 << 16


def _moved_after_a_goal(phase: float, taus: np.ndarray) -> np.ndarray:
    """Bench servo: a goal 260 ticks away arrives ``phase`` (0..1) of the way into a physics step;
    Present Position [ticks from the start] read ``taus`` [s] after the goal arrived."""
    from lowcostdex.hardware.dynamixel.protocol import instruction_packet, le_bytes

    chain = emulated_bench()
    send = lambda inst, params, t: chain.handle(instruction_packet(1, inst, params), t)  # noqa: E731
    send(Instruction.WRITE, le_bytes(64, 2) + b"\x01", 0.0101)  # Torque Enable
    start = chain.motors[1].get(Reg.GOAL_POSITION)
    t0 = 0.2 + phase * chain.plant.model.opt.timestep
    send(Instruction.WRITE, le_bytes(116, 2) + le_bytes(start + 260, 4), t0)  # Goal Position
    moved = []
    for tau in taus:
        (reply,) = send(Instruction.READ, le_bytes(132, 2) + le_bytes(4, 2), t0 + tau)
        (status,) = parse_packets(reply.data)
        moved.append(to_signed(int.from_bytes(status.params[-4:], "little"), 4) - start)
    return np.array(moved)


def test_a_goals_effect_does_not_depend_on_where_in_the_physics_grid_it_lands():
    """Physics is time-invariant: the same goal, read back the same times after it arrived,
    moves the servo the same whatever the phase of its arrival in the emulator's 2.5 ms physics
    grid (a real servo applies and samples within its own ~1 ms control period). Reads sample at
    their arrival (a partial physics step to it), goals act from theirs. Measured 2026-11-26 on
    the grid-only emulator (goal from the step before its arrival, state of the step before the
    read): up to 5 ticks apart across 8 phases; now at most 1 (the encoder's quantization)."""
    taus = np.array([0.004, 0.008, 0.012, 0.016, 0.024, 0.032, 0.048, 0.064])
    moved = np.array([_moved_after_a_goal(p, taus) for p in np.arange(8) / 8])
    assert np.all(moved[:, -1] > 200)  # it moved (260 ticks asked)
    assert np.all(moved.max(0) - moved.min(0) <= 1), moved
