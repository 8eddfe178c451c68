"""The main job in its smoke size: every stage runs on the emulated D'Claw and its outputs make
sense (issue 7)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lowcostdex.cli import main


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    out = tmp_path_factory.mktemp("main")
    assert main(["main", "--size", "smoke", "--out", str(out)]) == 0
    return out, json.loads((out / "results.json").read_text())


def test_robot_comes_up_scanned_and_calibrated(smoke):
    out, r = smoke
    bus = r["bus"]
    assert bus["motors_found"] == 10 and bus["motors_missing"] == []
    assert {m["id"] for m in bus["motors"]} == {10, 11, 12, 20, 21, 22, 30, 31, 32, 50}
    assert all(m["model"].startswith("XH430") and not m["errors"] for m in bus["motors"])
    # the servos hold the zero pose within backlash and steady-state error: a few ticks
    assert bus["calibration_ticks"] < 12
    assert (out / "hand.json").stat().st_size > 0


def test_demonstrations_recorded_with_resets(smoke):
    out, r = smoke
    d = r["demos"]
    assert d["episodes"] >= 3 and d["successful"] >= d["episodes"] - 1
    assert d["robot"]["resets"] >= d["episodes"]
    assert (out / d["file"]).stat().st_size > 0


def test_training_ran_on_the_robot_and_bc_beats_chance(smoke):
    out, r = smoke
    t = r["train"]
    for algo in ("dapg", "npg"):
        assert t[algo]["samples"] > 0 and t[algo]["robot_hours"] > 0
        assert (out / t[algo]["curves"]).stat().st_size > 5000
        assert t[algo]["robot"]["resets"] > 0
        assert t[algo]["robot"]["max_temperature"] < 65  # below the thermal guard's pause
    # a random policy never turns the valve 180 deg; the behaviour clone sometimes does
    assert t["success_after_bc"] > 0.0
    assert (out / t["plot"]).stat().st_size > 5000


def test_gap_analysis_names_the_emulated_robots_effects(smoke):
    out, r = smoke
    g = r["gap"]
    assert g["causes"], g["verdict"]
    # exactly the emulated robot's effects, none invented, with their parameters
    truth = {e["effect"]: e["params"] for e in g["truth"]}
    named = {c["effect"]: c["params"] for c in g["causes"]}
    assert set(named) == set(truth), g["verdict"]
    for effect, params in truth.items():
        for p, value in params.items():
            np.testing.assert_allclose(named[effect][p], value, rtol=0.2, err_msg=effect)
    assert g["extended_heldout_rmse_mrad"] < 0.5 * g["baseline_heldout_rmse_mrad"]
    assert g["extended_heldout_rmse_mrad"] < 1.5 * g["noise_floor_mrad"]
    assert (out / g["report"]).exists()
    for plot in g["plots"]:
        assert (out / plot).stat().st_size > 5000


def test_report_links_every_plot(smoke):
    out, r = smoke
    text = (out / "report.md").read_text()
    for section in ("The robot on its bus", "Kinesthetic demonstrations", "DAPG vs NPG",
                    "What the nominal simulation gets wrong", "Robot health"):
        assert section in text
    for png in ("learning_curves.png", "robot_health.png"):
        assert f"({png})" in text and (out / png).stat().st_size > 5000
    assert (out / "report.html").read_text().count("<img") >= 3
