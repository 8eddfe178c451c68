"""Careless but legitimate inputs to ``lowcostdex gap analyze`` on a user's own rig (the two-joint
arm of tests/gap_user_arm.py: plain MuJoCo, ``general`` servos, 100 Hz ``time.time()`` logs with
a velocity column): each is either read as the clean log it came from (the truth: the file the
plain-MuJoCo rig wrote) or refused with ONE line naming the problem and the fix, exit code 2,
nothing written. The analysis itself is stopped right after loading (these are about inputs).
"""

from __future__ import annotations

import pathlib
import re
import sys

import numpy as np
import pytest

sys.path.insert(0, str(pathlib.Path(__file__).parent))
import gap_user_arm as arm  # noqa: E402
from cli_refusal import assert_refused  # noqa: E402

from lowcostdex.cli import main  # noqa: E402


class Loaded(Exception):
    pass


@pytest.fixture(scope="module")
def user(tmp_path_factory):
    root = tmp_path_factory.mktemp("arm")
    arm.write_user_folder(root, seed=5, n_logs=3, seconds=4.0)  # 3 episodes
    return root


@pytest.fixture
def stop_after_loading(monkeypatch):
    import importlib

    mod = importlib.import_module("lowcostdex.gap.analyze")

    def loaded(ds, cfg=None, progress=None):
        raise Loaded(ds)

    monkeypatch.setattr(mod, "analyze", loaded)


def _folder(tmp_path, user, run_0=None, run_1=None, xml=None):
    (tmp_path / "logs").mkdir()
    for name, text in (("run_0.csv", run_0), ("run_1.csv", run_1), ("run_2.csv", None)):
        (tmp_path / "logs" / name).write_text(text if text is not None else
                                              (user / "logs" / name).read_text())
    (tmp_path / "arm.xml").write_text(xml or arm.user_model())
    return ["gap", "analyze", "--model", str(tmp_path / "arm.xml"), "--log",
            str(tmp_path / "logs"), "--out", str(tmp_path / "out")]


def _load(args, capsys):
    with pytest.raises(Loaded) as e:
        main(args)
    return e.value.args[0], capsys.readouterr().err


def _refused(args, tmp_path, capsys, words):
    assert_refused(args, tmp_path, capsys, words)


def _table(user, name="run_0.csv"):
    header, *rows = (user / "logs" / name).read_text().splitlines()
    return header, rows


def _clean(user, capsys, tmp_path):
    return _load(_folder(tmp_path / "clean", user), capsys)[0]


def test_columns_in_another_order_read_as_the_clean_log(user, tmp_path, capsys,
                                                        stop_after_loading):
    """One log's columns in another order (qpos first, elbow before shoulder, velocities
    between): read as written by the rig; it was refused ('all logs must measure the same
    joints') because its joints came in another order than the other log's."""
    header, rows = _table(user, "run_1.csv")
    perm = [0, 4, 2, 6, 1, 3, 5]  # time, qpos:elbow, goal:elbow, qvel:elbow, goal:shoulder, ...
    cols = header.split(",")
    text = "\n".join([",".join(cols[i] for i in perm)]
                     + [",".join(r.split(",")[i] for i in perm) for r in rows]) + "\n"
    ds, err = _load(_folder(tmp_path, user, run_1=text), capsys)
    (tmp_path / "clean").mkdir()
    clean = _clean(user, capsys, tmp_path)
    assert ds.joints == clean.joints == arm.JOINTS and ds.actuators == clean.actuators
    for a, b in zip(ds.trajectories, clean.trajectories, strict=True):
        for f in ("time", "goal", "qpos", "qvel"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


def test_a_half_second_hole_mid_log_splits_it_and_the_second_piece_keeps_its_motion(
        user, tmp_path, capsys, stop_after_loading):
    """0.5 s of rows dropped 2 s into a log (a USB hiccup): two pieces, said in a note, each
    the rig's own rows; positions only (no qvel column, as LeRobot logs): the piece after the
    hole starts inside the log, where the arm may be moving, so its first velocity is the line
    fit's, never the rest a log's own start may get."""
    header, rows = _table(user)
    keep = [c for c, name in enumerate(header.split(",")) if not name.startswith("qvel:")]
    strip = lambda r: ",".join(r.split(",")[c] for c in keep)  # noqa: E731
    t = np.array([float(r.split(",")[0]) for r in rows])
    a, b = np.searchsorted(t, t[0] + 2.0), np.searchsorted(t, t[0] + 2.5)
    text = "\n".join([strip(header)] + [strip(r) for r in rows[:a] + rows[b:]]) + "\n"
    other = "\n".join(strip(r) for r in (user / "logs" / "run_1.csv").read_text().splitlines())
    args = _folder(tmp_path, user, run_0=text, run_1=other + "\n")
    (tmp_path / "logs" / "run_2.csv").unlink()
    ds, err = _load(args, capsys)
    assert len(ds.trajectories) == 3  # run_0's two pieces, run_1
    note = next(ln for ln in err.splitlines() if "time jumps" in ln)
    assert f"after {t[a - 1] - t[0]:.6g} s into the log (row {a - 1})" in note
    first, second = ds.trajectories[0], ds.trajectories[1]
    np.testing.assert_array_equal(first.time, t[:a])
    np.testing.assert_array_equal(second.time, t[b:])
    assert second.meta.get("mid_log") and not first.meta.get("mid_log")
    from lowcostdex.gap.logs import estimate_velocity

    v = estimate_velocity(second.time, second.qpos, goal=second.goal)
    np.testing.assert_array_equal(second.qvel[0], v[0])


REFUSED = {
    "rows in reverse time order": (
        lambda h, r: [h] + r[::-1], None,
        ["run_0.csv", "'time' must be strictly increasing", "s from the first row",
         "reverse time order: sort them by time"]),
    "one joint renamed in its position column only": (
        lambda h, r: [h.replace("qpos:elbow", "qpos:Elbow")] + r, None,
        ["run_0.csv", "'qvel:elbow' without 'qpos:elbow'", "shoulder, Elbow",
         "after the same joint of the model"]),
    "a damper actuator beside the elbow's servo": (
        lambda h, r: [h] + r, ("</actuator>", '  <velocity name="elbow_damp" joint="elbow" '
                                              'kv="0.3"/>\n  </actuator>'),
        ["'elbow_damp' drives the joint of the logged actuator 'elbow'",
         "no 'goal:elbow_damp' column", "kv on the <position>", "biasprm[2]"]),
    "a feed-forward motor beside the elbow's servo": (
        lambda h, r: [h] + r, ("</actuator>", '  <motor name="elbow_ff" joint="elbow"/>\n'
                                              '  </actuator>'),
        ["'elbow_ff' drives the joint of the logged actuator 'elbow'", "remove it",
         "log its command"]),
    "positions logged under the servos' names, the joints named otherwise": (
        lambda h, r: [h] + r, ('joint="elbow"', 'joint="elbow_joint"'),
        ["run_0.csv", "'qpos:elbow': no joint 'elbow' in the model", "shoulder, elbow_joint",
         "'elbow' is the actuator driving joint 'elbow_joint': name the column "
         "'qpos:elbow_joint'"]),
    "positions in degrees": (
        lambda h, r: [h] + [",".join(c[:3] + [f"{np.degrees(float(x)):.3f}" for x in c[3:5]]
                                     + c[5:]) for c in (x.split(",") for x in r)], None,
        ["run_0.csv", "'qpos:shoulder'", "degrees? write rad", "or pass --units deg"]),
    "velocities in deg/s": (
        lambda h, r: [h] + [",".join(c[:5] + [f"{np.degrees(float(x)):.3f}" for x in c[5:]])
                            for c in (x.split(",") for x in r)], None,
        ["run_0.csv", "'qvel:", "deg/s or rpm? write rad/s", "or pass --units deg"]),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_a_careless_input_is_refused_with_the_fix(case, user, tmp_path, capsys,
                                                   stop_after_loading):
    edit, xml_edit, words = REFUSED[case]
    header, rows = _table(user)
    xml = arm.user_model()
    if xml_edit:
        xml = xml.replace(*xml_edit)
        assert re.search(r"_(damp|ff|joint)\"", xml)
        if "elbow_joint" in xml:  # the joint itself renamed too, the servo keeps its name
            xml = xml.replace('<joint name="elbow"', '<joint name="elbow_joint"')
    args = _folder(tmp_path, user, run_0="\n".join(edit(header, rows)) + "\n", xml=xml)
    _refused(args, tmp_path, capsys, words)


def test_a_second_actuator_logged_on_the_elbow_is_read_with_a_note(user, tmp_path, capsys,
                                                                   stop_after_loading):
    """The damper's command logged too (0 throughout): read, the elbow replayed as modelled
    and said to carry no candidate effect; the shoulder keeps its."""
    xml = arm.user_model().replace(
        "</actuator>", '  <velocity name="elbow_damp" joint="elbow" kv="0.3"/>\n  </actuator>')
    texts = []
    for name in ("run_0.csv", "run_1.csv", "run_2.csv"):
        header, rows = _table(user, name)
        texts.append("\n".join(
            [header.replace("goal:elbow,", "goal:elbow,goal:elbow_damp,")]
            + [",".join(r.split(",")[:3] + ["0"] + r.split(",")[3:]) for r in rows]) + "\n")
    args = _folder(tmp_path, user, *texts[:2], xml=xml)
    (tmp_path / "logs" / "run_2.csv").write_text(texts[2])
    ds, err = _load(args, capsys)
    assert ds.effect_joints == ("shoulder",)
    assert "joint 'elbow' is driven by 2 actuators" in err


def test_a_tendon_driven_elbow_is_read_with_a_note(user, tmp_path, capsys, stop_after_loading):
    xml = arm.user_model().replace(
        "<actuator>", '<tendon><fixed name="elbow_t"><joint joint="elbow" coef="1"/></fixed>'
        '</tendon>\n  <actuator>').replace('<general name="elbow" joint="elbow"',
                                           '<general name="elbow" tendon="elbow_t"')
    ds, err = _load(_folder(tmp_path, user, xml=xml), capsys)
    # gap-tendon (session 29): a joint driven through one tendon's servo carries effects, the
    # servo's on its actuator (before: none, 'driven by tendon elbow_t ... replays as modelled')
    assert ds.effect_joints == ("shoulder", "elbow")
    assert "joint 'elbow' is driven through tendon elbow_t: the servo's effects act on" in err


def _in_degrees(user, name):
    """The rig's log with goal, qpos (deg) and qvel (deg/s) columns in degrees, 6 decimals."""
    header, rows = _table(user, name)
    angle = [c != "time" for c in header.split(",")]
    return "\n".join([header] + [",".join(f"{np.degrees(float(x)):.6f}" if a else x
                                            for x, a in zip(r.split(","), angle, strict=True))
                                   for r in rows]) + "\n"


def test_logs_in_degrees_read_with_units_deg_as_the_rig_wrote_them(user, tmp_path, capsys,
                                                                   stop_after_loading):
    """All three logs in degrees (as LeRobot records angles) with ``--units deg``: the data set
    the rig's rad logs give, to the 6 printed decimals of a degree (1e-6 deg = 1.7e-8 rad)."""
    texts = [_in_degrees(user, f"run_{i}.csv") for i in range(3)]
    args = _folder(tmp_path, user, *texts[:2])
    (tmp_path / "logs" / "run_2.csv").write_text(texts[2])
    ds, err = _load(args + ["--units", "deg"], capsys)
    (tmp_path / "clean").mkdir()
    clean = _clean(user, capsys, tmp_path)
    assert ds.joints == clean.joints
    for a, b in zip(ds.trajectories, clean.trajectories, strict=True):
        np.testing.assert_array_equal(a.time, b.time)
        for f in ("goal", "qpos", "qvel"):
            np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=0, atol=2e-8,
                                       err_msg=f)


def test_units_deg_is_refused_for_a_model_with_a_slide_joint(user, tmp_path, capsys):
    """A slide joint's position is a length: degrees cannot be meant for it."""
    xml = arm.user_model().replace('<joint name="elbow" range="-0.5 2.2"/>',
                                   '<joint name="elbow" range="-0.5 2.2"/>\n          '
                                   '<joint name="slider" type="slide" axis="1 0 0"/>')
    assert "slider" in xml
    args = _folder(tmp_path, user, xml=xml) + ["--units", "deg"]
    _refused(args, tmp_path, capsys, ["--units deg", "slide joints (slider)",
                                      "log angles in rad"])
