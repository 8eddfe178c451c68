"""Careless calls, session 27 (issues 13, 11): each test failed on the code before its fix. The
physics a test needs is written out here in plain MuJoCo; a command is run as a user types it."""

from __future__ import annotations

import pytest

from lowcostdex.cli import USER_ERROR, main
from lowcostdex.errors import ConfigError


@pytest.mark.parametrize("extra,named", [(["--bc-epochs", "50"], "--bc-epochs"),
                                         (["--bc-log-std", "keep"], "--bc-log-std")])
def test_npg_refuses_clone_settings_without_a_clone(tmp_path, capsys, extra, named):
    # before: npg without --demos --bc-init made no clone and dropped the option unsaid
    out = tmp_path / "run"
    code = main(["train", "npg", "--out", str(out), "--n-iter", "1", "--no-progress", *extra])
    err = capsys.readouterr().err
    assert code == USER_ERROR, err
    assert f"{named}: settings of the behaviour clone, which npg makes only with --demos PATH " \
           "--bc-init" in err
    assert "Traceback" not in err and not out.exists()


_ARM = """<mujoco><worldbody><body><joint name="j" type="hinge" damping="0.1"/>
<geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0" mass="0.1"/></body></worldbody>
<actuator><position name="a" joint="j" kp="2"/></actuator></mujoco>"""


def test_a_randomization_on_a_joint_the_env_has_not_is_named_even_with_no_effects(tmp_path):
    # before: an extended model with no effect fitted gave a DomainRandomization on joint 'x'
    # that the valve env took without a word (with an effect it was refused), and one string
    # was read letter by letter
    import gymnasium as gym

    import lowcostdex  # noqa: F401  (registers the envs)
    from lowcostdex.gap.extension import load_extended, save_extended

    ext = load_extended(save_extended(tmp_path / "ext", {"arm": _ARM}, []))
    assert ext.domain_randomization("ff_top").joints == ("ff_top",)
    dr = ext.domain_randomization(joints=["x"])
    with pytest.raises(ConfigError, match=r"unknown joint in randomization.joints 'x'; valid "
                                          r"choices: 'ff_top', .*'valve'"):
        gym.make("lowcostdex/DClawTurnValve-v0", randomize=dr)
    gym.make("lowcostdex/DClawTurnValve-v0", randomize=ext.domain_randomization(["ff_top"])
             ).close()


@pytest.mark.parametrize("actuator,kind", [
    ('<position joint="j" kp="2"/>', "position"),
    ('<intvelocity joint="j" kp="2" actrange="-1 1"/>', "position"),
    ('<velocity joint="j" kv="1"/>', "velocity"),
    ('<motor joint="j" gear="3"/>', "force"),
    ('<general joint="j" gainprm="1"/>', "force"),
    ('<muscle joint="j" lengthrange="0.1 1"/>', "muscle"),
])
def test_what_an_actuators_input_is_has_one_predicate(actuator, kind):
    # before: load_dataset found the force actuators whose goals --units deg leaves alone by the
    # leading words of a message ('a motor', 'a muscle'); the input kind is now asked of one
    # predicate, and the message is said from it
    import mujoco

    from lowcostdex.gap.log_units import actuator_input, not_a_position_servo

    model = mujoco.MjModel.from_xml_string(_ARM.replace(
        '<position name="a" joint="j" kp="2"/>', actuator))
    assert actuator_input(model, 0) == kind
    assert bool(not_a_position_servo(model, 0)) == (kind != "position")


_TURNTABLE = """<mujoco><compiler angle="radian"/><option timestep="0.001"/>
<worldbody><body><joint name="j" type="hinge" axis="0 0 1" damping="0.2"/>
<geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0" mass="0.1"/></body></worldbody>
<actuator><position name="j" joint="j" kp="3"{force}/></actuator></mujoco>"""


def test_a_log_whose_unit_no_check_can_tell_on_an_unbounded_joint_is_said_to_be_read_as_rad(
        tmp_path):
    # a turntable (no range) on a position servo WITHOUT a force range: a linear system, so the
    # same motion at 57 x the scale replays as well and no rule can tell degrees from rad. Its
    # log, a 0.15 rad 0.5 Hz sine run in plain MuJoCo, written in degrees (8.6 deg): before,
    # read as an 8.6 rad swing without a word; now read the same, with a note that the unit was
    # taken on trust and what lets the analysis check (with a force range it is refused:
    # tests/test_careless23.py)
    import math

    import mujoco
    import numpy as np

    from lowcostdex.gap.dataset import load_dataset

    model = mujoco.MjModel.from_xml_string(_TURNTABLE.format(force=""))
    data = mujoco.MjData(model)
    t = np.arange(0.0, 4.0, 0.01)
    goal = 0.15 * np.sin(np.pi * t)
    q = np.empty_like(t)
    for k, g in enumerate(goal):  # 10 steps per 10 ms log row
        data.ctrl[0] = g
        mujoco.mj_step(model, data, nstep=10)
        q[k] = data.qpos[0]
    rows = ["time,goal:j,qpos:j"] + [f"{a:.2f},{math.degrees(b):.7f},{math.degrees(c):.7f}"
                                     for a, b, c in zip(t, goal, q, strict=True)]
    (tmp_path / "deg.csv").write_text("\n".join(rows) + "\n")
    for force, said in (("", ["actuator 'j' has no forcerange"]),
                        (' forcerange="-0.5 0.5"', None)):
        (tmp_path / "m.xml").write_text(_TURNTABLE.format(force=force).replace(
            'damping="0.2"', 'damping="0"'))  # no damping: no top speed either
        ds = load_dataset([tmp_path / "deg.csv"], model=tmp_path / "m.xml")
        why = "; ".join((said or []) + ["joint 'j' has no damping"])
        assert ds.notes == [f"joint 'j' turns 16.9 rad without a range and its model gives it "
                            f"no top speed ({why}), so a log in degrees could not be told from "
                            "one in rad: its 'qpos' was read as rad (give --units deg if it is "
                            "in degrees); the servo's stall torque as forcerange and the joint's "
                            "damping in the MJCF let the analysis check"]
    (tmp_path / "m.xml").write_text(_TURNTABLE.format(force=""))
    ds = load_dataset([tmp_path / "deg.csv"], model=tmp_path / "m.xml", angle_unit="deg")
    assert ds.notes == [] and np.ptp(ds.trajectories[0].qpos) < 0.31  # its unit given: read


def test_load_datasets_settings_of_the_wrong_type_are_named(tmp_path):
    # before: servo_period=None or '0.002' ended in numpy's "ufunc 'isfinite' not supported for
    # the input types", and bench='no' (a truthy string) read a CSV log as a BAM log
    from lowcostdex.gap.dataset import load_dataset

    (tmp_path / "m.xml").write_text(_ARM)
    (tmp_path / "log.csv").write_text("time,goal:a,qpos:j\n" + "".join(
        f"{k / 100:.2f},{0.3 * (k // 50 % 2):.3f},{0.3 * (k // 50 % 2):.3f}\n"
        for k in range(200)))
    for value in (None, "0.002"):
        with pytest.raises(ConfigError, match=rf"servo period \[s\]={value!r} must be a finite "
                                              r"number in \[0, 0.1\]"):
            load_dataset(tmp_path / "log.csv", model=tmp_path / "m.xml", servo_period=value)
    with pytest.raises(ConfigError, match=r"bench='no' must be True or False"):
        load_dataset(tmp_path / "log.csv", model=tmp_path / "m.xml", bench="no")


@pytest.mark.parametrize("units,added", [("s,rad,rad", ""),
                                         ("ms,deg,deg", "; to read its numbers in the units it "
                                                        "names, add --units deg --time-unit ms")])
def test_a_units_row_under_the_header_is_named_with_what_to_do(tmp_path, units, added):
    # before: "row 2, column 'time': 's' is not a number", the row not named a units row, and
    # the options for a log in degrees or milliseconds not named
    from lowcostdex.gap.log_csv import read_csv
    from lowcostdex.gap.trajectory import LogError

    rows = "".join(f"{k / 100:.2f},0.1,0.1\n" for k in range(30))
    (tmp_path / "log.csv").write_text(f"time,goal:j,qpos:j\n{units}\n{rows}")
    shown = ", ".join(units.split(","))
    with pytest.raises(LogError) as caught:
        read_csv(tmp_path / "log.csv", 100)
    assert str(caught.value) == (
        f"{tmp_path / 'log.csv'}: row 2 holds words under every channel ({shown}), not "
        "numbers: a units row? Delete it: a log's columns carry no units, each kind has its own "
        "(time s, positions rad, velocities rad/s, current A, voltage V)" + added)
    (tmp_path / "log.csv").write_text(f"time,goal:j,qpos:j\n{rows}")  # without it: read
    assert len(read_csv(tmp_path / "log.csv", 100)[0]["time"]) == 30


def test_record_log_of_part_of_a_finger_or_of_no_row_is_refused_before_recording(
        tmp_path, capsys):
    # before: --joints ff_top recorded logs whose offered model (the whole finger) gap analyze
    # then refused ("no goal for actuators ['ff_middle', 'ff_bottom']"); --seconds 0.01 ended
    # in a traceback ("need at least one array to concatenate") after writing the folder
    out = tmp_path / "logs"
    assert main(["record-log", "--port", "emulated", "--joints", "ff_top", "--out",
                 str(out)]) == USER_ERROR
    assert ("--joints ff_top leaves out ff_middle, ff_bottom of the same finger: the gap "
            "analysis replays whole fingers (`lowcostdex model --fingers`) and needs each of "
            "their joints commanded and read; give --joints ff_top,ff_middle,ff_bottom"
            ) in " ".join(capsys.readouterr().err.split())
    assert main(["record-log", "--port", "emulated", "--seconds", "0.01", "--out",
                 str(out)]) == USER_ERROR
    assert ("--seconds 0.01 at --rate 50 Hz is 0 row(s) a log; `gap analyze` reads logs of at "
            "least 20 rows over 0.5 s: give --seconds 1 or more (default 15)"
            ) in " ".join(capsys.readouterr().err.split())
    assert not out.exists()


def test_a_gap_report_of_settings_given_as_numpy_numbers_is_written():
    # before: GapConfig took seed=np.int64(3) (e.g. rng.integers(9)) and top_k=np.int64(2), and
    # report.json's json.dumps refused them after the whole analysis ("Object of type int64 is
    # not JSON serializable")
    import json

    import numpy as np

    from lowcostdex.gap.dataset import Split, Window
    from lowcostdex.gap.gain import Gain
    from lowcostdex.gap.results import GapConfig, GapResult

    eps = [Window(0, 0, 10, 0)]
    res = GapResult(GapConfig(seed=np.int64(3), top_k=np.int64(2), probes=(np.float32(0.01),)),
                    ["a.csv"], ("j0",), Split((0,), (), ()), eps, np.array([0.001]), {}, {}, [],
                    [], {}, Gain(0.01, 0.002, 0.01, 0.002, 0.008, 0.8, (0.0, 0.0), (0.0, 0.0),
                                 0.001, None, 2), [], "v", {}, [], {})
    config = json.loads(json.dumps(res.to_dict()))["config"]
    assert (config["seed"], config["top_k"]) == (3, 2)
    assert config["probes"] == [pytest.approx(0.01)]



def test_a_log_of_more_fingers_than_the_model_gets_the_model_of_its_fingers():
    # before: a log of the D'Claw's ff and mf against a model of ff said only "no actuator
    # 'mf_top' in the model; actuators: ff_top, ff_middle, ff_bottom" (the command that writes
    # the model of both fingers was offered only when no name matched)
    import numpy as np

    from lowcostdex.gap.logs import LogError, Trajectory, check_against_model
    from lowcostdex.sim.models.dclaw import build_dclaw

    model = build_dclaw("none", fingers=("ff",)).compile()
    names = ("ff_top", "ff_middle", "ff_bottom", "mf_top", "mf_middle", "mf_bottom")
    t = np.arange(100) / 100
    q = np.zeros((100, 6))
    log = Trajectory("log.csv", t, q, q.copy(), names, names)
    with pytest.raises(LogError) as caught:
        check_against_model(log, model)
    assert str(caught.value) == (
        "log.csv: 'goal:mf_top': no actuator 'mf_top' in the model; actuators: ff_top, "
        "ff_middle, ff_bottom; the log moves more of the hand than the model holds: its names "
        "are the D'Claw's: `lowcostdex model dclaw --station none --fingers ff,mf --out "
        "dclaw.xml` writes the model of those fingers")


def test_a_list_split_by_a_space_after_a_comma_is_named_with_the_list_to_type(tmp_path, capsys):
    # before: "unrecognized arguments: ff_middle, ff_bottom" and no word of the list the shell
    # split at the spaces
    out = tmp_path / "logs"
    assert main(["record-log", "--port", "emulated", "--joints", "ff_top,", "ff_middle,",
                 "ff_bottom", "--out", str(out)]) == USER_ERROR
    assert ("unrecognized arguments: ff_middle, ff_bottom; --joints ff_top, ff_middle, "
            "ff_bottom: a space after a comma ends the list there; type --joints "
            "ff_top,ff_middle,ff_bottom") in capsys.readouterr().err
    assert main(["main", "--out", str(out), "--stages=bus,", "demos"]) == USER_ERROR
    assert "type --stages=bus,demos" in capsys.readouterr().err
    assert not out.exists()


def test_logs_of_a_hand_given_without_a_model_get_the_model_command(tmp_path):
    # before: "project-format logs need --model MODEL.xml", though a record-log folder's
    # columns name the D'Claw's finger the model command writes
    from lowcostdex.gap.dataset import load_dataset
    from lowcostdex.gap.trajectory import LogError

    names = ("ff_top", "ff_middle", "ff_bottom")
    (tmp_path / "log_0.csv").write_text(
        "time," + ",".join(f"goal:{n},qpos:{n}" for n in names) + "\n"
        + "".join(f"{k / 50:.2f}" + ",0.1,0.1" * 3 + "\n" for k in range(60)))
    with pytest.raises(LogError) as caught:
        load_dataset(tmp_path)
    assert str(caught.value) == (
        "project-format logs need --model MODEL.xml (the MJCF of the robot that wrote them); "
        "its names are the D'Claw's: `lowcostdex model dclaw --station none --fingers ff --out "
        "dclaw.xml` writes the model of those fingers")


def test_hidden_widths_typed_with_commas_are_named_with_the_words_to_type(tmp_path, capsys):
    # before: "argument --hidden: invalid int value: '32,32'"
    out = tmp_path / "run"
    for algo, given, typed in (("npg", "32,32", "type --hidden 32 32"),
                               ("ppo", "64,", "e.g. --hidden 64 64 for two layers of 64")):
        assert main(["train", algo, "--out", str(out), "--hidden", given]) == USER_ERROR
        assert (f"argument --hidden: '{given}': the widths are separated by spaces, not commas: "
                f"{typed}") in capsys.readouterr().err
    assert not out.exists()
