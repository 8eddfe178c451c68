"""Codec constants no behaviour of the default hand can show at +1, pinned to their sources.

``bench/mutate_constants.py`` (+1 each, the codec group's tests, 5d44167): every Allegro constant
but ``PWM_MAX`` was noticed. ``PWM_MAX`` is the global clamp used until HAND_INFO names the hand's
version; every per-joint clamp of the v4 driver (at most 675) lies below it, so 1200 -> 1201
clamps nothing differently: pinned here to the number of its source instead.
(``dynamixel.protocol.MAX_ID`` is read by no code: listed as equivalent in bench/RESULTS.md.)
"""

from __future__ import annotations

import numpy as np

from lowcostdex.hardware.allegro import protocol as proto


def test_the_global_pwm_clamp_is_the_v4_drivers_12_volt_limit():
    # AllegroHandDrv.cpp (Wonik allegro_hand_ros v4): PWM_LIMIT_GLOBAL_12V 1200, the v4 hand's;
    # PWM_LIMIT_GLOBAL_8V 800 for a v3 hand
    assert proto.PWM_MAX == 1200
    assert proto.torque_scale(4)[1] == proto.PWM_MAX and proto.torque_scale(3)[1] == 800
    # the same driver's per-joint PWM limits (typed as in test_allegro_can: fingers roll, near,
    # middle, far; thumb), all below the global clamp: the default clamps are exactly them
    fingers, thumb = [375, 675, 450, 285], [525, 405, 270, 270]
    np.testing.assert_array_equal(proto.pwm_limits(), fingers * 3 + thumb)
    # a v3 hand's 800 clamp (8 V) leaves them too; a lower global clamp cuts them
    np.testing.assert_array_equal(proto.pwm_limits(800), fingers * 3 + thumb)
    np.testing.assert_array_equal(proto.pwm_limits(400), np.minimum(fingers * 3 + thumb, 400))
