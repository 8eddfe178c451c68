"""DynamixelConfig's retry and timing defaults, at the behaviour its docstring states.

``bench/mutate_constants.py --only DynamixelConfig.`` (+1 each) on lowcostdex/hardware/dynamixel/
config.py with the safety group's tests (main 50cb29d): ``read_retries`` 1, ``retries`` 3,
``settle_ms`` 10, ``max_invalid_reads`` 50 and ``reboot_timeout`` 2 s went unnoticed (the last
is left: a motor that takes the REBOOT and then stays silent is not emulated). No outside
number exists for them (the driver's own choices, documented in DynamixelConfig and the driver's
module docstring); each is pinned here one step either side, on the emulated D'Claw's bus (the
real dynamixel_sdk code path, a dead motor made by ``chain.kill``).
"""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.hands import dclaw_spec
from lowcostdex.hardware.bus import BusError
from lowcostdex.hardware.emulated.chain import emulated_dclaw
from lowcostdex.hardware.robot.backend import make_dynamixel_bus

HAND = dclaw_spec()


def _bus():
    chain = emulated_dclaw("valve", hand=HAND, rng=np.random.default_rng(0))
    bus = make_dynamixel_bus(HAND, chain.port(), chain.plant.model, handle_signals=False)
    bus.connect()
    return chain, bus


def test_a_dead_motor_stops_the_bus_at_its_fiftieth_invalid_read():
    chain, bus = _bus()
    dead = HAND.joints[2].motor_id
    chain.kill(dead)
    for _ in range(49):
        bus.read_state()
    with pytest.raises(BusError, match=rf"motors \[{dead}\] gave no valid reply in 50 "
                                       "consecutive reads"):
        bus.read_state()


def test_a_failed_unicast_is_tried_four_times():
    chain, bus = _bus()
    dead = HAND.joints[2].motor_id
    chain.kill(dead)
    before = bus.stats.transactions
    assert bus.ping(dead) is None
    assert bus.stats.transactions - before == 4  # 1 + retries 3 pings, none answered
    with pytest.raises(BusError, match=rf"motor {dead}: reboot failed after 4 attempts"):
        bus.reboot(dead)


def test_after_a_failed_transaction_the_next_goal_waits_the_10_ms_settle():
    chain, bus = _bus()
    clean = bus.goal_delay(9)
    chain.kill(HAND.joints[2].motor_id)
    bus.read_state()  # a timeout: the bus is dirty until the settle has passed
    assert bus.goal_delay(9) - clean == pytest.approx(0.010, abs=1e-9)
