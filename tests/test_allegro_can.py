"""Allegro v4 over CAN: the wire codec, the driver's host-side PD against the emulated hand on
python-can's virtual bus (lock-step virtual clock and real-time threads), and the Robot on top.
What reached the hand is checked on the device side (the emulator's torque log and physics)."""

from __future__ import annotations

import sys
import threading
import time

import mujoco
import numpy as np
import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.hands import allegro_spec
from lowcostdex.hardware.bus import BusError
from lowcostdex.hardware.robot.guards import ThermalConfig
from lowcostdex.hardware.robot.robot import Robot, RobotConfig
from lowcostdex.hardware.robot.safety import UnsafeCommand
from lowcostdex.sim.models.allegro import AllegroPD, build_allegro

can = pytest.importorskip("can", reason="python-can (the 'can' extra) is not installed")

from lowcostdex.hardware.allegro import protocol as proto  # noqa: E402 (needs python-can)
from lowcostdex.hardware.allegro.driver import (  # noqa: E402
    AllegroBus,
    AllegroGains,
    TemperatureSensorWarning,
    pd_torque,
)
from lowcostdex.hardware.allegro.emulator import (  # noqa: E402
    TORQUES_KEPT,
    AllegroThermal,
    EmulatedAllegro,
    emulated_allegro,
)
from lowcostdex.hardware.ringlog import RingLog  # noqa: E402

HAND = allegro_spec()
LOW = np.array([j.low for j in HAND.joints])
HIGH = np.array([j.high for j in HAND.joints])
MID = 0.5 * (LOW + HIGH)


def allegro_model(station: str = "none") -> mujoco.MjModel:
    """The Allegro model (its position actuators are switched off by the emulator)."""
    return build_allegro(station).compile()


STIFF = AllegroGains(kp=3.0, kd=0.08)  # stiffer than the ROS defaults: tight tracking checks


@pytest.fixture
def hand():
    bus, emu, clock = emulated_allegro(allegro_model(), gains=STIFF)
    emu.set_joint_positions(MID)
    yield bus, emu, clock
    bus.disconnect()
    emu.close()


# -- codec ----------------------------------------------------------------------------------------


def test_frame_ids_and_payload_codecs():
    assert proto.frame_id(proto.SET_TORQUE + 2, 0) == 0x188
    assert proto.frame_id(proto.FINGER_POSE + 3, 1) == 0x08D
    assert proto.frame_id(proto.HAND_INFO) == 0x200
    assert proto.split_id(0x18A) == (proto.SET_TORQUE + 2, 2)
    values = (-32768, -1, 0, 32767)
    assert proto.unpack4(proto.pack4(values)) == values
    assert proto.pack4((1, -1, 256, -256)) == bytes([1, 0, 0xFF, 0xFF, 0, 1, 0, 0xFF])
    q = np.array([-1.2, -0.001, 0.5, 1.7])
    back = proto.raw_to_radians(proto.radians_to_raw(q))
    assert np.max(np.abs(back - q)) <= proto.POSITION_UNIT / 2 + 1e-12
    assert proto.POSITION_UNIT == pytest.approx(np.radians(333.3 / 65536))
    assert proto.parse_period(proto.period_message(3, 0, 100).data) == (3, 0, 100)
    status = proto.STATUS_SERVO_ON | proto.STATUS_HIGH_TEMPERATURE
    info = proto.HandInfo(4, 0x0400, True, 31, status)
    back_info = proto.HandInfo.unpack(info.pack())
    assert back_info == info and back_info.servo_on and back_info.faults == ("high_temperature",)


# A real v4 hand on the wire: the candump trace in the docstring of Meta Platforms' MIT-licensed
# Python Allegro driver (quoted in 05-dynamixel-protocol.md section 6), typed in byte by byte.
#   0x80 (info)   can0  200   [7]  02 04 06 04 00 3C 05
#   0x38 (temp)   can0  0E0   [0]  remote request      (x4: 0E0, 0E4, 0E8, 0EC)
#                 can0  0E0   [4]  2B 2A 29 25
#                 can0  0E4   [4]  29 2B 29 27
#                 can0  0E8   [4]  27 27 27 24
#                 can0  0EC   [4]  30 26 24 F6
TRACE_INFO = (0x200, bytes([0x02, 0x04, 0x06, 0x04, 0x00, 0x3C, 0x05]))
TRACE_TEMPERATURE = ((0x0E0, bytes([0x2B, 0x2A, 0x29, 0x25])),
                     (0x0E4, bytes([0x29, 0x2B, 0x29, 0x27])),
                     (0x0E8, bytes([0x27, 0x27, 0x27, 0x24])),
                     (0x0EC, bytes([0x30, 0x26, 0x24, 0xF6])))
# The same bytes read as one unsigned byte per joint [deg C] (the Wonik v4 Linux demo,
# taewookim0812/allegro_hand_linux_v4 cpp/grasp_2204/main.cpp, prints data[0..3] as four values).
# The thumb's last byte 0xF6 = 246 is what the hand sent, and every reference driver decodes it
# unsigned and unchecked: Meta's driver struct.unpack("4B", data), Wonik's v4 ROS 2 SDK
# (Wonikrobotics-git/allegro_hand_ros2 allegro_hand_hardwares/v4/hardware/src/v4_spec.hpp:
# "uint8_t joint_temperature[4]; // Temperature in Celsius"), the Linux demo's printf %d.
TRACE_CELSIUS = (43, 42, 41, 37, 41, 43, 41, 39, 39, 39, 39, 36, 48, 38, 36, 246)


def test_temperature_frames_of_a_real_v4_trace_decode_to_one_byte_per_joint():
    for finger, (can_id, data) in enumerate(TRACE_TEMPERATURE):
        assert proto.split_id(can_id) == (0x38 + finger, 0)
        assert proto.frame_id(proto.TEMPERATURE + finger) == can_id
        assert proto.unpack_temperatures(data) == TRACE_CELSIUS[4 * finger:4 * finger + 4]
        assert proto.pack_temperatures(TRACE_CELSIUS[4 * finger:4 * finger + 4]) == data
    with pytest.raises(ValueError, match="4 temperature bytes"):
        proto.unpack_temperatures(bytes(8))


def test_a_temperature_byte_with_its_high_bit_set_is_a_sensor_fault_not_a_temperature():
    # In the trace 0xF6 sits beside 15 joints at 36..48 deg C (TRACE_CELSIUS) and a palm at
    # 0x3C = 60 deg C, and the same hand's HAND_INFO status 0x05 has the high-temperature fault
    # bit (0x02, every driver) clear: the hand itself did not take 246 deg C (or -10 deg C,
    # the byte read signed) for a joint temperature, so the driver must not either.
    assert TRACE_INFO[1][6] & 0x02 == 0 and TRACE_INFO[1][5] == 60
    assert max(TRACE_CELSIUS[:15]) == 48 and int.from_bytes(b"\xf6", signed=True) == -10
    t = proto.temperatures_celsius(TRACE_CELSIUS)
    np.testing.assert_array_equal(t[:15], TRACE_CELSIUS[:15])
    assert np.isnan(t[15])
    # the boundary: 0x7F is still a number, 0x80 (128 unsigned, -128 signed) is not
    edge = proto.temperatures_celsius([0x00, 0x7F, 0x80, 0xFF])
    np.testing.assert_array_equal(edge[:2], [0.0, 127.0])
    assert np.isnan(edge[2]) and np.isnan(edge[3])


# More of the same trace (Meta's driver docstring): a pose frame of the index finger, the host's
# SET_TORQUE answer, and what the driver sends for SYSTEM_ON (no data) and SET_PERIOD.
TRACE_POSE = (0x080, bytes([0xCA, 0xFD, 0xBD, 0xFE, 0x90, 0xFF, 0xCE, 0xFF]))
TRACE_TORQUE = (0x180, bytes([0x02, 0x00, 0xCB, 0x00, 0x42, 0x00, 0x25, 0x00]))


def test_pose_and_torque_frames_of_the_trace_round_trip_through_si_units():
    can_id, data = TRACE_POSE
    raw = proto.unpack4(data)
    assert raw == (-566, -323, -112, -50)  # int16 little endian, typed from the bytes
    q = proto.raw_to_radians(np.array(raw))
    assert q[0] == pytest.approx(-566 * 333.3 / 65536 * np.pi / 180)
    counts = proto.radians_to_raw(q)
    assert counts.dtype.kind == "i" and tuple(counts) == raw
    msg = proto.pose_message(0, q)  # default device id 0: the traced hand's 0x080
    assert (msg.arbitration_id, bytes(msg.data), msg.is_extended_id) == (can_id, data, False)
    can_id, data = TRACE_TORQUE
    pwm = np.array(proto.unpack4(data))
    assert tuple(pwm) == (2, 203, 66, 37)
    tau = proto.pwm_to_torque(pwm)  # v4: 1200 PWM per N m
    np.testing.assert_allclose(tau, np.array([2, 203, 66, 37]) / 1200.0, rtol=1e-15)
    back = proto.torque_to_pwm(np.concatenate([tau, np.zeros(12)]))
    assert back.dtype.kind == "i" and tuple(back[:4]) == (2, 203, 66, 37)
    msg = proto.torque_message(0, back[:4])
    assert (msg.arbitration_id, bytes(msg.data)) == (can_id, data)


def test_commands_without_data_and_the_period_payloads_of_the_reference_drivers():
    # Meta's driver: set_motor sends SYSTEM_ON/OFF with data=None, standard 11-bit ids
    on = proto.message(proto.SYSTEM_ON)
    assert (on.arbitration_id, bytes(on.data), on.dlc, on.is_extended_id) == (0x100, b"", 0,
                                                                               False)
    # Meta's set_period packs "HHHH" (position, imu, temperature, status): 8 bytes
    assert proto.parse_period(bytes([3, 0, 0, 0, 0, 0, 0, 0])) == (3, 0, 0)
    # Wonik's data_period_t: three uint16 (a short payload reads the missing periods as 0)
    assert proto.parse_period(bytes([0xFF, 0xFF, 0x2C, 0x01])) == (65535, 300, 0)
    assert bytes(proto.period_message(3, 0, 500).data) == bytes([3, 0, 0, 0, 0xF4, 0x01])
    with pytest.raises(ValueError, match="expected 8 data bytes, got 7"):
        proto.unpack4(bytes(7))


def test_frames_of_other_device_ids_and_default_periods():
    # frame id = command << 2 | device id (v4 driver); a hand at device id 2
    q = np.zeros(4)
    assert proto.pose_message(2, q, device_id=2).arbitration_id == (0x20 + 2) << 2 | 2
    assert proto.period_message(3, device_id=1).arbitration_id == 0x81 << 2 | 1
    # the reference drivers' SET_PERIOD {3, 0, 0}: only the pose stream, no IMU, no temperature
    msg = proto.period_message(3)
    assert (msg.arbitration_id, bytes(msg.data)) == (0x204, bytes([3, 0, 0, 0, 0, 0]))
    assert bytes(proto.period_message(40000).data)[:2] == (40000).to_bytes(2, "little")  # uint16
    with pytest.raises(ConfigError, match="A v5 hand speaks a different CAN protocol"):
        proto.torque_scale(5)
    # the driver accepts HAND_INFO frames of 7 or more bytes: an 8th byte does not change them
    assert proto.HandInfo.unpack(TRACE_INFO[1] + b"\x00") == proto.HandInfo.unpack(TRACE_INFO[1])


def test_codec_edges_of_the_vendor_field_types():
    # TEMPERATURE bytes are unsigned deg C: below 0.5 deg C -> 0, above 255 -> 255
    assert proto.pack_temperatures([-5.0, 0.4, 0.6, 300.0]) == bytes([0, 0, 1, 255])
    # HAND_INFO fields are uint16 / uint8 (Wonik's data_info_t): the whole range packs
    info = proto.HandInfo(0xFFFF, 0x8000, True, 200, 0x9F)
    assert info.pack() == bytes([0xFF, 0xFF, 0x00, 0x80, 0x01, 200, 0x9F])
    assert proto.HandInfo.unpack(info.pack()) == info


def test_hand_info_of_a_real_v4_trace():
    can_id, data = TRACE_INFO
    assert proto.split_id(can_id) == (0x80, 0)
    info = proto.HandInfo.unpack(data)
    # the v4 ROS driver prints "hardware version: 0x%02x%02x" from data[1], data[0] and takes
    # data[1] as the hand version (simlabrobotics/allegro_hand_ros_v4 AllegroHandDrv.cpp)
    assert info.hardware_version == 0x0402 and info.major_version == 4
    assert info.firmware_version == 0x0406
    assert not info.left and info.palm_temperature == 0x3C == 60
    # status 0x05 from a hand that was streaming and answering: servo on plus bit 2, which the
    # Wonik drivers call "internal communication fault" and Meta's driver "temperature throttle"
    assert info.status == 0x05 and info.servo_on
    assert info.faults == () and len(info.flags) == 1 and info.flags[0].startswith("bit2")
    assert info.pack() == data


def test_status_bits_one_at_a_time():
    # bit0 servo on, bit1 high-temperature fault (every driver); bit2 / bit3 / bit4 are Meta's
    # joint_temp_throttle / joint_comm_fault / palm_temp_fault (stat & 0x4, 0x8, 0x10), Wonik's
    # v4 data_info_t names only bit2 (internal_communication_fault)
    servo_only = proto.HandInfo(0x0402, 0x0406, False, 30, 0x01)
    assert servo_only.servo_on and servo_only.faults == () and servo_only.flags == ()
    hot = proto.HandInfo(0x0402, 0x0406, False, 30, 0x02)
    assert not hot.servo_on and hot.faults == ("high_temperature",) and hot.flags == ()
    for bit, name in ((0x04, "bit2"), (0x08, "bit3"), (0x10, "bit4")):
        info = proto.HandInfo(0x0402, 0x0406, False, 30, bit)
        assert info.faults == () and len(info.flags) == 1 and info.flags[0].startswith(name)
    assert proto.HandInfo(0x0402, 0x0406, False, 30, 0x20).flags == ()  # no driver names bit5


def test_torque_constant_follows_the_hand_version():
    # AllegroHandDrv.cpp (v4 ROS driver): data[1] == 4 -> _tau_cov_const 1200,
    # PWM_LIMIT_GLOBAL_12V 1200; any other version -> 800 and PWM_LIMIT_GLOBAL_8V 800
    assert proto.torque_scale(proto.HandInfo.unpack(TRACE_INFO[1]).major_version) == (1200, 1200)
    v3 = proto.HandInfo.unpack(bytes([0x02, 0x03, 0x06, 0x04, 0x00, 0x3C, 0x01]))  # data[1] = 3
    assert v3.major_version == 3 and proto.torque_scale(3) == (800, 800)
    tau = np.full(16, 0.1)
    assert proto.torque_to_pwm(tau, *proto.torque_scale(3))[0] == 80
    assert proto.torque_to_pwm(tau, *proto.torque_scale(4))[0] == 120
    with pytest.raises(ConfigError, match="version 5 is not supported"):
        proto.torque_scale(5)


def test_torque_to_pwm_scales_by_1200_and_clamps_per_joint():
    pwm = proto.torque_to_pwm(np.full(16, 10.0))
    np.testing.assert_array_equal(pwm, proto.pwm_limits())
    assert pwm[0] == 375 and pwm[12] == 525 and pwm[15] == 270
    assert proto.torque_to_pwm(np.full(16, -0.1))[1] == -120
    assert pd_torque(np.ones(16), np.zeros(16), np.zeros(16), np.full(16, 2.0), np.zeros(16),
                     0.7)[0] == pytest.approx(0.7)


# simlabrobotics/allegro_hand_ros_v4 @b19b18ea130c4fbe343f2c178eec6cb55186a4ac, joints j00..j33
# (index, middle, ring, thumb), PWM counts per rad and per rad/s; the PD node's torque is
# (k_p err - k_d qdot) / torqueConversion() with torqueConversion() = 1200 on a v4 hand.
# src/allegro_hand_controllers/src/allegro_node_pd.cpp "Default P/D Gains for PD Controller,
# loaded if 'gains_pd.yaml' file is not loaded":
ROS_NODE_KP = [600.0, 600.0, 600.0, 1000.0, 600.0, 600.0, 600.0, 1000.0,
               600.0, 600.0, 600.0, 1000.0, 1000.0, 1000.0, 1000.0, 600.0]
ROS_NODE_KD = [15.0, 20.0, 15.0, 15.0, 15.0, 20.0, 15.0, 15.0,
               15.0, 20.0, 15.0, 15.0, 30.0, 20.0, 20.0, 15.0]
# src/allegro_hand_parameters/gains_pd.yaml, which allegro_hand_controllers/launch/
# allegro_hand.launch always loads (<rosparam file="$(arg PARAMS_DIR)/gains_pd.yaml" .../>):
ROS_YAML_KP = [4000.0] * 16
ROS_YAML_KD = [150.0, 200.0, 150.0, 150.0, 150.0, 200.0, 150.0, 150.0,
               150.0, 200.0, 150.0, 150.0, 300.0, 200.0, 200.0, 150.0]


def test_ros_gain_presets_are_the_v4_packages_and_the_default_differs_only_where_documented():
    names = [j.name for j in HAND.joints]
    for preset, (kp_counts, kd_counts) in ((AllegroGains.ros_launch(), (ROS_YAML_KP, ROS_YAML_KD)),
                                           (AllegroGains.ros_fallback(),
                                            (ROS_NODE_KP, ROS_NODE_KD))):
        kp, kd = preset.arrays()
        np.testing.assert_allclose(kp * 1200, kp_counts, rtol=1e-12)
        np.testing.assert_allclose(kd * 1200, kd_counts, rtol=1e-12)
    launched = build_allegro("none", pd=AllegroPD.ros_launch()).compile()
    # a position actuator: force = kp ctrl - kp q - kv qdot
    np.testing.assert_allclose([launched.actuator(n).gainprm[0] * 1200 for n in names],
                               ROS_YAML_KP, rtol=1e-12)
    np.testing.assert_allclose([-launched.actuator(n).biasprm[2] * 1200 for n in names],
                               ROS_YAML_KD, rtol=1e-12)
    # The default (driver and simulated hand alike) is the fallback in two sets; where it
    # differs from the fallback is said in sim/models/allegro.py and docs/hardware.md.
    model = allegro_model()
    default_kp, default_kd = AllegroGains().arrays()
    np.testing.assert_allclose([model.actuator(n).gainprm[0] for n in names], default_kp)
    np.testing.assert_allclose([-model.actuator(n).biasprm[2] for n in names], default_kd)
    differ_kp = {names[i] for i in np.flatnonzero(default_kp * 1200 != np.array(ROS_NODE_KP))}
    differ_kd = {names[i] for i in np.flatnonzero(default_kd * 1200 != np.array(ROS_NODE_KD))}
    assert differ_kp == {"thumb_3"}
    assert differ_kd == {"index_1", "middle_1", "ring_1", "index_3", "middle_3", "ring_3",
                         "thumb_1", "thumb_2", "thumb_3"}


def test_the_launch_gains_hold_steps_on_the_emulated_hand_tighter_than_the_default():
    """+-0.15 rad steps on all 16 joints, 1.5 s at 333 Hz: the launched (4000 counts/rad) gains
    settle within 0.03 rad without oscillating; the 4-6.7x softer default sags under gravity."""
    goal = MID + np.where(np.arange(16) % 2 == 0, 0.15, -0.15)
    worst = {}
    for name, gains in (("launch", AllegroGains.ros_launch()), ("default", AllegroGains())):
        bus, emu, clock = emulated_allegro(allegro_model(), gains=gains)
        emu.set_joint_positions(MID)
        bus.connect()
        bus.set_torque(True)
        bus.write_goal_positions(goal)
        qs = []
        for _ in range(150):
            clock.sleep(0.01)
            qs.append(emu.qpos.copy())
        bus.disconnect()
        emu.close()
        tail = np.array(qs[-50:])
        worst[name] = np.abs(tail - goal).max()
        assert tail.std(axis=0).max() < 1e-3, name  # settled, no limit cycle
    assert worst["launch"] < 0.03
    assert worst["default"] > 3 * worst["launch"]


# -- driver against the emulated hand (lock-step virtual clock) -----------------------------------


def test_connect_reads_hand_info_and_streams_at_333_hz(hand):
    bus, emu, clock = hand
    bus.connect()
    assert bus.hand_info() is not None and bus.hand_info().major_version == 4
    assert bus.torque_constant == 1200.0
    # the reference drivers' SET_PERIOD {3, 0, 0}: poses streamed, temperatures asked for by RTR
    assert emu.period_ms == (3, 0, 0)
    before = bus.cycles
    clock.sleep(1.0)
    assert 330 <= bus.cycles - before <= 334  # one PD cycle per 3 ms pose set
    s = bus.read_state()
    assert s.valid.all()
    np.testing.assert_allclose(s.position, emu.qpos, atol=proto.POSITION_UNIT)
    assert np.all(s.temperature == pytest.approx(25.0, abs=1.0))


def test_servo_off_until_torque_on_then_pd_tracks_goals(hand):
    bus, emu, clock = hand
    bus.connect()
    clock.sleep(0.1)
    assert not emu.servo_on
    assert all(np.all(tau == 0) for _, tau in emu.torque_log)  # nothing applied while off
    bus.set_torque(True)
    goal = MID + np.where(np.arange(16) % 2 == 0, 0.15, -0.15)
    bus.write_goal_positions(goal)
    clock.sleep(1.5)
    assert emu.servo_on
    np.testing.assert_allclose(emu.qpos, goal, atol=0.05)
    bus.set_torque(False, ids=[0, 1, 2, 3])
    clock.sleep(0.05)
    _, tau = emu.torque_log[-1]
    assert np.all(tau[:4] == 0) and np.any(tau[4:] != 0)  # device side: index finger free


def test_driver_reads_the_trace_temperature_frames(hand):
    bus, emu, clock = hand
    bus.connect()
    for can_id, data in TRACE_TEMPERATURE:  # the hand's frames, byte for byte
        emu.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))
    bus.poll()
    t = bus.read_state().temperature
    np.testing.assert_array_equal(t[:15], TRACE_CELSIUS[:15])
    assert np.isnan(t[15])  # 0xF6: a sensor fault, unknown to the thermal guard, not 246 deg C
    assert bus.temperature_faults == {15: 0xF6}
    bad = bus.bad_frames
    emu.bus.send(can.Message(arbitration_id=0x0E0, data=bytes(8), is_extended_id=False))
    bus.poll()
    assert bus.bad_frames == bad + 1  # an 8-byte frame is not a temperature frame


def test_connect_names_a_joint_whose_temperature_sensor_sends_0xf6(hand):
    bus, emu, clock = hand
    emu.temperature[15] = 0xF6  # the traced thumb's byte, sent as-is by the emulated hand
    with pytest.warns(TemperatureSensorWarning, match=r"thumb\S* reads 0xF6") as record:
        bus.connect()
    assert len(record) == 1
    t = bus.read_state().temperature
    assert np.isnan(t[15]) and np.all(np.isfinite(t[:15]))
    assert bus.temperature_faults == {15: 0xF6}
    emu.temperature[15] = 40.0  # the sensor recovers: the next reply is a temperature again
    clock.sleep(0.15)  # temperatures are asked for every 100 ms
    assert bus.read_state().temperature[15] == 40.0 and bus.temperature_faults == {}


def test_emulated_hand_answers_temperature_requests_with_four_bytes(hand):
    _, emu, _ = hand
    emu.temperature[:] = np.arange(16) + 30.2  # rounded to whole deg C on the wire
    host = can.Bus(interface="virtual", channel=emu.channel)  # a second host on the wire
    try:
        for f in range(4):
            host.send(can.Message(arbitration_id=0x0E0 + 4 * f, is_remote_frame=True,
                                  is_extended_id=False, dlc=0))
        emu.poll()
        replies = [host.recv(timeout=1.0) for _ in range(4)]
    finally:
        host.shutdown()
    for f, msg in enumerate(replies):
        assert msg.arbitration_id == 0x0E0 + 4 * f and not msg.is_remote_frame
        assert msg.dlc == 4 and bytes(msg.data) == bytes(range(30 + 4 * f, 34 + 4 * f))


def test_temperatures_follow_the_hand_through_periodic_requests(hand):
    bus, emu, clock = hand
    bus.connect()  # waits for the first temperatures: the emulated hand streams none (period 0)
    assert emu.period_ms[2] == 0
    np.testing.assert_array_equal(bus.read_state().temperature, np.full(16, 25.0))
    emu.temperature[:] = 55.4
    emu.temperature[15] = 61.0
    clock.sleep(0.25)  # requests every 100 ms
    expected = np.full(16, 55.0)
    expected[15] = 61.0
    np.testing.assert_array_equal(bus.read_state().temperature, expected)


@pytest.mark.parametrize("version, scale", [(0x0402, 1200), (0x0302, 800)])
def test_pwm_on_the_wire_uses_the_hand_versions_torque_constant(version, scale):
    bus, emu, clock = emulated_allegro(allegro_model(), gains=STIFF)
    emu.set_joint_positions(MID)
    emu.info = proto.HandInfo(version, 0x0406, False, 25, 0)
    try:
        bus.connect()
        assert bus.torque_constant == scale
        bus.set_torque(True)
        bus.write_goal_positions(MID + 0.1)
        clock.sleep(0.03)
        tau = bus.read_state().extra["torque"]
        assert np.any(np.abs(tau) > 0.05)
        # device side: the PWM counts the hand holds are tau * (its version's constant) ...
        lim = proto.pwm_limits(scale)
        np.testing.assert_array_equal(emu.pwm, np.clip(np.rint(tau * scale), -lim, lim))
        # ... so the torque the hand applies is the one the PD asked for, on a v3 hand too
        np.testing.assert_allclose(emu.applied_torque(), tau, atol=0.5 / scale)
    finally:
        bus.disconnect()
        emu.close()


def test_connect_refuses_a_hand_version_it_has_no_torque_constant_for():
    bus, emu, clock = emulated_allegro(allegro_model())
    emu.info = proto.HandInfo(0x0502, 0x0100, False, 25, 0)  # a v5 hand's major version
    try:
        with pytest.raises(ConfigError, match="version 5 is not supported"):
            bus.connect()
        emu.poll()
        assert not emu.servo_on and np.all(emu.pwm == 0)
    finally:
        bus.disconnect()
        emu.close()


def test_missing_pose_stream_marks_joints_invalid_and_robot_raises(hand):
    bus, emu, clock = hand
    robot = Robot(HAND, bus, RobotConfig(control_period=0.01, max_invalid_reads=2))
    robot.connect()
    emu.period_ms = (0, 0, 0)  # the hand stops streaming (cable pulled)
    clock.sleep(0.1)
    assert not bus.read_state().valid.any()
    with pytest.raises(BusError, match="consecutive reads"):
        for _ in range(4):
            robot.read()


def test_connect_without_a_hand_fails_bounded():
    channel = f"no-hand-{time.monotonic_ns()}"
    from lowcostdex.hardware.allegro.emulator import LockstepClock

    emu = EmulatedAllegro(allegro_model(), channel=channel)
    emu.device_id = 3  # answers nothing addressed to device 0
    clock = LockstepClock(emu)
    bus = AllegroBus(can.Bus(interface="virtual", channel=channel), threaded=False, clock=clock,
                     own_bus=True, timeout=0.2)
    clock.attach(bus)
    t0 = time.monotonic()
    with pytest.raises(BusError, match="no HAND_INFO"):
        bus.connect()
    assert time.monotonic() - t0 < 5.0
    bus.disconnect()
    emu.close()


# -- the Robot on the Allegro ----------------------------------------------------------------------


def test_robot_clips_goals_to_limits_and_rejects_nan(hand):
    bus, emu, clock = hand
    config = RobotConfig(control_period=0.02, motion_reference="goal")  # soft PD: rate limit
    with Robot(HAND, bus, config) as robot:
        robot.torque(True)
        sent = [robot.step(HIGH + 1.0) for _ in range(100)]
        assert np.all(robot.last_sent <= HIGH + 1e-12)
        assert np.all(bus._goal <= HIGH + 1e-12)  # the PD's goal stops at the limits ...
        np.testing.assert_allclose(bus._goal[:12], HIGH[:12])  # ... (thumb: held by the lead
        # bound, blocked by the curled fingers)
        assert np.all(emu.qpos <= HIGH + 0.03)  # device side: never driven past the limits
        assert robot.metrics.limit_clips > 0 and len(sent) == 100
        goal_before = bus._goal.copy()
        n_sent = robot.metrics.sent
        bad = MID.copy()
        bad[5] = np.nan
        with pytest.raises(UnsafeCommand, match="middle_1=nan"):
            robot.send(bad)
        assert robot.metrics.sent == n_sent and robot.metrics.rejected == 1
        np.testing.assert_array_equal(bus._goal, goal_before)  # nothing reached the PD
    emu.poll()  # the hand handles the frames on the wire
    assert not emu.servo_on  # leaving the block turned the servos off


def stall_thumb_until_a_pause_is_pending(robot, emu, steps=600):
    """Torque on, the thumb base driven at a hard stop put at its present angle (it pushes
    against it with all it has) until the thermal guard asks for a pause."""
    robot.torque(True)
    goal = MID.copy()
    goal[12] = HIGH[12]
    emu.plant.model.jnt_range[emu.plant.model.joint("thumb_0").id] = [0.0, MID[12]]
    for _ in range(steps):
        robot.step(goal)
        if robot.thermal.pause_pending:
            break
    assert robot.thermal.pause_pending


def test_thermal_guard_relaxes_a_stalled_joint_before_the_firmware_fault():
    # a small heat capacity: minutes of heating and cooling in seconds of emulated time
    bus, emu, clock = emulated_allegro(allegro_model(), gains=AllegroGains(kp=5.0),
                                       thermal=AllegroThermal(capacitance=1.0))
    emu.set_joint_positions(MID)
    with Robot(HAND, bus, RobotConfig(control_period=0.1)) as robot:
        stall_thumb_until_a_pause_is_pending(robot, emu)
        assert not emu.fault  # the firmware limit was never reached
        record = robot.pause_if_hot()
        assert record is not None and record.hottest == "thumb_0"
        assert np.max(emu.temperature) < robot.thermal.resume
    emu.close()


def test_a_thermal_pause_ends_beside_a_joint_whose_sensor_sends_0xf6():
    """The traced thumb's 0xF6 (a sensor fault, read NaN) never reads cool: the pause must leave
    that joint out of its cool-down test (it stays flagged) or it only ends by ThermalTimeout.
    The rest of the hand is checked on the device: every other winding is below resume."""
    bus, emu, clock = emulated_allegro(allegro_model(), gains=AllegroGains(kp=5.0),
                                       thermal=AllegroThermal(capacitance=1.0))
    emu.set_joint_positions(MID)
    emu.sensor_fault[15] = 0xF6  # thumb_3's sensor, as in Meta's trace
    config = RobotConfig(control_period=0.1, thermal=ThermalConfig(max_pause=60.0))
    with pytest.warns(TemperatureSensorWarning), Robot(HAND, bus, config) as robot:
        stall_thumb_until_a_pause_is_pending(robot, emu)
        record = robot.pause_if_hot()  # raised ThermalTimeout after 60 s before the change
        assert record is not None and record.hottest == "thumb_0"
        assert record.duration < 60.0 and record.end_max < robot.thermal.resume
        assert np.max(np.delete(emu.temperature, 15)) < robot.thermal.resume  # device side
        flagged = robot.telemetry()["temperature_faults"]
        assert [robot.joint_names[i] for i in np.flatnonzero(flagged)] == ["thumb_3"]
        emu.sensor_fault.clear()  # the sensor recovers: its joint counts again ...
        emu.temperature[15] = robot.thermal.resume + 5.0
        clock.sleep(0.25)
        state = robot.read()
        assert not state.temperature_fault[15] and not robot.thermal.cooled(state.temperature)
        assert robot.telemetry()["temperature_faults"][15]  # ... and stays on the record
    emu.close()


# -- real time: threaded driver against the hand served from a thread ----------------------------


def test_threaded_driver_against_a_real_time_emulated_hand():
    channel = f"rt-{time.monotonic_ns()}"
    emu = EmulatedAllegro(allegro_model(), channel=channel)
    emu.set_joint_positions(MID)
    stop = threading.Event()
    server = threading.Thread(target=emu.serve, args=(stop,), daemon=True)
    server.start()
    bus = AllegroBus(can.Bus(interface="virtual", channel=channel), threaded=True, own_bus=True)
    try:
        bus.connect()
        bus.set_torque(True)
        time.sleep(0.3)
        assert bus.cycles >= 30  # 333 Hz nominal; a loaded CI machine still manages this
        assert bus.read_state().valid.all()
    finally:
        bus.disconnect()
        stop.set()
        server.join(2.0)
        emu.close()


# -- issue 19: codec edges and the constants the driver and the emulator share, from the reference
# (05-dynamixel-protocol.md section 6: the v4 drivers' command table and frame ids)

def test_command_bytes_and_frame_ids_typed_from_the_reference():
    assert (proto.SYSTEM_ON, proto.SYSTEM_OFF) == (0x40, 0x41)
    assert [proto.frame_id(proto.SET_TORQUE + f) for f in range(4)] == [0x180, 0x184, 0x188,
                                                                        0x18C]
    assert [proto.frame_id(proto.FINGER_POSE + f) for f in range(4)] == [0x080, 0x084, 0x088,
                                                                         0x08C]
    assert proto.frame_id(proto.HAND_INFO) == 0x200
    assert (proto.SET_PERIOD, proto.CONFIG, proto.SERIAL, proto.IMU) == (0x81, 0x68, 0x88, 0x30)
    assert (proto.SET_POSE, proto.TEMPERATURE) == (0xE0, 0x38)
    # every device id 0..3 lands in the two low bits and comes back out; 4 is refused
    for dev in range(4):
        assert proto.frame_id(proto.SET_TORQUE + 1, dev) == 0x184 | dev
        assert proto.split_id(0x184 | dev) == (0x61, dev)
        msg = proto.torque_message(1, np.zeros(4, int), device_id=dev)
        assert msg.arbitration_id == 0x184 | dev and not msg.is_extended_id and msg.dlc == 8
    with pytest.raises(ConfigError, match="outside 0..3"):
        proto.frame_id(proto.SET_TORQUE, 4)
    with pytest.raises(ConfigError):
        proto.frame_id(proto.SET_TORQUE, -1)


def test_negative_torques_clamp_per_joint_and_int16_saturates():
    # the v4 driver's per-joint PWM limits, typed: fingers (375, 675, 450, 285), thumb
    # (525, 405, 270, 270)
    limits = [375, 675, 450, 285] * 3 + [525, 405, 270, 270]
    np.testing.assert_array_equal(proto.torque_to_pwm(np.full(16, -10.0)),
                                  [-x for x in limits])
    # just inside a limit is kept: 0.3 N m * 1200 = 360 < 375 on joint 0, -360 too
    assert proto.torque_to_pwm(np.full(16, -0.3))[0] == -360
    # int16 payloads saturate instead of wrapping: 32767 = FF 7F, -32768 = 00 80 (little endian)
    assert proto.pack4((40000, -40000, 32768, -32769)) == bytes(
        [0xFF, 0x7F, 0x00, 0x80, 0xFF, 0x7F, 0x00, 0x80])
    raw = proto.radians_to_raw(np.array([100.0, -100.0, 0.0, 1e-9]))
    assert raw.tolist() == [32767, -32768, 0, 0]
    # one count is 333.3 / 65536 deg: 1 deg is 196.6 -> 197 counts
    assert proto.radians_to_raw(np.radians([1.0]))[0] == 197


def test_torque_log_keeps_the_newest_cycles_in_bounded_memory(hand):
    """An hours-long run must not grow the hand's torque log without end (one entry per 3 ms
    cycle: ~1 GB in 3 h): past its size the log keeps the newest cycles, in order, every cycle
    counted, and the newest entry is the torque the hand applies now."""
    bus, emu, clock = hand
    emu.torque_log = RingLog(256)
    bus.connect()
    bus.set_torque(True)
    bus.write_goal_positions(MID + 0.1)
    clock.sleep(3.0)  # ~1000 cycles
    log = emu.torque_log
    assert log.total >= 990 and len(log) == 256 and log.dropped == log.total - 256
    times = np.array([t for t, _ in log])
    assert np.all(np.diff(times) > 0) and emu.time - times[-1] <= 0.0051  # the newest cycles
    now = emu.applied_torque()
    emu.cycle()  # one more cycle: its entry is the torque applied in it
    assert log.total == log.dropped + 256 and np.any(now != 0)
    np.testing.assert_array_equal(log[-1][1], now)
    # the default: 2^16 cycles (3.3 min) of a (time, 16 torques) entry each
    t, tau = log[-1]
    entry = sys.getsizeof(log[-1]) + sys.getsizeof(t) + sys.getsizeof(tau)
    assert TORQUES_KEPT == 1 << 16 and TORQUES_KEPT * entry < 25e6
