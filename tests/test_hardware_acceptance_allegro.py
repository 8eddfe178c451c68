"""A short, safe acceptance test of a real Allegro hand v4, and the same test on the emulated one.

    pytest -m hardware --can-channel can0

runs every test twice: on the emulated Allegro (python-can's virtual bus, lock-step clock: what CI
runs) and on the hand on ``--can-channel`` over socketcan (skipped, with this reason, when the
option is not given). On the hand: its identity and version, temperatures arriving, positions
within the joint limits, and one 0.1 rad motion of the index finger's first flexion joint.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from lowcostdex.hands import allegro_spec
from lowcostdex.sim.models.allegro import build_allegro

can = pytest.importorskip("can", reason="python-can (the 'can' extra) is not installed")

from lowcostdex.hardware.allegro.driver import AllegroBus, AllegroGains  # noqa: E402 (python-can)
from lowcostdex.hardware.allegro.emulator import emulated_allegro  # noqa: E402

pytestmark = pytest.mark.hardware
HAND = allegro_spec()
LOW = np.array([j.low for j in HAND.joints])
HIGH = np.array([j.high for j in HAND.joints])
GAINS = AllegroGains(kp=3.0, kd=0.08)
"""Host-side PD gains [N m/rad, N m s/rad] firm enough to track 0.1 rad against gravity and
friction (0.3 N m at 0.1 rad error, well inside the per-joint PWM clamps)."""


@pytest.fixture(params=["emulated", "real"])
def allegro(request):
    """(bus, sleep) of a connected hand."""
    if request.param == "real":
        channel = request.config.getoption("--can-channel")
        if not channel:
            pytest.skip("no --can-channel: the real-hand acceptance runs with "
                        "`pytest -m hardware --can-channel can0`")
        bus = AllegroBus(interface="socketcan", channel=channel, threaded=True, gains=GAINS)
        sleep = time.sleep
        emu = None
    else:
        bus, emu, clock = emulated_allegro(build_allegro("none").compile(), gains=GAINS)
        emu.set_joint_positions(0.5 * (LOW + HIGH))
        sleep = clock.sleep
    bus.connect()
    try:
        yield bus, sleep
    finally:
        bus.disconnect()
        if emu is not None:
            emu.close()


def test_identity_temperatures_and_positions(allegro):
    bus, sleep = allegro
    info = bus.hand_info()
    assert info is not None and info.major_version in (3, 4), info
    assert bus.torque_constant == {4: 1200.0, 3: 800.0}[info.major_version]
    sleep(0.5)                                # temperatures are asked for every 100 ms
    s = bus.read_state()
    assert s.valid.all()
    assert np.all((s.temperature >= 5) & (s.temperature <= 65)), s.temperature
    assert np.all((s.position >= LOW - 0.1) & (s.position <= HIGH + 0.1)), s.position


def test_one_small_motion(allegro):
    bus, sleep = allegro
    sleep(0.1)
    start = bus.read_state().position
    goal = start.copy()
    goal[1] = np.clip(start[1] + 0.1, LOW[1], HIGH[1])   # index finger, first flexion joint
    bus.set_torque(True)
    bus.write_goal_positions(goal)
    sleep(1.5)
    moved = bus.read_state().position
    bus.set_torque(False)
    assert moved[1] == pytest.approx(goal[1], abs=0.05)
