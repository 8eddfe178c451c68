"""Careless calls and logs as users have them, session 18 (issue 13). Each test of a defect fails
on the code before its fix (main 1848272).

- ``calibrate`` without ``--yes`` and ``transfer --port`` without ``--yes``, run from a script,
  a pipe or nohup (stdin closed): an EOFError traceback at the prompt.
- a CSV log saved by a spreadsheet as "Unicode text" (UTF-16, tabs) was refused as "not a text
  CSV file (binary data?)"; one with an accented word in a note column of the user's own, saved
  in the spreadsheet's 8-bit encoding, the same;
- a log from a spreadsheet in a locale whose decimal mark is ',' (columns separated by ';',
  decimal commas) was refused, the user sent to convert it by hand;
- a sensor dropout logged as the last reading (the position held, its logged velocity too) was
  read and replayed as if the joint had stood still.

The truths: the same log written by the test in the project's plain format (numbers to 1e-6),
the rows the test froze, the files in the folder before and after.
"""

from __future__ import annotations

import io
import sys
from pathlib import Path

import numpy as np
import pytest

from lowcostdex.cli import main

sys.path.insert(0, str(Path(__file__).parent))
from cli_check import run_cli  # noqa: E402
from test_bad_inputs import bench_model, csv_text, servo_log, with_velocity  # noqa: E402

_run = run_cli


# ------------------------------------------------------------------------------------------------
# a prompt with nobody at the keyboard


def test_calibrate_from_a_script_says_to_pass_yes(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))  # `lowcostdex calibrate ... < /dev/null`
    out = tmp_path / "dclaw.json"
    code, err = _run(["calibrate", "--port", "emulated", "--samples", "2", "--out", str(out)],
                     capsys)
    assert code == 2
    assert err == ("lowcostdex calibrate: error: calibrate needs a person at the keyboard (stdin "
                   "is closed); with the hand in its zero pose, pass --yes to read it at once")
    assert list(tmp_path.iterdir()) == []


def test_transfer_on_a_robot_from_a_script_says_to_pass_yes(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    monkeypatch.chdir(tmp_path)
    # 'COM3' is a port name the posix port check leaves to the bus: the prompt comes first
    code, err = _run(["transfer", "--port", "COM3", "--out", "runs/t", "--size", "smoke"], capsys)
    assert code == 2
    assert err == ("lowcostdex transfer: error: the robot on COM3 will move and nobody can "
                   "confirm it (stdin is closed); pass --yes to run without asking")
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------------
# spreadsheet exports


def _plain(tmp_path: Path, cols: dict[str, np.ndarray]) -> Path:
    path = tmp_path / "plain.csv"
    path.write_text(csv_text(cols))
    return path


def _same(a, b) -> None:
    for name in ("time", "goal", "qpos"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    if a.qvel is not None or b.qvel is not None:
        np.testing.assert_array_equal(a.qvel, b.qvel)
    assert a.channels.keys() == b.channels.keys()
    for k in a.channels:
        np.testing.assert_array_equal(a.channels[k], b.channels[k])


def test_a_utf16_unicode_text_export_reads_as_the_plain_log(tmp_path):
    from lowcostdex.gap.logs import read_log

    cols = with_velocity(servo_log())
    plain = _plain(tmp_path, cols)
    path = tmp_path / "export.csv"  # Excel's "Unicode text": UTF-16 with its mark, tabs
    path.write_bytes(csv_text(cols, sep="\t").replace("\n", "\r\n").encode("utf-16"))
    _same(read_log(plain), read_log(path))


def test_an_ansi_export_with_an_accent_in_a_note_reads_with_a_note(tmp_path):
    from lowcostdex.gap.logs import read_log

    cols = servo_log()
    plain = _plain(tmp_path, cols)
    lines = plain.read_text().splitlines()
    text = "\n".join([lines[0] + ",note"] + [ln + (",poussé à la main" if i == 3 else ",")
                                             for i, ln in enumerate(lines[1:])]) + "\n"
    path = tmp_path / "ansi.csv"
    path.write_bytes(text.encode("cp1252"))
    tr = read_log(path)
    _same(read_log(plain), tr)
    assert tr.meta["notes"][:2] == [
        "ansi.csv: line 5 is not UTF-8 text (a spreadsheet's ANSI export?); read as Latin-1",
        "ansi.csv: column 'note' holds text ('poussé à la main' in row 5), not a log channel; "
        "left out"]


def test_binary_data_is_still_refused(tmp_path):
    from lowcostdex.gap.logs import LogError, read_log

    path = tmp_path / "scope.csv"
    path.write_bytes(b"time,goal:arm,qpos:arm\n" + bytes(range(256)) * 8)
    with pytest.raises(LogError, match="not a text CSV file"):
        read_log(path)


@pytest.mark.parametrize("decimal", [",", "."])
def test_semicolons_and_decimal_commas_read_as_the_plain_log(decimal, tmp_path):
    from lowcostdex.gap.logs import read_log

    cols = with_velocity(servo_log())
    plain = _plain(tmp_path, cols)
    path = tmp_path / "excel_de.csv"
    text = csv_text(cols).replace(",", ";")
    path.write_text(text.replace(".", decimal), encoding="utf-8-sig")
    tr = read_log(path)
    _same(read_log(plain), tr)
    said = ", decimal commas read as points" if decimal == "," else ""
    assert tr.meta["notes"] == [
        f"excel_de.csv: columns separated by ';' (a spreadsheet's export){said}"]


def test_a_word_in_a_channel_of_a_semicolon_log_is_still_refused(tmp_path):
    from lowcostdex.gap.logs import LogError, read_log

    text = csv_text(servo_log()).replace(",", ";").replace(".", ",")
    lines = text.splitlines()
    # (a word: 'n/a' was the word here until careless17 read pandas' missing-value markers,
    # 'n/a' among them, as an empty cell; tests/test_careless17.py)
    lines[7] = lines[7].split(";", 1)[0] + ";off;" + lines[7].split(";", 2)[2]
    path = tmp_path / "excel_de.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(LogError, match=r"row 8, column 'goal:arm': 'off' is not a number"):
        read_log(path)


def test_gap_analyze_reads_a_semicolon_log(tmp_path, monkeypatch, capsys):
    """The whole command: the log is loaded (the analysis stopped right after loading)."""
    import importlib

    mod = importlib.import_module("lowcostdex.gap.analyze")

    class Loaded(Exception):
        pass

    def loaded(ds, cfg=None, progress=None):
        raise Loaded(ds)

    monkeypatch.setattr(mod, "analyze", loaded)
    (tmp_path / "bench.xml").write_text(bench_model())
    (tmp_path / "run.csv").write_text(csv_text(servo_log()).replace(",", ";").replace(".", ","))
    with pytest.raises(Loaded) as e:
        main(["gap", "analyze", "--model", str(tmp_path / "bench.xml"), "--log",
              str(tmp_path / "run.csv"), "--out", str(tmp_path / "report")])
    assert len(e.value.args[0].trajectories) == 1
    assert "separated by ';'" in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------
# a sensor dropout logged as the last reading


def _dropout(cols: dict[str, np.ndarray], a: int, b: int) -> dict[str, np.ndarray]:
    """Rows a..b-1 repeat row a - 1's position and velocity: a logger that writes the last
    value it read when a read fails."""
    out = {k: v.copy() for k, v in cols.items()}
    for key in ("qpos:arm", "qvel:arm"):
        out[key][a:b] = out[key][a - 1]
    return out


def test_a_dropout_logged_as_the_last_reading_is_refused_naming_the_rows(tmp_path):
    from lowcostdex.gap.logs import LogError, read_log

    cols = with_velocity(servo_log())
    v = cols["qvel:arm"]
    # the truth: a stretch where the first-order lag moves the joint (its logged speed)
    a = int(np.argmax(np.abs(v[100:]) > 1.0)) + 100
    # the held velocity over the 31 rows that read the same (row a - 1 and the 30 copies)
    moved = float(np.sum(np.abs(v[a - 1]) * np.full(30, 0.01)))
    assert moved > 0.05
    path = tmp_path / "dropout.csv"
    path.write_text(csv_text(_dropout(cols, a, a + 30)))
    with pytest.raises(LogError) as e:
        read_log(path)
    msg = str(e.value)
    assert f"column 'qpos:arm' stands still at {cols['qpos:arm'][a - 1]:.6g} rad for 31 rows" in msg
    assert f"rows {a - 1}-{a + 29}, 0-based" in msg
    assert f"moves the motor {moved:.3g} rad away from it" in msg
    assert "a position read that failed, logged as the last value (a dropout)?" in msg


def test_a_dropout_left_empty_is_cut_out_and_read(tmp_path):
    """The fix the refusal names works: the failed reads' cells left empty."""
    from lowcostdex.gap.dataset import load_dataset

    cols = with_velocity(servo_log())
    a = int(np.argmax(np.abs(cols["qvel:arm"][100:]) > 1.0)) + 100
    held = _dropout(cols, a, a + 30)
    for key in ("qpos:arm", "qvel:arm"):
        held[key][a:a + 30] = np.nan
    (tmp_path / "bench.xml").write_text(bench_model())
    (tmp_path / "dropout.csv").write_text(csv_text(held).replace("nan", ""))
    ds = load_dataset([tmp_path / "dropout.csv"], tmp_path / "bench.xml")
    assert sum(len(tr.time) for tr in ds.trajectories) == len(cols["time"]) - 30


def test_a_joint_at_rest_or_stalled_at_one_velocity_count_is_not_a_dropout(tmp_path):
    """A reading that stands still while the logged velocity is 0, or one count (0.024 rad/s)
    through a 3 s stall (real XL330 logs), is physics, not a failed read."""
    from lowcostdex.gap.logs import read_log

    cols = with_velocity(servo_log())
    n = len(cols["time"])
    rest = {k: v.copy() for k, v in cols.items()}
    rest["qpos:arm"][300:600] = rest["qpos:arm"][299]
    rest["qvel:arm"][300:600] = 0.0
    rest["goal:arm"][299:600] = rest["qpos:arm"][299] + 0.01
    (tmp_path / "rest.csv").write_text(csv_text(rest))
    read_log(tmp_path / "rest.csv")
    stall = {k: v.copy() for k, v in rest.items()}
    stall["qvel:arm"][300:600] = 0.229 * 2 * np.pi / 60  # one Present Velocity count
    (tmp_path / "stall.csv").write_text(csv_text(stall))
    assert len(read_log(tmp_path / "stall.csv").time) == n


def test_the_measured_logs_are_not_dropouts():
    """Every BAM raw log of the measured servos reads (they log Present Velocity beside the
    position; a reading stands still at turning points while the velocity filter lags)."""
    import json
    import os

    from lowcostdex.gap.logs import read_log

    root = Path(os.environ.get("LOWCOSTDEX_MEASURED_DATA")
                or Path(__file__).resolve().parents[2] / "shared" / "data" / "measured")
    if not root.is_dir():
        pytest.skip(f"measured logs absent ({root})")
    read = 0
    for path in sorted(root.glob("*/*.json")):
        if not path.read_bytes()[:4096].lstrip().startswith(b"{"):
            continue
        head = json.loads(path.read_text())
        if not isinstance(head, dict) or "entries" not in head:
            continue  # not a raw log (friction or PWM tables)
        read_log(path)
        read += 1
    assert read >= 100


# ------------------------------------------------------------------------------------------------
# logs of different joints in one call

TWO_JOINTS = """<mujoco><compiler angle="radian"/><option timestep="0.002"/><worldbody>
<body name="a"><joint name="j1" axis="0 1 0" range="-2 2" damping="0.1"/>
<geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="0.05"/>
<body name="b" pos="0.1 0 0"><joint name="j2" axis="0 1 0" range="-2 2" damping="0.1"/>
<geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="0.05"/></body></body>
</worldbody><actuator><position name="j1" joint="j1" kp="3"/><position name="j2" joint="j2" kp="3"/>
</actuator></mujoco>"""


def test_logs_of_different_joints_name_each_set_and_the_fix(tmp_path):
    """Before: "one.csv: no goal for actuators ['j2']; ... give a model of the logged joints
    only", advice the other log (of both joints) then breaks."""
    from lowcostdex.gap.dataset import load_dataset
    from lowcostdex.gap.logs import LogError

    cols = servo_log()
    both = {"time": cols["time"], "goal:j1": cols["goal:arm"], "goal:j2": cols["goal:arm"] / 2,
            "qpos:j1": cols["qpos:arm"], "qpos:j2": cols["qpos:arm"] / 2}
    one = {k: v for k, v in both.items() if not k.endswith("j2")}
    (tmp_path / "two.xml").write_text(TWO_JOINTS)
    (tmp_path / "both.csv").write_text(csv_text(both))
    (tmp_path / "one.csv").write_text(csv_text(one))
    with pytest.raises(LogError) as e:
        load_dataset([tmp_path / "both.csv", tmp_path / "one.csv"], tmp_path / "two.xml")
    assert str(e.value) == (
        "the logs are of different joints: both.csv logs j1, j2; one.csv logs j1; one analysis "
        "takes logs of the same joints and actuators: analyse each set on its own (with a model "
        "of its joints), or log every joint in every log")
