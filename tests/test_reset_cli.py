"""The ``lowcostdex reset-test`` and ``lowcostdex record-demos`` commands on the emulated D'Claw."""

from __future__ import annotations

import json

import numpy as np

from lowcostdex.cli import main
from lowcostdex.demonstrations.file import (
    read_demo_pairs,
    read_episodes,
    read_info,
    read_label_model,
)


def test_reset_test_reports_success_rate_and_times(tmp_path, capsys):
    out = tmp_path / "reset.json"
    assert main(["reset-test", "--port", "emulated", "--trials", "3", "--seed", "2",
                 "--json", str(out)]) == 0
    summary = json.loads(out.read_text())
    assert summary["trials"] == 3 and summary["success_rate"] == 1.0
    assert 0 < summary["time_mean"] <= summary["time_max"] < 60
    assert "success rate 3/3 = 100%" in capsys.readouterr().out


def test_record_demos_with_the_virtual_teacher(tmp_path):
    out = tmp_path / "valve.h5"
    assert main(["record-demos", "--hand", "dclaw", "--task", "turn-valve", "--port", "emulated",
                 "--episodes", "1", "--out", str(out)]) == 0
    info, episodes, steps = read_info(out)
    # the demonstration and its two playbacks (servo-goal labels, the default)
    assert (episodes, steps) == (3, 120) and info.source == "virtual_teacher"
    assert [(e.source, e.label) for e in read_episodes(out)] == [
        ("virtual_teacher", "servo_goal"), ("playback", "commanded"), ("playback", "commanded")]
    assert read_label_model(out)["model"] == "linear_servo_response"
    pairs = read_demo_pairs(out)
    assert len(pairs) == 3
    for obs, act in pairs:
        assert obs.shape == (40, info.obs_dim) and np.all(np.abs(act) <= 1)
    # BAIR's labels, no playbacks
    bair = tmp_path / "bair.h5"
    assert main(["record-demos", "--port", "emulated", "--episodes", "1", "--labels",
                 "next_position", "--out", str(bair)]) == 0
    assert [e.label for e in read_episodes(bair)] == ["next_position"]
    assert read_label_model(bair) is None


def test_bad_arguments_are_errors_not_hangs(tmp_path, capsys):
    assert main(["reset-test", "--trials", "0"]) == 2
    assert "--trials must be >= 1" in capsys.readouterr().err
