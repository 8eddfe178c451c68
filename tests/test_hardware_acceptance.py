"""A short, safe acceptance test of a real D'Claw, and the same test on the emulated one.

    pytest -m hardware --dxl-port /dev/ttyUSB0

runs every test here twice: on the emulated D'Claw through the real dynamixel_sdk code path (an
in-process port on the emulator's virtual clock: what CI runs, immune to a loaded machine) and on
the hand at ``--dxl-port`` (skipped, with this reason, when the option is not given). What it does on
the hand: a scan, units read back within physical ranges, one small motion of one joint within
its limits, and a bus-watchdog trip and recovery. Keep the hand clear of the valve and people.
"""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.hands import dclaw_spec
from lowcostdex.hardware.bus import WatchdogTripped
from lowcostdex.hardware.dynamixel.driver import DynamixelBus
from lowcostdex.hardware.dynamixel.scan import scan
from lowcostdex.hardware.emulated.chain import emulated_dclaw

pytestmark = pytest.mark.hardware

FINGER_IDS = {10, 11, 12, 20, 21, 22, 30, 31, 32}
"""D'Claw finger motor ids (ROBEL's numbering: finger x 10 + joint)."""


@pytest.fixture(params=["emulated", "real"])
def port(request):
    if request.param == "real":
        path = request.config.getoption("--dxl-port")
        if not path:
            pytest.skip("no --dxl-port: the real-hand acceptance runs with "
                        "`pytest -m hardware --dxl-port /dev/ttyUSB0`")
        yield path
        return
    chain = emulated_dclaw(rng=np.random.default_rng(0))
    yield chain.port()


def test_scan_finds_the_fingers_healthy(port):
    found = {m.motor_id: m for m in scan(port, ids=sorted(FINGER_IDS))}
    assert set(found) == FINGER_IDS, f"missing motors: {sorted(FINGER_IDS - set(found))}"
    for m in found.values():
        assert m.model.startswith(("XH430", "XM430")), (m.motor_id, m.model)
        assert not m.hardware_error, (m.motor_id, m.hardware_error)
        assert m.firmware is not None and m.firmware >= 38, "bus watchdog needs firmware >= 38"
        # a 12 V supply (the D'Claw's) within the XH430's operating range 10-14.8 V
        assert 10.0 <= m.voltage <= 14.8, (m.motor_id, m.voltage)
        assert 5 <= m.temperature <= 65, (m.motor_id, m.temperature)


def test_units_read_back_within_physical_ranges(port):
    hand = dclaw_spec()
    with DynamixelBus.from_hand(hand, port, handle_signals=False, latency_ms=16) as bus:
        s = bus.read_state()
    assert s.valid.all()
    by_id = {j.motor_id: j for j in hand.all_joints}
    for k, motor_id in enumerate(bus.ids):
        j = by_id[motor_id]
        q = j.calibration.to_joint(float(s.position[k]))
        # at rest, torque off: inside the joint's limits (a few degrees of slack), not moving
        assert j.low - 0.1 <= q <= j.high + 0.1, (j.name, q)
        assert abs(s.velocity[k]) < 0.5, (j.name, s.velocity[k])
        assert abs(s.current[k]) < 1.0, (j.name, s.current[k])      # amperes, not counts
        assert 10.0 <= s.voltage[k] <= 14.8 and 5 <= s.temperature[k] <= 65


def test_one_small_motion_within_the_limits(port):
    hand = dclaw_spec()
    with DynamixelBus.from_hand(hand, port, handle_signals=False, latency_ms=16) as bus:
        bus.set_torque(True)
        start = bus.read_state().position
        goal = start.copy()
        k = list(bus.ids).index(11)          # first finger's middle joint, swung outwards
        goal[k] -= 0.15
        bus.write_goal_positions(goal)
        bus.sleep(0.8)                       # keeps the watchdog fed while it moves
        moved = bus.read_state().position
        bus.set_torque(False)
    assert moved[k] - start[k] == pytest.approx(-0.15, abs=0.03)
    others = np.delete(np.abs(moved - start), k)
    assert others.max() < 0.05                # nothing else moved


def test_the_bus_watchdog_stops_a_silent_host_and_recovers(port):
    hand = dclaw_spec()
    with DynamixelBus.from_hand(hand, port, handle_signals=False, latency_ms=16) as bus:
        bus.set_torque(True)
        hold = bus.read_state().position
        bus.sleep(0.5)                       # fed: no trip
        bus.write_goal_positions(hold)
        bus.port.sleep(0.4)                  # silent for 4x the 100 ms watchdog
        with pytest.raises(WatchdogTripped):
            bus.write_goal_positions(hold)
        bus.set_torque(True)                 # re-armed from where they stopped
        bus.write_goal_positions(hold)
        bus.set_torque(False)
