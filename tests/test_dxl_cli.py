"""The hardware CLI handlers (scan, calibrate) against the in-process emulator."""

from __future__ import annotations

import argparse
import math

import pytest

from lowcostdex.hands import HandSpec, dclaw_spec
from lowcostdex.hardware import cli


def run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    cli.add_commands(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.func(args)


def test_parse_ids():
    assert cli.parse_ids("10-12,50, 60") == [10, 11, 12, 50, 60]


def test_scan_emulated_dclaw(capsys):
    assert run(["scan", "--port", "emulated", "--hand", "dclaw"]) == 0
    rows = capsys.readouterr().out.strip().splitlines()
    assert len(rows) == 1 + 10
    assert rows[1].split()[:4] == ["10", "XH430-W350", "1000", "52"]
    assert all(r.split()[4:7] == ["25C", "12.0V", "off"] for r in rows[1:])
    assert run(["scan", "--port", "emulated", "--hand", "bench", "--ids", "1-3"]) == 0
    rows = capsys.readouterr().out.strip().splitlines()
    assert [r.split()[0] for r in rows[1:]] == ["1"]


def test_calibrate_writes_a_hand_spec(tmp_path, capsys):
    out = tmp_path / "dclaw.json"
    assert run(["calibrate", "--hand", "dclaw", "--port", "emulated", "--out", str(out),
                "--yes", "--samples", "3"]) == 0
    new, nominal = HandSpec.load(out), dclaw_spec()
    assert [j.motor_id for j in new.all_joints] == [j.motor_id for j in nominal.all_joints]
    for a, b in zip(new.all_joints, nominal.all_joints, strict=True):
        # the emulated hand rests near its zero pose, mounted as the nominal spec says
        assert a.calibration.offset == pytest.approx(b.calibration.offset, abs=0.01)
        assert (a.calibration.sign, a.calibration.scale) == (1, 1.0)
    assert "ff_top" in capsys.readouterr().out
    assert math.isfinite(new.joints[0].calibration.offset)
