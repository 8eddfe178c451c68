"""Codec constants no behaviour of the default hand can show at +1, pinned to their sources.

``bench/mutate_constants.py`` (+1 each, the codec group's tests, 5d44167): every Allegro constant
but ``PWM_MAX`` was noticed. ``PWM_MAX`` is the global clamp used until HAND_INFO names the hand's
version; every per-joint clamp of the v4 driver (at most 675) lies below it, so 1200 -> 1201
clamps nothing differently: pinned here to the number of its source instead.
The Dynamixel constants are pinned to dynamixel_sdk (the reference driver) and the e-Manual.
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


# ---- Dynamixel Protocol 2.0: the reference driver's numbers (dynamixel_sdk, a core dependency) --

def test_instruction_codes_are_dynamixel_sdks():
    """Every instruction of ``Instruction`` is dynamixel_sdk's ``INST_*`` (robotis_def.py): the
    driver sends the SDK's codes, the emulator answers ours; a typo on one side is the other
    side's truth. (CLEAR 0x10 and the FAST_* codes were noticed by no test at +1 before.)"""
    from dynamixel_sdk import robotis_def as sdk

    from lowcostdex.hardware.dynamixel.protocol import Instruction
    for inst in Instruction:
        assert int(inst) == getattr(sdk, f"INST_{inst.name}"), inst.name
    assert {f"INST_{i.name}" for i in Instruction} == {k for k in vars(sdk)
                                                       if k.startswith("INST_")}


def test_ids_error_numbers_and_limits_are_dynamixel_sdks():
    from dynamixel_sdk import protocol2_packet_handler as ph
    from dynamixel_sdk import robotis_def as sdk

    from lowcostdex.hardware.dynamixel import protocol as p
    assert (p.BROADCAST_ID, p.MAX_ID, p.STATUS) == (sdk.BROADCAST_ID, sdk.MAX_ID, sdk.INST_STATUS)
    assert p.MAX_LENGTH == ph.RXPACKET_MAX_LEN and p.ALERT == ph.ERRBIT_ALERT
    for e in p.ErrorNumber:
        if e.name != "NONE":
            assert int(e) == getattr(ph, f"ERRNUM_{e.name}"), e.name
    assert p.ErrorNumber.NONE == 0


def test_hardware_error_bits_and_baud_codes_are_the_e_manuals():
    from lowcostdex.hardware.dynamixel import protocol as p

    # ROBOTIS e-Manual, X-series control table: Hardware Error Status (70) bit 0 input voltage,
    # bit 2 overheating, bit 3 motor encoder, bit 4 electrical shock, bit 5 overload
    assert {h.name: int(h) for h in p.HardwareError} == {
        "INPUT_VOLTAGE": 1 << 0, "OVERHEATING": 1 << 2, "MOTOR_ENCODER": 1 << 3,
        "ELECTRICAL_SHOCK": 1 << 4, "OVERLOAD": 1 << 5}
    # Baud Rate (8): 0 9600, 1 57600, 2 115200, 3 1M, 4 2M, 5 3M, 6 4M, 7 4.5M bps
    assert p.BAUD_CODES == {0: 9600, 1: 57_600, 2: 115_200, 3: 1_000_000, 4: 2_000_000,
                            5: 3_000_000, 6: 4_000_000, 7: 4_500_000}
    assert [p.baud_code(r) for r in (9600, 57_600, 1_000_000, 4_500_000)] == [0, 1, 3, 7]
