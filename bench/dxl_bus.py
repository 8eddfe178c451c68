"""Dynamixel driver cycle: Python cost vs the bare SDK, pty loop rate, wire-time limit.

A cycle is what a control step does: one sync read of the 21-byte block 126..146 of 9 motors
(D'Claw fingers) plus one sync write of their goal positions.

1. In-process emulator (virtual clock, MuJoCo physics behind it), same run, interleaved blocks:
   the SDK's bare ``GroupSyncRead(126, 21).txRxPacket()`` vs ``DynamixelBus.read_state() +
   write_goal_positions()``. Reported as wall time per call, total and with the emulator's own
   time (packet handling + physics, timed inside the chain) subtracted, i.e. the host-side Python
   cost. Target: driver cycle <= 2x the bare sync read.
2. pty: ``lowcostdex emulate dclaw --station none`` in its own process (real-time clock, no wire
   delay) and the driver cycle over the pty; loop rate [Hz]. Target >= 1 kHz.
3. The wire-time limit of the same cycle at 1 and 4 Mbps (Return Delay Time 0), printed beside.

Usage: python bench/dxl_bus.py [--seconds 3] [--no-pty]
"""

from __future__ import annotations

import argparse
import os
import platform
import signal
import subprocess
import sys
import time

import numpy as np
from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, GroupSyncWrite, PacketHandler

from lowcostdex.hardware.dynamixel.driver import DynamixelBus
from lowcostdex.hardware.dynamixel.protocol import sync_read_bytes, sync_write_bytes, wire_time
from lowcostdex.hardware.emulated.chain import emulated_dclaw

N, LENGTH = 9, 21


class Timed:
    """Wraps a bound method and accumulates its wall time."""

    def __init__(self, fn):
        self.fn, self.total = fn, 0.0

    def __call__(self, *args, **kwargs):
        t = time.perf_counter()
        try:
            return self.fn(*args, **kwargs)
        finally:
            self.total += time.perf_counter() - t


def inprocess(blocks: int, per_block: int) -> dict[str, float]:
    chain = emulated_dclaw(station="none", rng=np.random.default_rng(0))
    handle, advance = Timed(chain.handle), Timed(chain.advance_to)
    chain.handle, chain.advance_to = handle, advance
    bus = DynamixelBus.from_hand(chain.hand, chain.port(), handle_signals=False)
    bus.connect()
    bus.set_torque(True)
    center = bus.read_state().position
    port, ph = bus.port, PacketHandler(2.0)
    gsr = GroupSyncRead(port, ph, 126, LENGTH)
    for i in bus.ids:
        gsr.addParam(i)
    gsw = GroupSyncWrite(port, ph, 116, 4)
    for i in bus.ids:
        gsw.addParam(i, [0, 8, 0, 0])
    results: dict[str, list[float]] = {k: [] for k in ("bare", "bare_fast", "bare_cycle",
                                                       "driver", "driver_read")}

    def run(name, body):
        e0 = handle.total + advance.total
        t0 = time.perf_counter()
        for k in range(per_block):
            body(k)
        wall = (time.perf_counter() - t0) / per_block
        emu = (handle.total + advance.total - e0) / per_block
        results[name].append((wall, wall - emu))

    def bare(k):
        assert gsr.txRxPacket() == COMM_SUCCESS

    def bare_fast(k):
        assert gsr.fastSyncRead() == COMM_SUCCESS

    def bare_cycle(k):
        assert gsr.txRxPacket() == COMM_SUCCESS
        gsw.txPacket()

    def driver(k):
        bus.read_state()
        bus.write_goal_positions(center + 0.2 * np.sin(0.01 * k))

    def driver_read(k):
        bus.read_state()

    bus.sleep(0.05)  # keep the watchdog fed between blocks
    for _ in range(blocks):
        for name, body in (("bare", bare), ("driver", driver), ("bare_fast", bare_fast),
                           ("bare_cycle", bare_cycle), ("driver_read", driver_read)):
            bus.read_state()
            run(name, body)
    bus.disconnect()
    out = {}
    for name, vals in results.items():
        arr = np.array(vals)
        out[name] = float(np.median(arr[:, 0]))
        out[name + "_host"] = float(np.median(arr[:, 1]))
    out["fast"] = bus.fast_read
    return out


def pty(seconds: float) -> dict[str, float]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "lowcostdex.cli", "emulate", "dclaw",
                             "--station", "none", "--quiet"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, env=env)
    try:
        path = proc.stdout.readline().split()[1]
        out = {}
        bus = DynamixelBus.from_hand(emulated_hand(), path, handle_signals=False, latency_ms=16)
        with bus:
            bus.set_torque(True)
            center = bus.read_state().position
            for fast in (True, False):
                bus.fast_read = fast
                key = "driver_fast" if fast else "driver"
                n, t0, c0, e0 = 0, time.perf_counter(), time.process_time(), cpu(proc.pid)
                while time.perf_counter() - t0 < seconds:
                    bus.read_state()
                    bus.write_goal_positions(center + 0.2 * np.sin(0.002 * n))
                    n += 1
                out[key] = n / (time.perf_counter() - t0)
                out[key + "_host_cpu"] = (time.process_time() - c0) / n
                out[key + "_emu_cpu"] = (cpu(proc.pid) - e0) / n
            out["invalid"] = bus.stats.invalid
            port, ph = bus.port, PacketHandler(2.0)
            gsr = GroupSyncRead(port, ph, 126, LENGTH)
            gsw = GroupSyncWrite(port, ph, 116, 4)
            for k, i in enumerate(bus.ids):
                gsr.addParam(i)
                ticks = int(round(center[k] * 4096 / (2 * np.pi)))
                gsw.addParam(i, list(ticks.to_bytes(4, "little")))
            n, t0 = 0, time.perf_counter()
            while time.perf_counter() - t0 < seconds:
                gsr.txRxPacket()
                gsw.txPacket()
                n += 1
            out["bare"] = n / (time.perf_counter() - t0)
        return out
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)


def cpu(pid: int) -> float:
    """CPU time [s] (user + system) a process has used."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def emulated_hand():
    from lowcostdex.hands import dclaw_spec

    hand = dclaw_spec()
    return type(hand)(hand.name, hand.motor, hand.joints, ())  # the 9 finger motors


def wire_limits() -> dict[str, float]:
    out = {}
    for baud in (1_000_000, 4_000_000):
        for fast in (False, True):
            inst, reply = sync_read_bytes(N, LENGTH, fast)
            cycle = wire_time(inst + reply + sync_write_bytes(N, 4), baud)
            out[f"{baud // 1_000_000}M{'_fast' if fast else ''}"] = 1.0 / cycle
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=3.0, help="pty measurement per variant")
    p.add_argument("--blocks", type=int, default=7)
    p.add_argument("--per-block", type=int, default=200)
    p.add_argument("--no-pty", action="store_true")
    p.add_argument("--repeat", type=int, default=3,
                   help="pty measurements (a shared machine's neighbours make them vary)")
    args = p.parse_args()
    print(f"# {platform.node()} | {platform.processor() or platform.machine()} | "
          f"{os.cpu_count()} cpus | load {os.getloadavg()[0]:.1f} | Python "
          f"{platform.python_version()}")
    r = inprocess(args.blocks, args.per_block)
    us = 1e6
    print("in-process emulator, 9 motors x 21 B, median of interleaved blocks [us per call]")
    print("                         wall    host-side (emulator time removed)")
    for name, label in (("bare", "SDK GroupSyncRead.txRxPacket"),
                        ("bare_fast", "SDK GroupSyncRead.fastSyncRead"),
                        ("bare_cycle", "SDK sync read + sync write"),
                        ("driver_read", "DynamixelBus.read_state"),
                        ("driver", "driver cycle (read_state + write goals)")):
        print(f"  {label:<42} {r[name] * us:8.1f} {r[name + '_host'] * us:8.1f}")
    print(f"  driver cycle / bare sync read: {r['driver'] / r['bare']:.2f}x wall, "
          f"{r['driver_host'] / r['bare_host']:.2f}x host-side   (target <= 2x; driver uses "
          f"{'fast' if r['fast'] else 'normal'} sync read)")
    print(f"  stricter baselines: read_state / bare fast sync read "
          f"{r['driver_read'] / r['bare_fast']:.2f}x wall, "
          f"{r['driver_read_host'] / r['bare_fast_host']:.2f}x host-side; driver cycle / bare "
          f"read+write {r['driver'] / r['bare_cycle']:.2f}x wall, "
          f"{r['driver_host'] / r['bare_cycle_host']:.2f}x host-side")
    w = wire_limits()
    print("wire-time limit of the cycle (RDT 0): "
          f"1 Mbps {w['1M']:.0f} Hz ({w['1M_fast']:.0f} Hz fast), "
          f"4 Mbps {w['4M']:.0f} Hz ({w['4M_fast']:.0f} Hz fast)")
    if not args.no_pty:
        runs = []
        for _ in range(args.repeat):
            load = os.getloadavg()[0]
            q = pty(args.seconds)
            runs.append(q)
            print(f"pty, emulator in its own process (load {load:.1f}): driver "
                  f"cycle {q['driver_fast']:.0f} Hz (fast sync read), {q['driver']:.0f} Hz (sync "
                  f"read); bare SDK read+write {q['bare']:.0f} Hz; invalid motor-reads "
                  f"{q['invalid']}; CPU per driver cycle: host {q['driver_fast_host_cpu'] * us:.0f}"
                  f" us (the SDK busy-polls while it waits), emulator "
                  f"{q['driver_fast_emu_cpu'] * us:.0f} us")
        best = max(max(q["driver_fast"], q["driver"]) for q in runs)
        print(f"pty driver loop: best {best:.0f} Hz of {len(runs)} runs (target >= 1000 Hz); "
              f"wire-time limit at 1 Mbps {w['1M']:.0f} Hz, at 4 Mbps {w['4M']:.0f} Hz")


if __name__ == "__main__":
    main()
