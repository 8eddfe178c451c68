"""Bad inputs and careless calls to ``lowcostdex gap analyze`` as an outside user makes them, on
the LEAP-like user's own logs (tests/gap_user_leap.py, plain MuJoCo): each either loads (the
repair said in a note) or stops with ONE line naming the file or column and what to do, exit
code 2, no traceback, nothing written. The analysis itself is stopped right after loading
(these are about the inputs; tests/test_gap_user_leap.py runs it)."""

from __future__ import annotations

import pathlib
import re
import sys

import numpy as np
import pytest

sys.path.insert(0, str(pathlib.Path(__file__).parent))
import gap_user_leap as leap  # noqa: E402
from cli_refusal import assert_refused  # noqa: E402

from lowcostdex.cli import main  # noqa: E402


@pytest.fixture(scope="module")
def user(tmp_path_factory):
    root = tmp_path_factory.mktemp("leap")
    leap.write_user_folder(root, seed=2, n_logs=2, seconds=8.0)
    return root


class Loaded(Exception):
    pass


@pytest.fixture
def stop_after_loading(monkeypatch):
    import importlib

    mod = importlib.import_module("lowcostdex.gap.analyze")  # the module, not the function

    def loaded(ds, cfg=None, progress=None):
        raise Loaded(ds)

    monkeypatch.setattr(mod, "analyze", loaded)


def _table(user):
    lines = (user / "logs" / "run_0.csv").read_text().splitlines()
    return lines[0], lines[1:]


def _cells(rows, f):
    return [",".join(f(r.split(","))) for r in rows]


def _deg(c):
    return c[:5] + [f"{np.degrees(float(x)):.3f}" for x in c[5:]]


def _ticks(c):  # a Dynamixel's present position register: 2048 at the centre, 4096 per turn
    return c[:1] + [f"{2048 + float(x) * 4096 / (2 * np.pi):.0f}" for x in c[1:]]


def _ms(c):
    return [f"{float(c[0]) * 1e3:.1f}"] + c[1:]


def _us_from_start(c):
    return [f"{(float(c[0]) - leap.EPOCH) * 1e6:.0f}"] + c[1:]


REFUSED = {
    # name: (edit of (header, rows) -> lines, model edit or None, words the one line must hold)
    "time in ms (epoch)": (lambda h, r: [h] + _cells(r, _ms), None,
                           ["run_0.csv", "'time'", "ms?", "divide the time stamps by 1e+03"]),
    "time in us from the start": (lambda h, r: [h] + _cells(r, _us_from_start), None,
                                  ["run_0.csv", "'time'", "us?", "1e+06"]),
    "positions in degrees": (lambda h, r: [h] + _cells(r, _deg), None,
                             ["run_0.csv", "'qpos:if_", "degrees? write rad"]),
    "positions in ticks": (lambda h, r: [h] + _cells(r, _ticks), None,
                           ["run_0.csv", "raw encoder ticks? write rad"]),
    "a joint's column missing": (
        lambda h, r: [h.replace(",qpos:if_dip", "")] + _cells(r, lambda c: c[:-1]), None,
        ["run_0.csv", "'qpos:if_dip'", "log its position too"]),
    "time column named timestamp": (lambda h, r: [h.replace("time,", "timestamp,")] + r, None,
                                    ["run_0.csv", "'timestamp'", "name the time stamps' column "
                                     "'time' (in seconds)"]),
    "LeRobot-style names": (
        lambda h, r: [h.replace("time,", "timestamp,").replace("goal:", "action.").replace(
            "qpos:", "observation.state.")] + r, None, ["run_0.csv", "missing column 'time'"]),
    "underscore instead of colon": (
        lambda h, r: [h.replace("qpos:", "qpos_").replace("goal:", "goal_")] + r, None,
        ["run_0.csv", "'goal_if_abd' is not '<kind>:<name>'", "rename it"]),
    "joint names not the MJCF's": (lambda h, r: [h.replace("if_", "joint_")] + r, None,
                                   ["run_0.csv", "no actuator 'joint_abd'",
                                    "actuators: if_abd, if_mcp, if_pip, if_dip"]),
    "same time twice, other values": (
        lambda h, r: [h] + r[:100] + [r[101].split(",")[0] + "," + r[100].split(",", 1)[1]]
        + r[101:], None, ["run_0.csv", "'time' must be strictly increasing", "row 101"]),
    "motor actuators": (lambda h, r: [h] + r, (r"<position ([^>]*) kp=\"3\" [^>]*/>",
                                               r'<motor \1 ctrlrange="-0.5 0.5"/>'),
                        ["run_0.csv", "is a motor", "model the servo as <position kp=...>"]),
    "velocity actuators": (lambda h, r: [h] + r, (r"<position ([^>]*) kp=\"3\" [^>]*/>",
                                                  r'<velocity \1 kv="0.5"/>'),
                           ["run_0.csv", "velocity servo", "<position kp=...>"]),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_a_careless_input_stops_with_one_line(case, user, tmp_path, capsys, stop_after_loading):
    _refused(case, *REFUSED[case], user, tmp_path, capsys)


def test_a_two_second_log_alone_stops_with_one_line(user, tmp_path, capsys):
    """Loaded, then refused by the split (one episode; fit, select and test need three)."""
    _refused("a 2-second log alone", lambda h, r: [h] + r[:100], None,
             ["too little data: 1 episode(s) from 1 log(s), 1.98 s in all", "longer or more logs"], user, tmp_path, capsys)


def _refused(case, edit, model_edit, words, user, tmp_path, capsys):
    header, rows = _table(user)
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "run_0.csv").write_text("\n".join(edit(header, rows)) + "\n")
    if case != "a 2-second log alone":
        (tmp_path / "logs" / "run_1.csv").write_bytes((user / "logs" / "run_1.csv").read_bytes())
    xml = (user / "leap_finger.xml").read_text()
    if model_edit:
        xml = re.sub(*model_edit, xml)
    (tmp_path / "m.xml").write_text(xml)
    assert_refused(["gap", "analyze", "--model", str(tmp_path / "m.xml"), "--log",
                    str(tmp_path / "logs"), "--out", str(tmp_path / "out")], tmp_path, capsys,
                   words)


def _load(tmp_path, files, user, capsys):
    (tmp_path / "logs").mkdir()
    for name, text in files.items():
        (tmp_path / "logs" / name).write_text(text)
    with pytest.raises(Loaded) as e:
        main(["gap", "analyze", "--model", str(user / "leap_finger.xml"), "--log",
              str(tmp_path / "logs"), "--out", str(tmp_path / "out")])
    return e.value.args[0], capsys.readouterr().err


def test_dropped_rows_on_wall_clock_time_are_said_from_the_logs_start(user, tmp_path, capsys,
                                                                      stop_after_loading):
    """A 1.2 s hole in a log stamped with time.time(): the note said 'after 1.7327e+09 s'."""
    header, rows = _table(user)
    t = [float(r.split(",")[0]) for r in rows]
    ds, err = _load(tmp_path, {"run_0.csv": "\n".join([header] + rows[:200] + rows[260:]),
                               "run_1.csv": (user / "logs" / "run_1.csv").read_text()},
                    user, capsys)
    assert len(ds.trajectories) == 3
    note = next(ln for ln in err.splitlines() if "time jumps" in ln)
    # the hole: from row 199 to the row written after it (row 260 of the original log)
    assert f"{t[260] - t[199]:.3g} s after {t[199] - t[0]:.6g} s into the log (row 199)" in note
    assert "e+09" not in note


def test_repairable_rows_load_with_a_note(user, tmp_path, capsys, stop_after_loading):
    header, rows = _table(user)
    nan_row = rows[50].split(",")[0] + "," + ",".join(["nan"] * 8)
    swapped = rows[:120] + [rows[121], rows[120]] + rows[122:]
    text = "\n".join([header] + rows[:50] + [nan_row] + rows[50:80] + [rows[79]] + swapped[80:])
    ds, err = _load(tmp_path, {"run_0.csv": text, "README.txt": "my LEAP logs, 2026-11-27"},
                    user, capsys)
    assert len(ds.trajectories) == 1 and len(ds.trajectories[0].time) == len(rows)
    assert "NaN value dropped" in err and "repeated row(s) dropped" in err
    assert "out of time order" in err and "Traceback" not in err
    np.testing.assert_array_equal(np.diff(ds.trajectories[0].time) > 0, True)


def test_semicolons_load_as_the_plain_log_with_a_note(user, tmp_path, capsys,
                                                      stop_after_loading):
    """A spreadsheet's ';' separators (and decimal commas) were refused before session 18."""
    header, rows = _table(user)
    text = "\n".join([header.replace(",", ";")] + [x.replace(",", ";").replace(".", ",")
                                                   for x in rows]) + "\n"
    ds, err = _load(tmp_path, {"run_0.csv": text}, user, capsys)
    (tmp_path / "plain").mkdir()
    plain, _ = _load(tmp_path / "plain", {"run_0.csv": "\n".join([header] + rows) + "\n"},
                     user, capsys)
    assert "run_0.csv: columns separated by ';' (a spreadsheet's export), decimal commas read " \
        "as points" in err
    for a, b in zip(ds.trajectories, plain.trajectories, strict=True):
        np.testing.assert_array_equal(a.qpos, b.qpos)
        np.testing.assert_array_equal(a.goal, b.goal)
        np.testing.assert_array_equal(a.time, b.time)


def test_one_test_episode_gets_no_zero_width_gain_interval():
    """A bootstrap over one test episode resamples it and returns [x, x]: the report said
    '95 % CI [26.8, 26.8]' for a single user log. Now no interval, and why."""
    from lowcostdex.gap.gain import gain_with_ci
    from lowcostdex.gap.report import _gain_interval

    one = gain_with_ci([4.0], [1.0], [100], [10.0], [5.0], 1e-6, np.random.default_rng(0))
    assert one.ci95[0] == one.ci95[1]  # the degenerate bootstrap itself
    assert one.to_dict()["ci95"] is None and one.to_dict()["relative_ci95"] is None
    assert _gain_interval(one).startswith("no interval: 1 test episode")
    two = gain_with_ci([4.0, 9.0], [1.0, 1.0], [100, 100], [10.0, 20.0], [5.0, 5.0], 1e-6,
                       np.random.default_rng(0))
    assert two.to_dict()["ci95"][0] < two.to_dict()["ci95"][1]
    assert _gain_interval(two).startswith("95 % CI [")
