"""``lowcostdex transfer --port``: the user's D'Claw, here an emulated one that ``lowcostdex emulate
dclaw`` serves on a Linux pty from its own process, in real time, so every bus the loop opens
(identification, on_robot training, evaluation) goes through the unmodified dynamixel_sdk.

Slow: real time on a pty (~2-3 min wall at load 10) and, on a machine loaded well beyond its
cores, a starved emulator trips its own 100 ms bus watchdog (the same reason as
tests/test_backend_emulated.py::test_hardware_backend_over_a_pty).
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux pty")]

LOG_ROWS = 150  # the smoke size's identification logs: 3 s at the 50 Hz identification rate


@contextlib.contextmanager
def served(station: str):
    """``lowcostdex emulate dclaw --station STATION`` in its own process; yields its pty path."""
    proc = subprocess.Popen([sys.executable, "-m", "lowcostdex.cli", "emulate", "dclaw",
                             "--station", station, "--quiet"], stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline().split()
        assert line[:1] == ["PORT"], line
        yield line[1]
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def point(link, path) -> None:
    """``link`` -> ``path``: the stable name a udev rule gives a real adapter
    (/dev/serial/by-id/...), while the pty's own name changes from server to server."""
    if link.is_symlink():
        link.unlink()
    link.symlink_to(path)


def test_transfer_on_a_port_identifies_stops_then_trains_on_the_robot_and_evaluates(
        tmp_path, capsys):
    from lowcostdex.cli import main
    from lowcostdex.gap import read_log
    from lowcostdex.transfer.loop import SIZES

    size = SIZES["smoke"]
    link, out = tmp_path / "dclaw", tmp_path / "t"
    args = ["transfer", "--out", str(out), "--size", "smoke", "--port", str(link),
            "--latency-ms", "16", "--yes", "--algos", "npg", "--conditions",
            "identified,on_robot"]

    # 1. valve off: identification logs on the robot, then the command stops and says why
    with served("none") as pty:
        point(link, pty)
        assert main(args) == 0
    printed = capsys.readouterr().out
    assert "Put the valve back on and run the same command again" in printed
    logs = sorted((out / "identify" / "robot" / "ff" / "logs").glob("log_*.csv"))
    assert len(logs) == size.id_logs
    for p in logs:
        assert len(read_log(p)) == LOG_ROWS  # complete: read_log refuses a missed reading
    finger = json.loads((out / "identify" / "robot" / "ff" / "finger.json").read_text())
    assert finger["robot_seconds"] == size.id_logs * size.id_seconds
    assert not (out / "runs").exists() and not (out / "transfer.json").exists()
    stamps = [p.stat().st_mtime_ns for p in logs]

    # 2. nothing on the port: refused before anything runs
    link.unlink()
    assert main(args) == 2
    assert f"--port {link}: no such device" in capsys.readouterr().err
    assert not (out / "runs").exists()

    # 3. valve on: the same command resumes (identification found done), trains on the robot
    # and evaluates every policy on it
    with served("valve") as pty:
        point(link, pty)
        assert main(args) == 0
    printed = capsys.readouterr().out
    assert "identified robot/ff (found done)" in printed
    assert [p.stat().st_mtime_ns for p in logs] == stamps
    rows = json.loads((out / "transfer.json").read_text())["rows"]
    assert sorted(r["condition"] for r in rows) == ["identified", "on_robot"]
    for r in rows:
        assert r["robot"] == "robot" and r["episodes"] == size.episodes
        assert len(r["final_error"]) == size.episodes
    config = json.loads((out / "runs" / "npg" / "on_robot_robot_seed0" / "config.json")
                        .read_text())
    assert config["backend"] == "hardware" and config["sampler"] == "serial"
    assert config["env_kwargs"]["port"] == str(link)
    assert config["env_kwargs"]["latency_ms"] == 16
    # the valve-log fit ran on the robot once the valve was back: (c) trains in its edit
    fit = json.loads((out / "identify" / "robot" / "valve_fit.json").read_text())
    assert fit["episodes"] == size.valve_episodes and fit["robot_seconds"] == 4.0 * fit["episodes"]
    ident = next(r for r in rows if r["condition"] == "identified")
    assert ident["model_edit"] == fit["model_edit"]
