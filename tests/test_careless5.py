"""Issue 12, session 10: a reply is tied to the request that asked for it by default, and
record-log's park waits for a slow robot.

Late replies: Protocol 2.0 status packets carry no sequence number, so a reply later than the
status timeout and the settle wait that lands in the slot of a lost one looked fresh. The driver
reads the 21-byte present block (Present Current 126 .. Present Temperature 146, e-Manual) on a
clean bus and the 27-byte block from Realtime Tick (120) on from the first lost reply: a late reply
to a 21-byte request is refused by its length, one to a 27-byte request by its tick. Checked
against the emulator's record of the bytes each motor sent for each read (``reply_log``) and its
physics, not the driver's belief.

Park: the other fingers of the D'Claw are swung out before an identification log; the park
waited a fixed time and was refused 0.052 rad short of its 0.05 rad tolerance on a loaded host
(a pty-served emulator behind its clock). It now waits while the joints still get closer.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_dxl_soak import check_fresh, replies_since

from lowcostdex.errors import ConfigError
from lowcostdex.hands import dclaw_spec
from lowcostdex.hardware.dynamixel.config import DynamixelConfig
from lowcostdex.hardware.dynamixel.driver import DynamixelBus
from lowcostdex.hardware.emulated.chain import FaultConfig, emulated_dclaw
from lowcostdex.hardware.robot.backend import make_dynamixel_bus, robot_hand
from lowcostdex.hardware.robot.robot import Robot, RobotConfig
from lowcostdex.sim.models.dclaw import build_dclaw

IDS = (10, 11, 12)


def three_motors(**config):
    chain = emulated_dclaw(station="none", rng=np.random.default_rng(3), record_replies=True)
    bus = DynamixelBus(chain.port(), DynamixelConfig(
        ids=IDS, models=("XH430-W350",) * 3, handle_signals=False, fast_read="off",
        read_retries=0, retries=0, max_invalid_reads=None, **config))
    return chain, bus


def fresh_read(chain, bus):
    n0 = chain.instruction_count
    state = bus.read_state()
    check_fresh(bus, state, replies_since(chain, n0))
    return state


def test_a_clean_bus_keeps_the_short_block_and_one_lost_reply_switches_for_good():
    """The simulation's motion bound assumes the 21-byte read (``motion.PRESENT_BLOCK_BYTES``):
    a clean bus keeps it; the first read that loses a reply switches to 27 bytes and stays
    there (the lost reply may come at any time). The read that lost it keeps its other, fresh,
    replies (no earlier read had a reply outstanding)."""
    chain, bus = three_motors()
    with bus:
        for _ in range(200):
            assert fresh_read(chain, bus).valid.all()
        assert (bus._block_addr, bus._block_len) == (126, 21)
        chain.kill(12)  # silent from now on (the last one read: the others' replies are kept)
        state = fresh_read(chain, bus)
        assert state.valid.tolist() == [True, True, False]
        assert (bus._block_addr, bus._block_len) == (120, 27)
        assert np.isfinite(state.position[:2]).all() and np.isnan(state.position[2])
        for _ in range(20):
            assert fresh_read(chain, bus).valid.tolist() == [True, True, False]
        assert bus._block_len == 27


def test_a_late_tick_reply_is_refused_even_before_its_motor_has_a_reference():
    """With the tick block from the start: the very first read's replies all come 17 ms late
    (past the timeout and the 10 ms settle), and torque-on's read of the present positions
    loses every fresh reply, so the late ones land in its slots while no motor has a reply to
    compare their tick with. A request to each went unanswered: refused (the tick kept as an
    untrusted reference), torque stays off; the next clean read is consistent with it and is
    taken, byte for byte what the motors sent for it. (Before: a tick reply without a
    reference passed unchecked, and torque-on would have held the motors at the late
    positions.)"""
    from lowcostdex.hardware.bus import BusError

    chain, bus = three_motors(realtime_tick=True)
    with bus:  # connect reads no block with these settings (fast_read off)
        chain.faults = FaultConfig(late=1.0, late_delay=(0.017, 0.017))
        assert not bus.read_state().valid.any()
        chain.faults = FaultConfig(drop=1.0)
        with pytest.raises(BusError, match="cannot read the present position"):
            bus._present_ticks(IDS)
        assert bus.stats.stale == 3  # they arrived, and were refused
        assert not any(m.torque_on for m in chain.motors.values())
        chain.faults = FaultConfig()
        assert fresh_read(chain, bus).valid.all()
        assert fresh_read(chain, bus).valid.all()
        assert bus.stats.stale == 3


@pytest.mark.parametrize("lateness", [0.017, 0.030, 0.250])
def test_late_replies_after_the_switch_never_pass_as_fresh(lateness):
    """Every reply of one read comes ``lateness`` late, after which 4 reads lose every fresh
    reply: whatever lands in their slots is refused (length, or tick against a trusted
    reference), and the clean reads after are taken; every value the driver returns as valid
    is one the motors sent for that read. Right after the switch no motor has a tick reference
    and requests went unanswered: the first clean read is refused (kept as the reference)."""
    chain, bus = three_motors()
    with bus:
        assert fresh_read(chain, bus).valid.all()
        for k in range(3):  # 1: 21-byte replies late (the switch); 2, 3: 27-byte ones
            chain.faults = FaultConfig(late=1.0, late_delay=(lateness, lateness))
            assert not bus.read_state().valid.any()
            chain.faults = FaultConfig(drop=1.0)
            for _ in range(4):
                bus.port.sleep(lateness / 4)
                assert not fresh_read(chain, bus).valid.any()
            chain.faults = FaultConfig()
            valid = [fresh_read(chain, bus).valid.all() for _ in range(3)]
            assert valid == ([False, True, True] if k == 0 else [True] * 3)
        assert bus._block_len == 27
        assert bus.stats.contaminated + bus.stats.stale >= 3


# ------------------------------------------------------------------------------------------------
# record-log's park: wait while the joints still move toward the pose


def dclaw_robot(motion_scale: float):
    hand = dclaw_spec()
    model = build_dclaw("none", hand).compile()
    chain = emulated_dclaw("none", hand=hand, effects=(), rng=np.random.default_rng(0))
    h = robot_hand(hand, model)
    robot = Robot(h, make_dynamixel_bus(h, chain.port(), model),
                  RobotConfig(control_period=0.02, motion_scale=motion_scale))
    return chain, robot


def joint_position(chain, name: str) -> float:
    m = chain.plant.model
    return float(chain.plant.data.qpos[m.jnt_qposadr[m.joint(name).id]])


def test_the_park_waits_for_joints_that_move_slowly_toward_it():
    """The parked joints' motors limited to 8 x 0.229 rev/min (Profile Velocity, e-Manual
    address 112: 0.19 rad/s) reach -1.0 rad in about 5 s, longer than one 3 s settle: they still
    get closer, so the park waits, and they get there (the emulator's joint angles). Before:
    refused after 3 s, ~0.4 rad short."""
    from lowcostdex.hardware.dynamixel.control_table import Reg
    from lowcostdex.hardware.robot.trace import PARK_TOLERANCE, _park, dclaw_park

    chain, robot = dclaw_robot(motion_scale=10.0)
    park = dclaw_park(robot.hand.joint_names, ("ff_top", "ff_middle", "ff_bottom"))
    assert len(park) == 2 and set(park.values()) == {-1.0}
    with robot:
        for j in robot.hand.joints:
            if j.name in park:
                robot.bus.write_register(j.motor_id, Reg.PROFILE_VELOCITY, 8)
        start = robot.clock.now()
        _park(robot, park)
        took = robot.clock.now() - start
    assert took > 3.0  # longer than one settle: the fixed wait would have refused
    for name, target in park.items():
        assert abs(joint_position(chain, name) - target) < PARK_TOLERANCE


def test_a_park_stopped_short_is_refused_without_waiting_the_bound():
    """A park pose beyond the joint's limit (the Robot clips the goal at the limit): the joint
    stops short and gets no closer, so the park is refused after the settle that shows no
    progress, well before ``PARK_MAX_SECONDS``."""
    from lowcostdex.hardware.robot.trace import PARK_MAX_SECONDS, _park

    chain, robot = dclaw_robot(motion_scale=10.0)
    k = robot.index(("mf_middle",))[0]
    beyond = float(robot.low[k]) - 0.3
    with robot:
        start = robot.clock.now()
        with pytest.raises(ConfigError, match=r"the joints to park did not get there: "
                                              r"\('mf_middle',\) are \[0\.\d+\] rad off"):
            _park(robot, {"mf_middle": beyond})
        took = robot.clock.now() - start
    assert took < PARK_MAX_SECONDS / 3
    assert abs(joint_position(chain, "mf_middle") - robot.low[k]) < 0.05  # it did move there


# ------------------------------------------------------------------------------------------------
# fresh careless calls (session 10): an Allegro spec given to the Dynamixel commands, the cable
# pulled mid-calibrate


@pytest.mark.parametrize("command", [["calibrate", "--port", "emulated", "--yes"],
                                     ["setup-motors", "--port", "emulated"]])
def test_the_allegro_s_spec_given_to_a_dynamixel_command_is_named(command, tmp_path, capsys):
    """Before: 'unknown Dynamixel model 'allegro'; valid choices: ...' (60 model names)."""
    from lowcostdex.cli import USER_ERROR, main
    from lowcostdex.hands import allegro_spec

    spec = tmp_path / "allegro.json"
    spec.write_text(allegro_spec().to_json())
    out = ["--out", str(tmp_path / "cal.json")] if command[0] == "calibrate" else []
    code = main([*command, "--spec", str(spec), *out])
    err = capsys.readouterr().err
    assert code == USER_ERROR and "Traceback" not in err
    assert (f"--spec {spec} is the allegro hand spec, whose motors ('allegro') are not "
            "Dynamixel servos") in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["allegro.json"]


def test_the_cable_pulled_mid_calibrate_is_one_line_and_writes_nothing(tmp_path, capsys,
                                                                       monkeypatch):
    """``calibrate --port PTY --latency-ms 16`` (the option its own timeout message advises;
    before, calibrate refused it) on an emulated D'Claw served on a real pty; the server stops
    after the first read (the adapter unplugged: the pty's reads fail with EIO). Before: a
    pyserial/termios traceback, exit 1, and one 'torque off not confirmed' line per motor. Now:
    one error line naming the port, exit 2, one warning about the torque off, no file."""
    import lowcostdex.hardware.robot.calibration as calibration
    from lowcostdex.cli import USER_ERROR, main

    server = emulated_dclaw("valve", rng=np.random.default_rng(0)).serve_pty()
    real = calibration.calibrate_offsets

    def unplugged_after_one_read(bus, hand, samples):
        assert bus.read_state().valid.all()  # the port works
        server.stop()
        return real(bus, hand, samples=samples)

    monkeypatch.setattr(calibration, "calibrate_offsets", unplugged_after_one_read)
    try:
        code = main(["calibrate", "--port", server.path, "--latency-ms", "16", "--samples",
                     "5", "--yes", "--out", str(tmp_path / "cal.json")])
    finally:
        server.stop()
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == USER_ERROR and "Traceback" not in err, err
    assert len(lines) <= 2, err
    assert lines[-1].startswith(f"lowcostdex calibrate: error: {server.path} stopped working")
    assert "unplugged" in lines[-1]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", [
    ["record-log", "--logs", "1", "--seconds", "0.2", "--out", "logs"],
    ["reset-test", "--trials", "1"],
    ["record-demos", "--episodes", "1", "--out", "demos.h5"]])
def test_the_other_hand_s_spec_on_a_robot_port_is_named_before_the_port_is_used(
        command, tmp_path, capsys, monkeypatch):
    """The Allegro's spec given to a D'Claw command on a serial port (a pty nothing answers
    on): one line naming the spec and the hand it is, exit 2, nothing written, before the port
    is used (nothing answers on it: a message about motors would mean it was)."""
    import os

    from lowcostdex.cli import USER_ERROR, main
    from lowcostdex.hands import allegro_spec

    monkeypatch.chdir(tmp_path)
    (tmp_path / "allegro.json").write_text(allegro_spec().to_json())
    master, slave = os.openpty()
    try:
        code = main([*command, "--port", os.ttyname(slave), "--spec", "allegro.json"])
    finally:
        os.close(master)
        os.close(slave)
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == USER_ERROR and "Traceback" not in err and len(lines) == 1, err
    assert "allegro.json" in lines[0] and "allegro" in lines[0].split("allegro.json", 1)[1], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["allegro.json"]
