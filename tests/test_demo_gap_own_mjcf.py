"""demos/gap_own_mjcf.py end to end: a user's two-joint MJCF on plain ``position`` actuators,
logs from that MJCF with a 3x dry friction and 30 ms goal latency written in the demo (plain
MuJoCo), analysed by ``lowcostdex gap analyze``. Slow (about 3.5 min of CPU)."""

from __future__ import annotations

import importlib.util
import json
import pathlib
import sys

import pytest

DEMO = pathlib.Path(__file__).resolve().parents[1] / "demos" / "gap_own_mjcf.py"


@pytest.mark.slow
def test_the_demo_names_the_friction_and_latency_it_hid(tmp_path, monkeypatch):
    spec = importlib.util.spec_from_file_location("gap_own_mjcf", DEMO)
    demo = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(demo)
    monkeypatch.setattr(sys, "argv", ["gap_own_mjcf.py", "--out", str(tmp_path / "run")])
    demo.main()
    report = json.loads((tmp_path / "run" / "report" / "report.json").read_text())
    named = {c["effect"]: c for c in report["causes"]}
    assert set(named) == {"latency", "coulomb_friction"}
    # truth from the demo's robot: 30 ms late goals, 0.06 - 0.02 N m of friction missing
    assert named["latency"]["params"]["delay"]["value"] == pytest.approx([0.030, 0.030], abs=0.002)
    assert named["coulomb_friction"]["params"]["frictionloss"]["value"] == pytest.approx(
        [0.04, 0.04], rel=0.1)
    assert report["gain"]["extended_rmse"] < 0.2 * report["gain"]["baseline_rmse"]


def test_the_demo_refuses_a_folder_that_holds_files(tmp_path, monkeypatch, capsys):
    spec = importlib.util.spec_from_file_location("gap_own_mjcf", DEMO)
    demo = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(demo)
    (tmp_path / "mine.txt").write_text("keep")
    monkeypatch.setattr(sys, "argv", ["gap_own_mjcf.py", "--out", str(tmp_path)])
    with pytest.raises(SystemExit) as e:
        demo.main()
    assert e.value.code == 2 and (tmp_path / "mine.txt").read_text() == "keep"
    assert "not empty" in capsys.readouterr().err
