"""``record-log`` on both hands and the model command it prints: logs an analysis can read.

A user who records identification logs follows the command's own hint for the model to
replay them with. Until this file, that hint named the whole D'Claw, which the gap analysis
refuses for a one-finger log ("no goal for actuators ..."), and an Allegro owner could not
record logs at all. Truth here: the full models (built the normal way) for the kinematics of a
finger subset, and the analyzer's own log reader for "the logs load against the model".
"""

from __future__ import annotations

import re
import shlex

import mujoco
import numpy as np
import pytest

from lowcostdex.cli import main
from lowcostdex.errors import ConfigError
from lowcostdex.sim.models.allegro import build_allegro

ALLEGRO_INDEX = ("index_0", "index_1", "index_2", "index_3")


def _tip(model: mujoco.MjModel, site: str, q: dict[str, float]) -> np.ndarray:
    data = mujoco.MjData(model)
    for name, value in q.items():
        data.qpos[model.jnt_qposadr[model.joint(name).id]] = value
    mujoco.mj_kinematics(model, data)
    return data.site(site).xpos.copy()


def test_an_allegro_model_of_some_fingers_keeps_their_kinematics_and_actuators():
    full = build_allegro("none").compile()
    part = build_allegro("none", fingers=("thumb", "index")).compile()
    names = [part.actuator(i).name for i in range(part.nu)]
    assert names == [*ALLEGRO_INDEX, "thumb_0", "thumb_1", "thumb_2", "thumb_3"]
    assert part.njnt == 8
    q = {"index_0": 0.2, "index_1": 0.9, "index_2": 0.5, "index_3": 0.3, "thumb_0": 0.8,
         "thumb_1": 0.4, "thumb_2": 0.6, "thumb_3": 0.2}
    for site in ("index_tip", "thumb_tip"):
        np.testing.assert_allclose(_tip(part, site, q), _tip(full, site, q), atol=1e-12)
    for i in range(part.nu):  # same gains and torque limits as the whole hand's actuators
        a = full.actuator(part.actuator(i).name)
        np.testing.assert_allclose(part.actuator_gainprm[i, 0], a.gainprm[0])
        np.testing.assert_allclose(part.actuator_forcerange[i], a.forcerange)


@pytest.mark.parametrize("fingers, words", [
    ("index", "sequence"), ((), "sequence"), (("index", "pinky"), "thumb"),
    (("ring", "ring"), "twice")])
def test_bad_allegro_finger_lists_are_refused_with_the_choices(fingers, words):
    with pytest.raises(ConfigError, match=words):
        build_allegro("none", fingers=fingers)


def test_the_bench_model_has_no_fingers_to_choose(tmp_path, capsys):
    assert main(["model", "bench", "--fingers", "ff", "--out", str(tmp_path / "b.xml")]) == 2
    assert "bench has one joint" in capsys.readouterr().err
    assert not (tmp_path / "b.xml").exists()


def _hinted_model(err: str, out) -> list[str]:
    """The ``lowcostdex model ...`` command record-log printed, writing to ``out``."""
    text = " ".join(err.split())
    found = re.search(r"MODEL\.xml: `(lowcostdex model [^`]+)`", text)
    assert found, text
    argv = shlex.split(found.group(1))[1:]
    argv[argv.index("MODEL.xml")] = str(out)
    return argv


@pytest.mark.parametrize("hand, joints", [
    ("dclaw", ("ff_top", "ff_middle", "ff_bottom")), ("allegro", ALLEGRO_INDEX)])
def test_record_log_hints_a_model_its_logs_load_against(tmp_path, capsys, hand, joints):
    from lowcostdex.gap import load_dataset

    logs = tmp_path / "my logs"
    assert main(["record-log", "--hand", hand, "--logs", "2", "--seconds", "1.5",
                 "--out", str(logs)]) == 0
    xml = tmp_path / "model.xml"
    assert main(_hinted_model(capsys.readouterr().err, xml)) == 0
    paths = sorted(logs.glob("log_*.csv"))
    assert len(paths) == 2
    ds = load_dataset([str(p) for p in paths], model=str(xml))  # raises on a mismatch
    for traj in ds.trajectories:
        assert traj.actuators == joints and traj.joints == joints
        assert np.all(np.isfinite(traj.qpos))
        moved = traj.qpos.max(0) - traj.qpos.min(0)
        assert np.all(moved > 0.05), moved  # every logged joint was excited
        assert np.all(np.diff(traj.time) > 0)


def test_allegro_logs_follow_their_goals_on_the_emulated_hand(tmp_path):
    """The emulated Allegro's joints track the excitation (a held goal is reached within the
    soft PD's steady-state error), so the log is of a hand that moved as commanded."""
    from lowcostdex.gap import read_log

    assert main(["record-log", "--hand", "allegro", "--logs", "1", "--seconds", "4",
                 "--rate", "50", "--out", str(tmp_path)]) == 0
    traj = read_log(tmp_path / "log_0.csv")
    held = np.abs(np.diff(traj.goal, axis=0)) < 1e-9  # (T-1, n)
    errors = []
    for j in range(held.shape[1]):  # rows ending a hold of >= 0.4 s (20 rows) of joint j
        ends = [k + 1 for k in range(20, len(held)) if held[k - 20:k, j].all()]
        errors += list(np.abs(traj.qpos[ends, j] - traj.goal[ends, j]))
    assert len(errors) > 10, "the excitation held hardly any goal for 0.4 s"
    assert np.median(errors) < 0.1, np.median(errors)


@pytest.mark.parametrize("argv, words", [
    (["--hand", "allegro", "--latency-ms", "16"], "CAN"),
    (["--hand", "allegro", "--joints", "ff_top"], "index_0"),
    (["--joints", " , "], "no joint"),
])
def test_record_log_refuses_options_of_the_other_hand(tmp_path, argv, words, capsys):
    code = main(["record-log", *argv, "--logs", "1", "--seconds", "1",
                 "--out", str(tmp_path / "out")])
    assert code == 2
    assert words in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
