"""Output folders never lose what the tool did not write (issue 12, item 1)."""

from __future__ import annotations

import json

import pytest

from lowcostdex.outdir import MARKER, OutputRefused, archive, check_out, staged_output


def _tree(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_users_folder_is_refused_untouched(tmp_path):
    user = tmp_path / "mylogs"
    user.mkdir()
    (user / "run1.csv").write_text("t,q\n0,0\n")
    (user / "notes.txt").write_text("do not lose me")
    before = _tree(user)
    with pytest.raises(OutputRefused, match="did not write") as err:
        with staged_output(user, "gap analyze") as tmp:
            (tmp / "report.md").write_text("x")
    assert "run1.csv" in str(err.value) or "notes.txt" in str(err.value)
    assert _tree(user) == before
    # no partial folder is left beside it
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mylogs"]


def test_previous_output_is_kept_not_deleted(tmp_path):
    out = tmp_path / "report"
    with staged_output(out, "gap analyze", {"seed": 1}) as tmp:
        (tmp / "report.md").write_text("first")
    with staged_output(out, "gap analyze", {"seed": 2}) as tmp:
        (tmp / "report.md").write_text("second")
    with staged_output(out, "gap analyze") as tmp:
        (tmp / "report.md").write_text("third")
    assert (out / "report.md").read_text() == "third"
    olds = sorted((out / "previous").iterdir())
    assert [(p / "report.md").read_text() for p in olds] == ["first", "second"]
    assert json.loads((out / MARKER).read_text())["command"] == "gap analyze"


def test_failed_run_leaves_previous_output_intact(tmp_path):
    out = tmp_path / "report"
    with staged_output(out, "gap analyze") as tmp:
        (tmp / "report.md").write_text("good")
    with pytest.raises(RuntimeError):
        with staged_output(out, "gap analyze") as tmp:
            (tmp / "report.md").write_text("half")
            raise RuntimeError("crash in the middle")
    assert (out / "report.md").read_text() == "good"
    assert not (out / "previous").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]


def test_other_commands_output_and_files_are_refused(tmp_path):
    out = tmp_path / "o"
    with staged_output(out, "main") as tmp:
        (tmp / "a").write_text("1")
    with pytest.raises(OutputRefused, match="lowcostdex main"):
        check_out(out, "gap analyze")
    f = tmp_path / "file.txt"
    f.write_text("x")
    with pytest.raises(OutputRefused, match="is a file"):
        check_out(f, "gap analyze")
    assert f.read_text() == "x"


def test_settings_that_must_match(tmp_path):
    out = tmp_path / "o"
    with staged_output(out, "main", {"seed": 0, "size": "smoke"}) as tmp:
        (tmp / "a").write_text("1")
    assert check_out(out, "main", {"seed": 0, "size": "smoke"}, must_match=("seed", "size"))
    with pytest.raises(OutputRefused, match="seed=0"):
        check_out(out, "main", {"seed": 3, "size": "smoke"}, must_match=("seed", "size"))
    # an empty folder is fine
    empty = tmp_path / "empty"
    empty.mkdir()
    assert check_out(empty, "main") is False


def test_archive_moves_named_entries(tmp_path):
    (tmp_path / "results.json").write_text("{}")
    (tmp_path / "train").mkdir()
    (tmp_path / "train" / "x").write_text("1")
    (tmp_path / "keep.txt").write_text("k")
    target = archive(tmp_path, ["results.json", "train", "missing"])
    assert target is not None and target.parent.name == "previous"
    assert (target / "results.json").exists() and (target / "train" / "x").read_text() == "1"
    assert (tmp_path / "keep.txt").exists() and not (tmp_path / "train").exists()
    assert archive(tmp_path, ["missing"]) is None


def test_model_out_never_replaces_a_users_file(tmp_path, capsys):
    from lowcostdex.cli import main

    mine = tmp_path / "finger.xml"
    mine.write_text("<mujoco><!-- my hand-tuned model --></mujoco>")
    assert main(["model", "bench", "--out", str(mine)]) != 0
    assert "left untouched" in capsys.readouterr().err
    assert "hand-tuned" in mine.read_text()
    assert main(["model", "bench", "--out", str(mine), "--overwrite"]) == 0
    assert "<actuator" in mine.read_text()
    assert main(["model", "bench", "--out", str(tmp_path)]) != 0          # a folder
    assert main(["model", "bench", "--out", str(tmp_path / "no" / "x.xml")]) != 0


def test_record_log_keeps_earlier_recordings_and_refuses_a_users_folder(tmp_path, capsys):
    from lowcostdex.cli import main

    user = tmp_path / "data"
    user.mkdir()
    (user / "calib.csv").write_text("1,2\n")
    args = ["record-log", "--port", "emulated", "--logs", "1", "--seconds", "0.4"]
    assert main([*args, "--out", str(user)]) != 0
    assert sorted(p.name for p in user.iterdir()) == ["calib.csv"]
    logs = tmp_path / "logs"
    assert main([*args, "--out", str(logs)]) == 0
    first = sorted(p.name for p in logs.glob("*.csv"))
    assert first
    first_bytes = (logs / first[0]).read_bytes()
    assert main([*args, "--seed", "1", "--out", str(logs)]) == 0
    (old,) = (logs / "previous").iterdir()
    assert (old / first[0]).read_bytes() == first_bytes
    assert sorted(p.name for p in logs.glob("*.csv")) == first


def test_record_demos_refuses_a_non_demo_file_before_the_robot_moves(tmp_path, capsys):
    import time

    from lowcostdex.cli import main

    notes = tmp_path / "notes.txt"
    notes.write_text("my notes")
    t0 = time.perf_counter()
    assert main(["record-demos", "--episodes", "1", "--out", str(notes)]) == 2
    assert time.perf_counter() - t0 < 10          # refused up front, not after recording
    assert "not an HDF5" in capsys.readouterr().err
    assert notes.read_text() == "my notes"
    assert main(["record-demos", "--episodes", "1", "--out", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
