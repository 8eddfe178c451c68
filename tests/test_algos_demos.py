"""The NPG/DAPG demo scripts run end to end with tiny budgets."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

DEMOS = Path(__file__).resolve().parents[1] / "demos"


def _run(script: str, args: list[str], monkeypatch) -> None:
    spec = importlib.util.spec_from_file_location(script, DEMOS / f"{script}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(sys, "argv", [script, *args])
    module.main()


def test_npg_valve_demo(tmp_path, monkeypatch, capsys):
    _run(
        "npg_valve", ["--iters", "2", "--n-traj", "2", "--out", str(tmp_path / "npg")], monkeypatch
    )
    assert "learning curves" in capsys.readouterr().out
    assert (tmp_path / "npg" / "learning_curves.png").exists()


def test_flip_keypoints_vs_quaternion_demo(tmp_path, monkeypatch):
    _run(
        "flip_keypoints_vs_quaternion",
        ["--iters", "1", "--n-traj", "2", "--out", str(tmp_path)],
        monkeypatch,
    )
    assert (tmp_path / "keypoints_vs_quaternion.png").stat().st_size > 10_000


def test_dapg_kinesthetic_valve_demo(tmp_path, monkeypatch, capsys):
    import lowcostdex.demonstrations.kinesthetic  # noqa: F401  (an import error fails, never skips)
    args = [
        "--demos",
        "2",
        "--iters",
        "1",
        "--n-traj",
        "2",
        "--backend",
        "sim",
        "--out",
        str(tmp_path),
    ]
    _run("dapg_kinesthetic_valve", args, monkeypatch)
    # the script reports what its demo file holds: the 2 demonstrations and the playbacks of
    # them that reached the goal (their rate: tests/test_demos_recording.py)
    from lowcostdex.demonstrations.file import read_episodes

    episodes = read_episodes(tmp_path / "valve_demos.h5")
    demos = [e for e in episodes if e.source == "virtual_teacher"]
    played = [e for e in episodes if e.source == "playback" and e.success[-1]]
    assert len(demos) == 2 and all(e.success[-1] for e in demos) and played
    assert f"BC on 2 demos + {len(played)} playbacks" in capsys.readouterr().out
