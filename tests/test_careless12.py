"""Careless calls, session 17 (issue 13). Each test fails on the code before its fix.

- ``calibrate --out dclaw.json`` run a second time (a typo in the name, a pasted command)
  replaced the earlier calibration - measured offsets, kept nowhere else - without a word,
  where ``model --out`` asks for ``--overwrite``.
- a CSV log with a text column of the user's own (a 'mode' or 'note' written beside the
  channels) was refused whole: "row 2, column 'note': 'start' is not a number".

The truths: the file bytes before and after, and the log read against the same log written
without the user's columns.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from lowcostdex.cli import main

sys.path.insert(0, str(Path(__file__).parent))
from cli_check import run_cli  # noqa: E402
from test_bad_inputs import bench_model, csv_text, servo_log  # noqa: E402

_run = run_cli


# ------------------------------------------------------------------------------------------------
# calibrate --out over an earlier calibration


CAL = ["calibrate", "--port", "emulated", "--yes", "--samples", "2"]


def test_calibrate_keeps_an_earlier_calibration_without_overwrite(tmp_path, capsys):
    out = tmp_path / "dclaw.json"
    assert main([*CAL, "--out", str(out)]) == 0
    capsys.readouterr()
    earlier = out.read_bytes()
    code, err = _run([*CAL, "--out", str(out)], capsys)
    assert code == 2
    assert err == (f"lowcostdex calibrate: error: --out {out} already holds a hand spec (an "
                   "earlier calibration?) and is left untouched; give a new file name, or "
                   "--overwrite to replace it")
    assert out.read_bytes() == earlier
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dclaw.json"]  # no temporary left


def test_calibrate_with_overwrite_replaces_a_hand_spec_only(tmp_path, capsys):
    from lowcostdex.hands import HandSpec, dclaw_spec

    out = tmp_path / "dclaw.json"
    out.write_text(dclaw_spec().to_json())
    assert main([*CAL, "--out", str(out), "--overwrite"]) == 0
    assert capsys.readouterr().out.strip().endswith(f"wrote {out}")
    assert HandSpec.load(out).name == "dclaw"
    notes = tmp_path / "notes.json"
    notes.write_text('{"todo": [1, 2]}')
    code, err = _run([*CAL, "--out", str(notes), "--overwrite"], capsys)
    assert code == 2 and "is not a hand spec; it is left untouched" in err
    assert notes.read_text() == '{"todo": [1, 2]}'


# ------------------------------------------------------------------------------------------------
# a CSV log with text columns of the user's own


def _with_text_columns(text: str) -> str:
    """``text`` with a 'mode' and a 'note' column: words in some rows, empty in others."""
    lines = text.splitlines()
    out = [lines[0] + ",mode,note"]
    for i, line in enumerate(lines[1:]):
        out.append(line + (",hold," if i % 50 else ",step,pushed by hand then let go"))
    return "\n".join(out) + "\n"


def test_a_text_column_of_the_users_own_is_left_out_with_a_note(tmp_path):
    from lowcostdex.gap.logs import read_log

    clean = tmp_path / "clean.csv"
    clean.write_text(csv_text(servo_log()))
    noted = tmp_path / "run.csv"
    noted.write_text(_with_text_columns(clean.read_text()))
    a, b = read_log(clean), read_log(noted)
    for name in ("time", "goal", "qpos"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    np.testing.assert_array_equal(a.channels["current"], b.channels["current"])
    assert b.meta["notes"] == [
        "run.csv: column 'mode' holds text ('step' in row 2), not a log channel; left out",
        "run.csv: column 'note' holds text ('pushed by hand then let go' in row 2), not a log "
        "channel; left out"]


def test_the_dataset_reads_it_and_says_so(tmp_path):
    from lowcostdex.gap.dataset import load_dataset

    (tmp_path / "bench.xml").write_text(bench_model())
    (tmp_path / "run.csv").write_text(_with_text_columns(csv_text(servo_log())))
    ds = load_dataset([tmp_path / "run.csv"], tmp_path / "bench.xml")
    assert any("column 'note' holds text" in n for n in ds.notes)


@pytest.mark.parametrize("column", ["time", "goal:arm", "QPOS : arm", "current:arm"])
def test_text_in_a_channel_is_still_refused_naming_the_row(column, tmp_path):
    """A word in a channel is a broken row, not a user's note: refused as before."""
    from lowcostdex.gap.logs import LogError, read_log

    cols = servo_log()
    text = csv_text(cols)
    lines = text.splitlines()
    header = lines[0].split(",")
    c = header.index(column.replace(" ", "").lower() if ":" in column else column)
    header[c] = column
    row = lines[11].split(",")
    row[c] = "ERR"
    lines[0], lines[11] = ",".join(header), ",".join(row)
    path = tmp_path / "run.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(LogError) as err:
        read_log(path)
    assert str(err.value) == f"{path}: row 12, column {column!r}: 'ERR' is not a number"


# ------------------------------------------------------------------------------------------------
# a number in the other unit: the option's range said, not the unit it is in


@pytest.mark.parametrize("argv, line", [
    (["gap", "analyze", "--log", "x.csv", "--out", "r", "--servo-period", "1"],
     "argument --servo-period: '1' is not a finite number in [0, 0.1]; in seconds: 1 ms is "
     "0.001"),
    (["gap", "analyze", "--log", "x.csv", "--out", "r", "--min-gain", "5"],
     "argument --min-gain: '5' is not a finite number in (0, 1); a fraction: 5 % is 0.05"),
    (["emulate", "--drop", "5"],
     "argument --drop: '5' is not a finite number in [0, 1]; a fraction: 5 % is 0.05"),
    (["transfer", "--out", "t", "--start-range", "30"],
     "argument --start-range: '30' is not a finite number in [0, 3.14159]; in radians: 30 deg "
     "is 0.5236"),
    (["calibrate", "--port", "/dev/ttyUSB0", "--out", "c.json", "--latency-ms", "0.016"],
     "argument --latency-ms: '0.016' is not a finite number in [0.5, 1000]; in milliseconds: "
     "0.016 s is 16"),
])
def test_a_number_in_the_other_unit_is_refused_naming_the_conversion(argv, line, tmp_path,
                                                                     monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, err = _run(argv, capsys)
    assert code == 2
    assert line in err and len(err.splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv", [["gap", "analyze", "--log", "x.csv", "--out", "r",
                                   "--servo-period", "500"],
                                  ["emulate", "--drop", "150"]])
def test_no_conversion_is_offered_where_none_fits(argv, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code, err = _run(argv, capsys)
    assert code == 2 and " is " in err and ";" not in err.split("is not a finite number")[1]


# ------------------------------------------------------------------------------------------------
# gap analyze --holdout read as --log is (a folder, a quoted pattern), as gap identify reads it


def _three_logs(tmp_path: Path) -> None:
    (tmp_path / "bench.xml").write_text(bench_model())
    (tmp_path / "logs").mkdir()
    for i in range(3):
        (tmp_path / "logs" / f"run{i}.csv").write_text(csv_text(servo_log(seconds=4.0 + i)))


@pytest.mark.parametrize("holdout", ["logs/*.csv", "logs"])
def test_a_holdout_pattern_or_folder_is_read_as_the_logs_are(holdout, tmp_path, monkeypatch,
                                                             capsys):
    """Every log held out: refused for holding out all (the pattern was read), not "--holdout
    logs/*.csv is not among the logs" (before); nothing is written."""
    monkeypatch.chdir(tmp_path)
    _three_logs(tmp_path)
    code, err = _run(["gap", "analyze", "--model", "bench.xml", "--log", "logs/*.csv",
                      "--holdout", holdout, "--out", "report"], capsys)
    assert code == 2
    assert err.splitlines()[-1] == (
        "lowcostdex gap analyze: error: the held-out logs must leave at least 2 episodes for "
        "fitting and selection, and hold out at least one")
    assert not (tmp_path / "report").exists()


def test_a_missing_holdout_file_is_said_to_be_missing(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    _three_logs(tmp_path)
    code, err = _run(["gap", "analyze", "--model", "bench.xml", "--log", "logs", "--holdout",
                      "logs/run3.csv", "--out", "report"], capsys)
    assert code == 2
    assert err == ("lowcostdex gap analyze: error: --holdout logs/run3.csv: no such file; every "
                   "--holdout file must also be given with --log")
    assert not (tmp_path / "report").exists()


# ------------------------------------------------------------------------------------------------
# time stamps written as dates and times (pandas' to_csv of a DatetimeIndex, ISO 8601 loggers)


def _dated(seconds: float, t0: str, sep: str, zone: str) -> str:
    from datetime import datetime, timedelta

    start = datetime.fromisoformat(t0)
    return (start + timedelta(seconds=float(seconds))).isoformat(sep=sep,
                                                                 timespec="microseconds") + zone


@pytest.mark.parametrize("sep, zone", [(" ", ""), ("T", "Z"), ("T", "+01:00")])
def test_dates_and_times_in_the_time_column_are_read_as_seconds(sep, zone, tmp_path):
    """Before: "row 2, column 'time': '2026-11-28 01:02:03.000000' is not a number"."""
    from lowcostdex.gap.logs import read_log

    cols = servo_log()
    (tmp_path / "clean.csv").write_text(csv_text(cols))
    (tmp_path / "dated.csv").write_text(
        csv_text(cols, time=lambda t: _dated(t, "2026-11-28 23:59:58", sep, zone)))
    a, b = read_log(tmp_path / "clean.csv"), read_log(tmp_path / "dated.csv")
    # the same instants: written to 1 us, read back as POSIX seconds (float64: ~2e-7 s there)
    np.testing.assert_allclose(b.time - b.time[0], a.time, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(a.goal, b.goal)
    np.testing.assert_array_equal(a.qpos, b.qpos)
    first = _dated(0.0, "2026-11-28 23:59:58", sep, zone)
    assert b.meta["notes"][0] == (f"dated.csv: column 'time' holds dates and times ({first!r} "
                                  "in row 2); read as seconds")


def test_dates_under_another_name_say_to_name_the_column_time(tmp_path):
    from lowcostdex.gap.logs import LogError, read_log

    text = csv_text(servo_log(), time=lambda t: _dated(t, "2026-11-28 01:02:03", " ", ""))
    path = tmp_path / "run.csv"
    path.write_text(text.replace("time,", "timestamp,", 1))
    with pytest.raises(LogError) as err:
        read_log(path)
    assert str(err.value) == (
        "run.csv: missing column 'time' [s]; its columns: 'goal:arm', 'qpos:arm', "
        "'current:arm'; name the time stamps' column 'time' (in seconds) (dates and times there "
        "are read as seconds); column 'timestamp' holds text ('2026-11-28 01:02:03.000000' in "
        "row 2), not a log channel; left out")


def test_an_npz_array_of_text_of_the_users_own_is_left_out_too(tmp_path):
    """As the CSV's text column: before, "column 'mode' holds <U4 values, not numbers"."""
    from lowcostdex.gap.logs import LogError, read_log

    cols = servo_log()
    n = len(cols["time"])
    np.savez(tmp_path / "clean.npz", **cols)
    np.savez(tmp_path / "run.npz", **cols, mode=np.array(["hold"] * n), note=np.array([b"x"] * n))
    a, b = read_log(tmp_path / "clean.npz"), read_log(tmp_path / "run.npz")
    np.testing.assert_array_equal(a.qpos, b.qpos)
    np.testing.assert_array_equal(a.goal, b.goal)
    assert b.meta["notes"] == ["run.npz: array 'mode' holds text, not a log channel; left out",
                               "run.npz: array 'note' holds text, not a log channel; left out"]
    np.savez(tmp_path / "bad.npz", **{**cols, "qpos:arm": np.array(["0.1"] * n)})
    with pytest.raises(LogError, match=r"column 'qpos:arm' holds <U3 values, not numbers"):
        read_log(tmp_path / "bad.npz")
