"""The motion bound's clean-bus time and narrowing (lowcostdex.motion), numbers written out.

Truth from outside the module: Dynamixel Protocol 2.0 packet layouts (ROBOTIS e-Manual: a status
packet is 11 bytes + its data; a fast sync read's reply is one packet of 8 bytes + 4 + data per
id; a sync write is 14 bytes + (1 + data) per id), 8N1 framing (10 bits a byte), the XH430-W350's
no-load speed (e-Manual: 30 rev/min at 12 V) and ROBEL's D'Claw bound (2 pi / 3 rad/s).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex import motion
from lowcostdex.hands import allegro_spec, dclaw_spec


def test_read_reply_time_plain_and_fast_sync_read_from_the_packet_layouts():
    # 9 motors, 21 bytes each, 1 Mbit/s: plain sync read = 9 status packets of 11 + 21 bytes;
    # fast sync read = one packet of 8 bytes + 9 x (4 + 21)
    assert motion.read_reply_time(9, 21, 1e6, fast=False) == pytest.approx(10 * 9 * 32 / 1e6)
    assert motion.read_reply_time(9, 21, 1e6, fast=True) == pytest.approx(10 * 233 / 1e6)
    # another count, length and rate: 3 motors x 4 bytes at 57600 bit/s
    assert motion.read_reply_time(3, 4, 57600.0, fast=False) == pytest.approx(
        10 * 3 * 15 / 57600)
    assert motion.read_reply_time(3, 4, 57600.0, fast=True) == pytest.approx(
        10 * (8 + 3 * 8) / 57600)


def test_clean_in_flight_is_the_fast_read_reply_plus_the_goal_write_and_a_usb_frame():
    # the D'Claw: 10 motors read (9 joints + the valve), 9 goals written, 1 Mbit/s:
    # 2.58 ms (8 + 10 x 25 bytes) + 0.59 ms (14 + 9 x 5 bytes) + 1 ms (one USB frame)
    assert motion.clean_in_flight(10, 9) == pytest.approx(2.58e-3 + 0.59e-3 + 1e-3, abs=1e-12)
    # a 4-byte read of 2 motors, 1 goal, at 115200 bit/s
    expected = 10 * (8 + 2 * 8) / 115200 + 10 * (14 + 5) / 115200 + 1e-3
    assert motion.clean_in_flight(2, 1, length=4, baudrate=115200.0) == pytest.approx(expected)


def test_dclaw_motion_bound_is_robels_narrowed_by_the_clean_bus_time():
    hand = dclaw_spec()
    speed = 1.5 * 30 * 2 * math.pi / 60  # 1.5 x the XH430-W350's no-load speed [rad/s]
    for period in (0.1, 0.05):
        expected = 2 * math.pi / 3 * period - speed * 4.17e-3
        np.testing.assert_allclose(motion.motion_bound(hand, period, 10), np.full(9, expected),
                                   atol=1e-9)
    np.testing.assert_allclose(motion.motion_bound(hand, 0.1, 10), 0.18979, atol=1e-5)


def test_a_hand_without_a_motor_spec_is_not_narrowed():
    # the Allegro's motors have no spec (no speed): the bound is max_velocity x period
    hand = allegro_spec()
    np.testing.assert_allclose(motion.motion_bound(hand, 0.05, 16), np.full(16, math.pi * 0.05))
    np.testing.assert_array_equal(motion.joint_speeds(hand), np.zeros(16))


def test_in_flight_step_narrows_by_speed_times_time_and_never_below_zero():
    np.testing.assert_allclose(
        motion.in_flight_step(np.array([0.2, 0.2, 0.01]), np.array([3.0, 0.0, 3.0]), 0.01),
        [0.17, 0.2, 0.0])
    # a negative elapsed time (clock skew) does not widen the bound
    np.testing.assert_allclose(motion.in_flight_step(np.array([0.2]), np.array([3.0]), -1.0),
                               [0.2])
