"""A user's log files as loggers and people leave them (session 24, lead): the last row of a
logger stopped mid-write, a torque_enable logged as True/False, logs one folder down. Each test
failed on the code before (a refusal naming a row, "'True' is not a number", "a folder without
logs" without a word on where they are)."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from lowcostdex.gap.log_paths import expand_log_paths
from lowcostdex.gap.logs import read_log
from lowcostdex.gap.trajectory import LogError

N = 200  # rows: 2 s at 100 Hz


def _rows(torque=None):
    """A one-joint log written out by hand: a 0.3 rad sine goal and a lagging reading."""
    out = []
    for i in range(N):
        t = i * 0.01
        goal, q = 0.3 * math.sin(2 * t), 0.3 * math.sin(2 * (t - 0.03))
        row = [f"{t:.4f}", f"{goal:.6f}", f"{q:.6f}"]
        if torque is not None:
            row.append(torque[0] if i < 150 else torque[1])
        out.append(",".join(row))
    return out


def _write(path, rows, header="time,goal:j,qpos:j"):
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


def test_a_last_row_cut_short_by_a_stopped_logger_is_dropped_and_said(tmp_path):
    rows = _rows()
    cut = _write(tmp_path / "cut.csv", rows[:-1] + [rows[-1][:9]])  # "1.9900,0." : 2 fields
    whole = read_log(_write(tmp_path / "whole.csv", rows))
    log = read_log(cut)
    assert len(log.time) == N - 1
    np.testing.assert_array_equal(log.qpos, whole.qpos[:-1])
    assert any("last row" in n and "dropped" in n for n in log.meta["notes"])
    middle = _write(tmp_path / "middle.csv", rows[:50] + [rows[50][:9]] + rows[51:])
    with pytest.raises(LogError, match="row 52 has 2 fields, the header has 3"):
        read_log(middle)  # a short row with rows after it is no stopped logger: refused


@pytest.mark.parametrize("words", [("True", "False"), ("TRUE", "FALSE"), ("true", "false"),
                                   ("on", "off")])
def test_torque_enable_logged_as_words_reads_as_the_numbers(tmp_path, words):
    header = "time,goal:j,qpos:j,torque_enable:j"
    as_words = read_log(_write(tmp_path / "w.csv", _rows(words), header))
    as_numbers = read_log(_write(tmp_path / "n.csv", _rows(("1", "0")), header))
    on = np.asarray(as_words.channels["torque_enable"])
    np.testing.assert_array_equal(on, np.asarray(as_numbers.channels["torque_enable"]))
    assert on[:150].min() == 1 and on[150:].max() == 0
    with pytest.raises(LogError, match="'yes' is not a number"):  # not a switch word: refused
        read_log(_write(tmp_path / "y.csv", _rows(("yes", "0")), header))


def test_logs_one_folder_down_are_named_with_what_to_type(tmp_path):
    for day in ("day1", "day2"):
        (tmp_path / "logs" / day).mkdir(parents=True)
        _write(tmp_path / "logs" / day / "a.csv", _rows())
    (tmp_path / "logs" / "README.txt").write_text("two sessions\n")
    with pytest.raises(LogError, match="subfolders day1, day2 hold some") as err:
        expand_log_paths(tmp_path / "logs")
    pattern = str(err.value).rsplit("the pattern '", 1)[1].rstrip("'")
    found = expand_log_paths(pattern)  # what the message says to type works
    assert sorted(p.parent.name for p in found) == ["day1", "day2"]
    shutil.rmtree(tmp_path / "logs" / "day1")
    shutil.rmtree(tmp_path / "logs" / "day2")
    with pytest.raises(LogError) as err:
        expand_log_paths(tmp_path / "logs")
    assert "subfolders" not in str(err.value)
