"""Fault soak on the virtual clock: dropped, corrupted and late status packets.

Checked on the device side: every value the driver returns as valid is byte-for-byte one the
motors sent in reply to *that* read (the emulator's reply log), and every goal a motor accepted is
inside the hand's joint limits (the emulator's goal log).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.hardware.bus import CommandError
from lowcostdex.hardware.dynamixel.driver import DynamixelBus
from lowcostdex.hardware.dynamixel.protocol import Instruction
from lowcostdex.hardware.emulated.chain import FaultConfig, emulated_dclaw

TICK = 2 * math.pi / 4096
READS = (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ)
# (state field, unit, control-table address, size): e-Manual X-series
FIELDS = (("position", TICK, 132, 4), ("velocity", None, 128, 4), ("current", None, 126, 2),
          ("voltage", 0.1, 144, 2), ("temperature", 1.0, 146, 1))


def replies_since(chain, n0):
    """Block data each motor sent in reply to sync reads after instruction ``n0``."""
    out: dict[int, list[bytes]] = {}
    for inst_no, motor_id, inst, payload in chain.reply_log:
        if inst_no > n0 and inst in READS:
            out.setdefault(motor_id, []).append(payload[1:])
    chain.reply_log.clear()
    return out


def check_fresh(bus, state, sent):
    """Every valid value equals one a motor sent for this read (never an earlier one)."""
    spec = bus.tables
    for k, i in enumerate(bus.ids):
        if not state.valid[k]:
            assert np.isnan(state.position[k]) and np.isnan(state.temperature[k])
            continue
        units = {"velocity": bus._velocity_unit[k], "current": bus._current_unit[k]}
        got = []
        for name, unit, addr, size in FIELDS:
            value = getattr(state, name)[k] / (unit or units[name])
            got.append((addr, size, round(value)))
        assert spec[i] is not None
        candidates = sent.get(i, [])
        # each reply in its own layout: a block ending at Present Temperature (146), 21 bytes
        # from 126 or 27 from 120 (the driver reads the longer one after a lost reply)
        assert any(all(int.from_bytes(raw[addr - (147 - len(raw)):][:size], "little",
                                      signed=name != "voltage") == v
                       for (addr, size, v), (name, *_) in zip(got, FIELDS, strict=True))
                   for raw in candidates), f"motor {i}: a valid value nobody sent in this read"


def limit_ticks(hand):
    out = {}
    for j in hand.all_joints:
        a, b = sorted((j.calibration.to_motor(j.low), j.calibration.to_motor(j.high)))
        out[j.motor_id] = (max(0, math.ceil(a / TICK - 1e-9)), min(4095, math.floor(b / TICK)))
    return out


def test_soak_10k_cycles_with_2_percent_faults_each():
    faults = FaultConfig(drop=0.02, corrupt=0.02, late=0.02)
    chain = emulated_dclaw(faults=faults, rng=np.random.default_rng(2024), record_replies=True)
    bus = DynamixelBus.from_hand(chain.hand, chain.port(), handle_signals=False,
                                 max_invalid_reads=None)
    rng = np.random.default_rng(7)
    n_valid = n_reads = nonfinite = 0
    with bus:
        bus.set_torque(True)
        center = bus.read_state().position
        while np.isnan(center).any():
            center = bus.read_state().position
        chain.reply_log.clear()
        for cycle in range(10_000):
            n0 = chain.instruction_count
            state = bus.read_state()
            check_fresh(bus, state, replies_since(chain, n0))
            n_valid += int(state.valid.sum())
            n_reads += len(bus.ids)
            goal = center + 0.5 * np.sin(0.01 * cycle + np.arange(len(center)))
            if cycle % 50 == 0:
                goal = goal + rng.choice([-3.0, 3.0], size=len(goal))  # way past the limits
            if cycle % 397 == 0:
                goal[rng.integers(len(goal))] = np.nan
            try:
                bus.write_goal_positions(goal)
            except CommandError:
                nonfinite += 1
    assert nonfinite == len(range(0, 10_000, 397))
    limits = limit_ticks(chain.hand)
    times, values = chain.goal_log.positions()
    ids = np.array([m for m, r in zip(chain.goal_log.motor_id, chain.goal_log.reg, strict=True)
                    if r == "Goal Position"])
    assert len(values) > 9 * 10_000
    for i, (lo, hi) in limits.items():
        v = values[ids == i]
        assert v.min() >= lo and v.max() <= hi, f"motor {i} accepted a goal outside [{lo}, {hi}]"
        assert v.max() == hi and v.min() == lo  # the out-of-range requests were clipped
    s = bus.stats
    assert s.timeouts > 50 and s.corrupt > 50 and s.retries > 50  # the faults really happened
    assert n_valid / n_reads > 0.97  # and the driver still delivers


@pytest.mark.parametrize("delay_ms,settle_ms", [(d, 10.0) for d in (7.5, 9.0, 11.0, 13.0)]
                         + [(d, 10.0) for d in (18.0, 21.0, 24.0, 27.0, 30.0)])
def test_late_replies_of_an_earlier_read_are_never_taken_as_fresh(delay_ms, settle_ms):
    """Every reply of one read comes ``delay_ms`` late (the 9-motor read times out after 6.9 ms).

    Up to timeout + settle the late bytes arrive before the next read and are flushed; later ones
    land inside later reads, between their fresh replies, and must be caught by the packet count.
    """
    chain = emulated_dclaw(station="none", rng=np.random.default_rng(3), record_replies=True)
    bus = DynamixelBus.from_hand(chain.hand, chain.port(), handle_signals=False,
                                 settle_ms=settle_ms, read_retries=0, fast_read="off",
                                 max_invalid_reads=None)
    with bus:
        bus.set_torque(True)
        goal = bus.read_state().position
        goal[[1, 4, 7]] += 1.0  # keep the fingers moving: stale values differ from fresh ones
        bus.write_goal_positions(goal)
        for _ in range(4):
            chain.faults = FaultConfig(late=1.0, late_delay=(delay_ms / 1000,) * 2)
            assert not bus.read_state().valid.any()  # every reply misses the timeout
            chain.faults = FaultConfig()
            chain.reply_log.clear()
            for _ in range(8):  # the stale bytes are in flight during these reads
                n0 = chain.instruction_count
                state = bus.read_state()
                check_fresh(bus, state, replies_since(chain, n0))
        if delay_ms > 6.9 + settle_ms + 1:
            assert bus.stats.contaminated > 0  # they did land inside later reads


@pytest.mark.slow
def test_soak_100k_cycles():
    faults = FaultConfig(drop=0.02, corrupt=0.02, late=0.02)
    chain = emulated_dclaw(faults=faults, rng=np.random.default_rng(5), record_replies=True)
    with DynamixelBus.from_hand(chain.hand, chain.port(), handle_signals=False,
                                max_invalid_reads=None) as bus:
        bus.set_torque(True)
        center = bus.read_state().position
        for cycle in range(100_000):
            n0 = chain.instruction_count
            state = bus.read_state()
            check_fresh(bus, state, replies_since(chain, n0))
            if not np.isnan(center).any():
                bus.write_goal_positions(center + 0.5 * np.sin(0.003 * cycle))
            else:
                center = state.position


@pytest.mark.parametrize("realtime_tick", [True, False])
def test_a_late_reply_in_the_slot_of_a_lost_one_is_not_taken_for_the_torque_on_position(
        realtime_tick):
    """Torque-on sets each motor's goal to its present position, read just before
    (``set_torque``). Every reply of one read of motors 10-12 comes 17 ms late (past its
    timeout and the 10 ms settle wait, so past the next read's flush: measured, 15-19 ms land in
    the next read) and every fresh reply of the next is lost: the late replies land in its
    slots, one per motor, and the packet count cannot tell. Refused either way, no position,
    torque stays off: with ``realtime_tick`` (the 27-byte block from the start) by their
    Realtime Tick, which has not advanced with the host's clock; without it (the default) by
    their length: the lost read switched the driver to the 27-byte block, and a late reply to a
    21-byte request is 6 bytes short. (Before the switch existed, the default took the late
    replies as the present positions.)"""
    from lowcostdex.hardware.bus import BusError
    from lowcostdex.hardware.dynamixel.config import DynamixelConfig

    chain = emulated_dclaw(station="none", rng=np.random.default_rng(3), record_replies=True)
    ids = (10, 11, 12)
    bus = DynamixelBus(chain.port(), DynamixelConfig(
        ids=ids, models=("XH430-W350",) * 3, handle_signals=False, fast_read="off",
        read_retries=0, retries=0, max_invalid_reads=None, realtime_tick=realtime_tick))
    with bus:
        assert bus.read_state().valid.all()  # each motor's tick and the host's time, noted
        assert bus._block_len == (27 if realtime_tick else 21)  # e-Manual: 120..146, 126..146
        chain.faults = FaultConfig(late=1.0, late_delay=(0.017, 0.017))
        assert not bus.read_state().valid.any()
        assert bus._block_len == 27  # one lost reply: the tick block from now on
        chain.faults = FaultConfig(drop=1.0)
        contaminated = bus.stats.contaminated
        with pytest.raises(BusError, match="cannot read the present position"):
            bus._present_ticks(ids)
        assert not any(m.torque_on for m in chain.motors.values())
        if realtime_tick:
            assert bus.stats.stale == 3  # each late reply read, and refused by its tick
        else:  # the first late reply (32 bytes for a 38-byte slot) voids the read
            assert bus.stats.stale == 0 and bus.stats.contaminated == contaminated + 1
