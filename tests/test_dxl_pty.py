"""The emulator on a Linux pty: the unmodified SDK (and the driver) in this or another process.

Real time on a shared machine: timeouts here assume the SDK's default 16 ms USB latency (the
driver's ``latency_ms=16``), so a loaded CPU delays but does not fail a transaction.
"""

from __future__ import annotations

import math
import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, PacketHandler, PortHandler

from lowcostdex.hardware.dynamixel.control_table import Reg
from lowcostdex.hardware.dynamixel.driver import DynamixelBus
from lowcostdex.hardware.emulated.chain import emulated_dclaw

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux pty")
TICK = 2 * math.pi / 4096
ENV = {**os.environ, "PYTHONUNBUFFERED": "1"}


@pytest.fixture
def served():
    chain = emulated_dclaw(clock="realtime", wire_time=False, rng=np.random.default_rng(0))
    server = chain.serve_pty()
    yield chain, server
    server.stop()


def lines_of(stream) -> queue.Queue:
    q: queue.Queue = queue.Queue()

    def pump():
        for line in stream:
            q.put(line.rstrip("\n"))

    threading.Thread(target=pump, daemon=True).start()
    return q


def wait_for(q: queue.Queue, pattern: str, timeout: float,
             err: queue.Queue | None = None) -> list[str]:
    """Lines up to and including the first matching ``pattern``; on failure the message also
    holds what arrived on ``err`` (a host's stderr, read all along so its pipe never fills)."""
    seen, end = [], time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            line = q.get(timeout=max(0.01, end - time.monotonic()))
        except queue.Empty:
            break
        seen.append(line)
        if re.search(pattern, line):
            return seen
    errs = []
    while err is not None and not err.empty():
        errs.append(err.get())
    raise AssertionError(f"no line matching {pattern!r} within {timeout} s; got {seen}; "
                         f"stderr: {errs[-40:]}")


def test_unmodified_sdk_and_driver_over_the_pty(served):
    chain, server = served
    port = PortHandler(server.path)
    assert port.openPort()
    ph = PacketHandler(2.0)
    assert ph.ping(port, 32) == (1000, COMM_SUCCESS, 0)
    gsr = GroupSyncRead(port, ph, 132, 4)
    for i in (32, 10, 50):
        gsr.addParam(i)
    assert gsr.txRxPacket() == COMM_SUCCESS
    assert abs(gsr.getData(10, 132, 4) - 1024) <= 8  # top joint hangs at joint 0 = tick 1024
    port.closePort()
    with DynamixelBus.from_hand(chain.hand, server.path, handle_signals=False,
                                latency_ms=16) as bus:
        bus.set_torque(True)
        start = bus.read_state().position
        goal = start.copy()
        goal[1] -= 0.3  # swing the first finger outwards (inwards it would meet the valve)
        bus.write_goal_positions(goal)
        bus.sleep(0.6)  # keeps the bus watchdog fed (a bare time.sleep would trip it)
        moved = bus.read_state().position
    assert moved[1] - start[1] == pytest.approx(-0.3, abs=0.01)
    with server.lock:
        times, values = chain.goal_log.positions(11)
        assert values[-1] == round(goal[1] / TICK)
        assert not any(m.torque_on for m in chain.motors.values())  # torque off on exit


def test_lowcostdex_emulate_prints_its_port_first_and_stops_on_sigint():
    proc = subprocess.Popen([sys.executable, "-m", "lowcostdex.cli", "emulate", "dclaw"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        first = proc.stdout.readline().strip()
        assert re.fullmatch(r"PORT /dev/pts/\d+", first), first
        port = PortHandler(first.split()[1])
        assert port.openPort()
        found, result = PacketHandler(2.0).broadcastPing(port)
        port.closePort()
        assert result == COMM_SUCCESS
        assert sorted(found) == [10, 11, 12, 20, 21, 22, 30, 31, 32, 50]
        assert {v[0] for v in found.values()} == {1000}
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0


HOST = """
import sys, numpy as np
from lowcostdex.hardware.dynamixel.control_table import Reg
from lowcostdex.hardware.dynamixel.driver import DynamixelBus
from lowcostdex.hands import dclaw_spec
bus = DynamixelBus.from_hand(dclaw_spec(), sys.argv[1], latency_ms=16)
bus.connect()
for i in bus.ids:
    bus.write_register(i, Reg.PROFILE_VELOCITY, 15)  # 0.36 rad/s: a long, slow motion
bus.set_torque(True)
goal = bus.read_state().position
goal[[1, 4, 7]] -= 0.9  # fingers swing outwards, the valve turns
goal[9] += 2.5
bus.write_goal_positions(goal)
print("MOVING", flush=True)
if sys.argv[2] == "exit":
    sys.exit(0)  # no disconnect: the atexit hook must turn torque off
while True:
    bus.read_state()
    bus.write_goal_positions(goal)
    if sys.argv[2] == "sleep":
        bus.sleep(0.05)
"""


def test_host_killed_mid_motion_motors_stop_within_the_watchdog_time(served):
    chain, server = served
    host = subprocess.Popen([sys.executable, "-c", HOST, server.path, "loop"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        wait_for(lines_of(host.stdout), "MOVING", timeout=60, err=lines_of(host.stderr))
        time.sleep(0.3)  # mid-motion
        with server.lock:
            state = {i: (m.torque_on, m.get(Reg.BUS_WATCHDOG)) for i, m in chain.motors.items()}
            assert all(v == (True, 5) for v in state.values()), (state, chain.events)
        t_kill = time.monotonic()
        host.kill()  # SIGKILL: no handler, no atexit, no torque off
        host.wait(timeout=10)
    finally:
        if host.poll() is None:
            host.kill()
    time.sleep(0.6)
    with server.lock:
        trips = {e.motor_id: e for e in chain.events if e.kind == "watchdog"}
        assert set(trips) == set(chain.motors)
        for e in trips.values():
            silence = float(re.search(r"after ([\d.]+) s silent", e.detail).group(1))
            # device side: one physics step at most. The trip is strictly after 100 ms, but
            # the event prints 1 us: a last packet on the physics step's grid trips 1e-13 s
            # after 100 ms and reads 'after 0.100000 s silent' (failed as 0.1 < 0.1)
            assert 0.100 <= silence <= 0.100 + 0.0026
            assert chain.clock.to_wall(e.time) < t_kill + 0.100 + 0.25  # wall side, loaded CPU
        stop = {i: m.setpoint for i, m in chain.motors.items()}
        assert all(m.torque_on for m in chain.motors.values())  # holding, not limp
    with server.lock:
        a = np.array(chain.drive.state().q)
    time.sleep(0.3)
    with server.lock:
        b = np.array(chain.drive.state().q)
    assert np.abs(b - a).max() < 3 * TICK  # standing still
    with server.lock:
        for i in (11, 21, 31, 50):  # the moving ones
            goal = chain.motors[i].get(Reg.GOAL_POSITION) - chain.motors[i].homing
            assert abs(stop[i] - goal) > 300  # stopped well short of where it was going
    port = PortHandler(server.path)
    port.openPort()
    ph = PacketHandler(2.0)
    for i in chain.motors:
        assert ph.read1ByteTxRx(port, i, 98)[:2] == (0xFF, COMM_SUCCESS)  # reads -1
    port.closePort()


@pytest.mark.parametrize("how", ["SIGTERM", "SIGINT", "exit"])
def test_torque_off_on_sigterm_sigint_and_exit(served, how):
    chain, server = served
    mode = "exit" if how == "exit" else "sleep"
    host = subprocess.Popen([sys.executable, "-c", HOST, server.path, mode],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
    try:
        wait_for(lines_of(host.stdout), "MOVING", timeout=60, err=lines_of(host.stderr))
        if how == "exit":
            assert host.wait(timeout=20) == 0
        else:
            time.sleep(0.3)
            with server.lock:
                assert all(m.torque_on for m in chain.motors.values())
            host.send_signal(getattr(signal, how))
            code = host.wait(timeout=20)
            # the previous handler still runs: the default SIGTERM action kills the process;
            # SIGINT raises KeyboardInterrupt, which Python re-raises as the signal at exit
            assert code == -getattr(signal, how)
    finally:
        if host.poll() is None:
            host.kill()
    time.sleep(0.3)
    with server.lock:
        assert not any(m.torque_on for m in chain.motors.values())
        assert not [e for e in chain.events if e.kind == "watchdog"]  # off before any trip
