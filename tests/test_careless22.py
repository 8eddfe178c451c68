"""Careless calls, session 25 (issues 13, 11): each test failed on the code before its fix.
A log's motion is written out here by hand (a sine in degrees and the same in rad), and an
output folder's expected contents are the files the test itself lists."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_careless21 import _sine_log  # one writer of the sine log (tests/ is on sys.path)

from lowcostdex.gap.logs import read_log
from lowcostdex.gap.trajectory import LogError
from lowcostdex.outdir import MARKER, staged_output


@pytest.mark.parametrize("degrees,hz", [(10.0, 1.0), (9.0, 1.2), (12.0, 0.75)])
def test_smooth_degrees_logs_under_100_deg_s_are_refused_by_their_sustained_speed(
        tmp_path, degrees, hz):
    # peak 2 pi hz A: 63, 68, 57 'rad/s', 99th percentiles under the 100 rad/s limit, values
    # inside 4 pi and no encoder grid: before, each was read as a joint swinging 20-60 rad
    # at up to 75 rad/s, beyond any servo's 40 rad/s (the motor table's fastest, XL330-M077)
    with pytest.raises(LogError, match=r"'qpos:j' moves at up to \d+\.\d+ rad/s and \d+\.?\d* "
                                       r"rad in .* every step faster than 50 rad/s.*degrees.*"
                                       r"numpy.radians"):
        read_log(_sine_log(tmp_path / "deg.csv", degrees, hz))
    log = read_log(_sine_log(tmp_path / "rad.csv", math.radians(degrees), hz))  # rad: read
    assert np.ptp(log.qpos) == pytest.approx(2 * math.radians(degrees), rel=1e-3)
    # a stiff position servo's steps stay accepted: 5.2 rad at 65 rad/s (80 ms, all of it
    # above 50 rad/s but short of a turn), held 1 s between steps
    rows, q = ["time,goal:j,qpos:j"], 0.0
    for i in range(400):
        goal = (2.6, -2.6)[i // 100 % 2]
        q += float(np.clip(goal - q, -0.65, 0.65))
        rows.append(f"{i / 100:.4f},{goal:.6f},{q:.6f}")
    (tmp_path / "arm.csv").write_text("\n".join(rows) + "\n")
    assert np.ptp(read_log(tmp_path / "arm.csv").qpos) == pytest.approx(5.2)


def _write_one(tmp):
    (tmp / "result.txt").write_text("new\n")


def test_an_output_into_the_empty_working_folder_lands_there(tmp_path, monkeypatch):
    # `lowcostdex gap generate --out .` in a new empty folder: before, os.rmdir('.') raised
    # "Invalid argument" after the work, the output left in a hidden ..partial-* folder
    here = tmp_path / "run"
    here.mkdir()
    monkeypatch.chdir(here)
    with staged_output(".", "gap generate") as tmp:
        _write_one(tmp)
    assert sorted(p.name for p in here.iterdir()) == [MARKER, "result.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no .partial left beside


def test_an_output_through_a_link_to_a_folder_lands_in_the_folder(tmp_path):
    # --out runs where runs -> /data/runs: before, an empty target ended in "Not a
    # directory" with a .partial folder left; a previous output moved the link itself into
    # previous/ and the new output became a real folder beside the user's data
    real = tmp_path / "real"
    real.mkdir()
    link = tmp_path / "link"
    link.symlink_to(real, target_is_directory=True)
    with staged_output(link, "gap generate") as tmp:
        _write_one(tmp)
    assert sorted(p.name for p in real.iterdir()) == [MARKER, "result.txt"]
    with staged_output(link, "gap generate") as tmp:  # again: the first kept in previous/
        (tmp / "result.txt").write_text("newer\n")
    assert link.is_symlink() and (real / "result.txt").read_text() == "newer\n"
    (old,) = (real / "previous").iterdir()
    assert (old / "result.txt").read_text() == "new\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "real"]


def test_domain_randomization_joints_typed_as_a_string_show_them_as_a_tuple():
    from lowcostdex.errors import ConfigError
    from lowcostdex.sim.effects import DomainRandomization

    # before: "joints='ff_top' must be a tuple of names, e.g. ('latency',)": an effect's name
    with pytest.raises(ConfigError, match=r"joints='ff_top' must be a tuple of names, e\.g\. "
                                          r"\('ff_top',\)"):
        DomainRandomization(("latency",), "ff_top", {"latency": {"delay": (0.01, 0.02)}})
    with pytest.raises(ConfigError, match=r"effects='latency' must be .*e\.g\. \('latency',\)"):
        DomainRandomization("latency", ("ff_top",))


@pytest.mark.parametrize("delay,words", [
    (float("nan"), r"parameter 'delay' must be finite, got \[nan\]"),
    (-0.01, r"parameter 'delay' = \[-0\.01\] \[s\] is outside its limits \[0, 0\.25\] s"),
    (20.0, r"parameter 'delay' = \[20\.0\] \[s\] is outside its limits \[0, 0\.25\] s"),  # ms
])
def test_an_emulated_robots_effect_object_with_a_value_no_servo_has_is_refused(delay, words):
    # the same values as a dict were refused (AppliedEffect.from_dict); as an object, before:
    # NaN made the emulator's simulation unstable and "reset failed ... off by 60 deg" after
    # four attempts, -0.01 s ran silently, 20 (ms meant) asked for "history buffers"
    from lowcostdex.errors import ConfigError
    from lowcostdex.hardware.robot.backend import as_effects
    from lowcostdex.sim.effects import AppliedEffect

    with pytest.raises(ConfigError, match=rf"effect latency: {words}"):
        as_effects([AppliedEffect("latency", "ff_top", {"delay": delay})])
    (ok,) = as_effects([AppliedEffect("latency", "ff_top", {"delay": 0.02})])
    assert ok.values["delay"].tolist() == [0.02]


def test_a_path_given_as_none_or_a_number_is_an_input_error_naming_it(tmp_path):
    from lowcostdex.algos.policy_files import load_policy
    from lowcostdex.errors import InputError
    from lowcostdex.hands import HandSpec

    # before: os.fspath's bare TypeError "expected str, bytes or os.PathLike object", which
    # the CLI shows as a crash; a TypeError still (PathTypeError is both)
    for call in (lambda: HandSpec.load(None), lambda: load_policy(None)):
        with pytest.raises(InputError, match=r"a file or folder path .* not NoneType: no path "
                                             r"was given"):
            call()
    with pytest.raises(TypeError, match=r"not int 3"):
        HandSpec.load(3)


def _spec_file(path, change):
    import json

    from lowcostdex.hands import dclaw_spec

    raw = json.loads(dclaw_spec().to_json())
    change(raw)
    path.write_text(json.dumps(raw))
    return path


def test_a_hand_spec_file_with_careless_values_is_named(tmp_path, monkeypatch):
    import json

    from lowcostdex.errors import InputError
    from lowcostdex.hands import HandSpec, dclaw_spec

    def sign(raw):
        raw["joints"][0]["calibration"]["sign"] = "-1"

    # before: "calibration sign must be +1 or -1, got -1" for the string "-1"
    with pytest.raises(InputError, match=r"sign must be \+1 or -1, got '-1'"):
        HandSpec.load(_spec_file(tmp_path / "a.json", sign))
    # before: "'NoneType' object is not iterable"; a dict's keys read as joints ("no joints")
    with pytest.raises(InputError, match=r"'aux_joints' must be a JSON list of joint objects "
                                         r"\(\[\] for none\), got NoneType"):
        HandSpec.load(_spec_file(tmp_path / "b.json", lambda r: r.update(aux_joints=None)))
    with pytest.raises(InputError, match=r"'joints' must be a JSON list .* got dict"):
        HandSpec.load(_spec_file(tmp_path / "c.json", lambda r: r.update(joints={})))
    # a spec written as YAML: before only "JSONDecodeError: Expecting value"
    yaml = pytest.importorskip("yaml", reason="PyYAML is not installed (not a dependency; the YAML-file case needs it to write one)")
    monkeypatch.chdir(tmp_path)
    text = yaml.safe_dump(json.loads(dclaw_spec().to_json()))
    (tmp_path / "hand.yaml").write_text(text)
    with pytest.raises(InputError, match=r"it reads as YAML; a hand spec is JSON") as err:
        HandSpec.load(tmp_path / "hand.yaml")
    fix = str(err.value).rsplit(": ", 1)[1]  # what the message says to run works
    exec(fix, {"HandSpec": HandSpec, "json": json, "yaml": yaml, "text": text})
    assert HandSpec.load("hand.json") == dclaw_spec()


def test_an_output_into_the_working_folder_again_keeps_the_folder_in_its_place(tmp_path,
                                                                               monkeypatch):
    # `lowcostdex gap analyze ... --out .` run twice: before, the working folder itself was
    # moved into previous/<time>/, so the shell sat there and `ls` showed the old report
    here = tmp_path / "run"
    here.mkdir()
    monkeypatch.chdir(here)
    with staged_output(".", "gap analyze") as tmp:
        (tmp / "report.md").write_text("first\n")
    inode = here.stat().st_ino
    with staged_output(".", "gap analyze") as tmp:
        (tmp / "report.md").write_text("second\n")
    assert here.stat().st_ino == inode and (here / "report.md").read_text() == "second\n"
    (old,) = (here / "previous").iterdir()
    assert sorted(p.name for p in old.iterdir()) == [MARKER, "report.md"]
    assert (old / "report.md").read_text() == "first\n"
    assert sorted(p.name for p in here.iterdir()) == [MARKER, "previous", "report.md"]


def test_a_trajectory_built_by_hand_with_careless_shapes_is_named_before_writing(tmp_path):
    # the route load_dataset's refusal of arrays names: write_log(path, Trajectory(...));
    # before: IndexError "too many indices" for 1-D arrays, a name string read as its letters
    # ("elbow": five actuators, then IndexError), numpy's "all input arrays must have the same
    # shape" for a short column
    from lowcostdex.gap import write_log
    from lowcostdex.gap.trajectory import Trajectory

    t = np.arange(300) * 0.01
    q = 0.3 * np.sin(2 * t)

    def traj(**change):
        kw = dict(name="arm", time=t, goal=q[:, None], qpos=q[:, None], actuators=("elbow",),
                  joints=("elbow",))
        return Trajectory(**{**kw, **change})

    cases = [({"goal": q}, r"goal has shape \(300,\); it must be \(300, 1\).*for one actuator "
                           r"give goal\[:, None\]"),
             ({"actuators": "elbow"}, r"actuators='elbow' must be a tuple of names, e\.g\. "
                                      r"\('elbow',\)"),
             ({"qpos": q[:-1, None]}, r"qpos has shape \(299, 1\); it must be \(300, 1\)"),
             ({"joints": ("elbow", "wrist")}, r"qpos has shape \(300, 1\); it must be "
                                              r"\(300, 2\).*joints=\('elbow', 'wrist'\)"),
             ({"channels": {"current": np.ones(300)}}, r"channels\['current'\] has shape")]
    for change, words in cases:
        with pytest.raises(LogError, match=words):
            write_log(tmp_path / "arm.csv", traj(**change))
        assert not (tmp_path / "arm.csv").exists()  # nothing half-written
    back = read_log(write_log(tmp_path / "arm.csv", traj()))
    assert back.actuators == ("elbow",) and back.qpos.shape == (300, 1)


@pytest.mark.parametrize("typed,rate", [("1M", 1_000_000), ("1e6", 1_000_000),
                                        ("57.6k", 57_600), ("1_000_000", 1_000_000),
                                        ("57600", 57_600)])
def test_a_bit_rate_is_read_as_people_write_it(typed, rate, capsys):
    from lowcostdex.argtypes import bit_rate
    from lowcostdex.cli import main

    # before: "argument --baud: invalid int value: '1M'" on scan, emulate, calibrate, ...
    assert bit_rate(typed) == rate
    assert main(["scan", "--port", "emulated", "--baud", typed, "--ids", "10"]) == 0
    assert "XH430-W350" in capsys.readouterr().out  # the emulated motor 10 answered


def test_a_bit_rate_that_is_no_number_says_what_to_type(capsys):
    from lowcostdex.cli import USER_ERROR, main

    assert main(["scan", "--port", "emulated", "--baud", "fast"]) == USER_ERROR
    assert ("'fast' is not a bit rate: give bit/s, e.g. 1000000 (1M, the Dynamixel default) or "
            "57600 (57.6k, a new motor's factory rate)") in capsys.readouterr().err


def test_flags_and_scales_typed_as_words_are_refused_not_read_as_true(tmp_path):
    from lowcostdex.algos.train import TrainConfig, train
    from lowcostdex.demonstrations.dataset import load_demos
    from lowcostdex.errors import ConfigError

    # before: resume="no" is truthy, and train went on as a resume; only_successful="false"
    # kept only the successful episodes; angle_scale="deg" reached the grid check and was told
    # "the log is in rad already"
    config = TrainConfig(algo="npg", env_id="lowcostdex/DClawTurnValve-v0", n_iter=1, n_traj=1)
    with pytest.raises(ConfigError, match=r"resume='no' must be True or False"):
        train(config, tmp_path / "run", resume="no")
    assert not (tmp_path / "run").exists()  # refused before anything was written
    with pytest.raises(ConfigError, match=r"only_successful='false' must be True or False"):
        load_demos(tmp_path / "demos.h5", only_successful="false")
    log = _sine_log(tmp_path / "deg.csv", 10.0, hz=0.2)
    for scale in ("deg", 0, float("nan")):
        with pytest.raises(LogError, match=rf"angle_scale={scale!r} must be a positive number "
                                           r"\(math.pi / 180 for degrees"):
            read_log(log, angle_scale=scale)
    with pytest.raises(LogError, match=r"time_scale='ms' must be a positive number \(1e-3"):
        read_log(log, time_scale="ms")
    assert np.ptp(read_log(log, angle_scale=math.pi / 180).qpos) == pytest.approx(
        math.radians(20.0), rel=1e-3)


def test_a_log_path_that_is_not_there_says_what_was_meant(tmp_path):
    from lowcostdex.gap.dataset import load_dataset

    # before: "no such file" alone for each, "is a folder, not a log file" for a folder
    for name in ("log_a.csv", "log_b.csv"):
        _sine_log(tmp_path / name, 0.2)
    cases = [(tmp_path / "log_a", r"no such file; did you mean '.*log_a\.csv'\?"),  # no suffix
             (tmp_path / "LOG_A.CSV", r"did you mean '.*log_a\.csv'\?"),  # another case
             (tmp_path / "log_c.csv", r"did you mean '.*log_[ab]\.csv' or '.*log_[ab]\.csv'\?"),
             (tmp_path / "*.csv", r"a pattern: read_log reads one file; load_dataset"),
             (tmp_path / "day2" / "log_a.csv", r"its folder .*day2 does not exist either"),
             (tmp_path, r"is a folder, not a log file \(read_log reads one file; load_dataset")]
    for path, words in cases:
        with pytest.raises(LogError, match=words):
            read_log(path)
    with pytest.raises(LogError, match=r"log_a: no such file; did you mean '.*log_a\.csv'"):
        load_dataset([tmp_path / "log_a", tmp_path / "log_b.csv"], model="unused.xml")


ARM = ('<mujoco><option timestep="0.002"/><worldbody><body><joint name="j" axis="0 1 0"/>'
       '<geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="0.1"/></body></worldbody>'
       '<actuator><position name="j" joint="j" kp="2"/></actuator></mujoco>')


def test_gap_analyze_given_log_twice_reads_both(tmp_path, capsys):
    from lowcostdex.cli import USER_ERROR, main

    # `--log a.csv --log b.csv`: before, argparse kept the last --log alone and the analysis
    # ran on b.csv without a word (here: refused as too little data from 1 log, not 2)
    (tmp_path / "arm.xml").write_text(ARM)
    a = _sine_log(tmp_path / "a.csv", 0.3, seconds=1.0)
    b = _sine_log(tmp_path / "b.csv", 0.2, seconds=1.0)
    args = ["gap", "analyze", "--model", str(tmp_path / "arm.xml"), "--log", str(a), "--log",
            str(b), "--out", str(tmp_path / "report")]
    assert main(args) == USER_ERROR
    assert "2 episode(s) from 2 log(s)" in " ".join(capsys.readouterr().err.split())
    assert not (tmp_path / "report").exists()


def test_csv_logs_saved_under_another_suffix_are_named_with_the_rename(tmp_path):
    from lowcostdex.gap.log_paths import expand_log_paths

    # before: "unknown log type '.txt'" and "a folder without logs" with no word that the
    # files are the logs, a suffix apart
    logs = tmp_path / "logs"
    logs.mkdir()
    _sine_log(logs / "run1.txt", 0.2)
    _sine_log(logs / "run2.log", 0.2)
    (logs / "notes.txt").write_text("two runs, arm at rest before each\n")
    with pytest.raises(LogError, match=r"unknown log type '\.txt'.*its first line is a CSV log "
                                       r"header: rename it run1\.csv"):
        read_log(logs / "run1.txt")
    with pytest.raises(LogError, match=r"a folder without logs .*run1\.txt, run2\.log read as "
                                       r"CSV logs under another name: rename them \.csv"):
        expand_log_paths(logs)
    with pytest.raises(LogError) as err:
        read_log(logs / "notes.txt")
    assert "rename" not in str(err.value)  # the user's notes are no log


def test_a_names_option_given_twice_keeps_both(tmp_path):
    import argparse

    import mujoco

    from lowcostdex.cli import main

    # before: `lowcostdex model dclaw --fingers ff --fingers mf` wrote a model of mf alone
    # (argparse kept the last); record-log --joints, gap analyze --candidates and main
    # --stages take the same action
    assert main(["model", "dclaw", "--station", "none", "--fingers", "ff", "--fingers", "mf",
                 "--out", str(tmp_path / "two.xml")]) == 0
    model = mujoco.MjModel.from_xml_path(str(tmp_path / "two.xml"))
    joints = sorted(model.joint(i).name for i in range(model.njnt))
    assert joints == ["ff_bottom", "ff_middle", "ff_top", "mf_bottom", "mf_middle", "mf_top"]
    from lowcostdex.argtypes import JoinRepeats

    parser = argparse.ArgumentParser()
    parser.add_argument("--joints", default=None, action=JoinRepeats)
    assert parser.parse_args([]).joints is None
    assert parser.parse_args(["--joints", "ff_top"]).joints == "ff_top"
    assert parser.parse_args(["--joints", "a,b", "--joints=c"]).joints == "a,b,c"


def test_env_kwargs_with_spaces_and_effects_as_a_comma_list_are_read(tmp_path):
    import json

    from lowcostdex.algos.train_cli import _parse_env_kwargs
    from lowcostdex.cli import main

    # before: "success_tol = 0.1" made the key 'success_tol ' ("unknown keyword argument
    # 'success_tol '"), and `gap generate --effect latency,backlash` was "unknown hidden effect
    # 'latency,backlash'" while --candidates takes the same comma list
    assert _parse_env_kwargs(["success_tol = 0.1", " goal_range= [0.5, 1.0]"]) == {
        "success_tol": 0.1, "goal_range": [0.5, 1.0]}
    assert main(["gap", "generate", "--effect", "latency,backlash", "--logs", "1", "--duration",
                 "1", "--out", str(tmp_path / "gen")]) == 0
    truth = json.loads((tmp_path / "gen" / "truth.json").read_text())
    assert [e["effect"] for e in truth["hidden"]] == ["latency", "backlash"]


def test_names_separated_by_spaces_are_named_with_the_comma_list(tmp_path, capsys):
    from lowcostdex.cli import USER_ERROR, main

    # before: "unknown joint 'ff_top ff_middle'; ... did you mean 'ff_middle' or 'th_middle'?"
    # and "unknown D'Claw finger 'ff mf'"
    assert main(["record-log", "--port", "emulated", "--joints", "ff_top ff_middle", "--out",
                 str(tmp_path / "logs")]) == USER_ERROR
    assert ("--joints 'ff_top ff_middle': names are separated by commas, not spaces; type "
            "--joints ff_top,ff_middle") in " ".join(capsys.readouterr().err.split())
    assert main(["model", "dclaw", "--fingers", "ff mf, th", "--out",
                 str(tmp_path / "m.xml")]) == USER_ERROR
    assert "type --fingers ff,mf,th" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # refused before anything was written


@pytest.mark.parametrize("hand,joint,low,high,rad", [
    ("dclaw", "ff_middle", -30.0, 30.0, r"low=-0\.5236, high=0\.5236"),
    ("allegro", "index_1", -10.0, 90.0, r"low=-0\.1745, high=1\.571"),
    ("bench", "bench", -90.0, 90.0, r"low=-1\.571, high=1\.571"),
])
def test_hand_limits_typed_in_degrees_are_named_with_the_radians(hand, joint, low, high, rad):
    import dataclasses

    from lowcostdex.errors import ConfigError
    from lowcostdex.hands import hand_spec

    # before: "span 60.000 rad ... more than its one turn" / "leave the Allegro's joint range"
    # with no word of degrees
    spec = hand_spec(hand)
    with pytest.raises(ConfigError, match=rf"joint {joint}: limits .*\(degrees\? in rad they "
                                          rf"are {rad}\)"):
        dataclasses.replace(spec, joints=tuple(
            dataclasses.replace(j, low=low, high=high) if j.name == joint else j
            for j in spec.joints))


def test_an_emulated_allegro_refusing_a_keyword_leaves_no_can_bus_open(caplog):
    import gc
    import logging

    import gymnasium as gym

    import lowcostdex  # noqa: F401 (registers the ids)
    from lowcostdex.errors import ConfigError

    # before: tracker= (a hardware keyword) was refused after the emulator's and the host's
    # virtual CAN buses were opened, and python-can said "VirtualBus was not properly shut
    # down" for both when they were collected
    caplog.set_level(logging.WARNING)
    with pytest.raises(ConfigError, match=r"unknown keyword argument 'tracker' for backend "
                                          r"'emulated'"):
        gym.make("lowcostdex/AllegroTurnValve-v0", backend="emulated", tracker=lambda: 0.0)
    gc.collect()
    assert "not properly shut down" not in caplog.text


def test_calibrate_on_the_emulator_with_another_hands_spec_names_the_hand(tmp_path, capsys):
    from lowcostdex.cli import USER_ERROR, main
    from lowcostdex.hands import bench_spec

    # before: "motor check failed on emulated:dclaw ... 1 XL330-M288 no reply" (the emulator
    # served the D'Claw for a bench spec), not a word of the hands not matching
    bench_spec().save(tmp_path / "bench.json")
    args = ["calibrate", "--port", "emulated", "--spec", str(tmp_path / "bench.json"), "--out",
            str(tmp_path / "cal.json"), "--yes"]
    assert main(args) == USER_ERROR
    assert ("is the bench hand spec, not dclaw's: --port emulated serves --hand dclaw; give "
            "--hand bench") in " ".join(capsys.readouterr().err.split())
    assert not (tmp_path / "cal.json").exists()


@pytest.mark.parametrize("argv,words", [
    (["gap", "generate", "--duration", "10s"], "'10s' is not a finite number in [1, 3600]; give "
                                                "the number alone, without 's'"),
    (["gap", "analyze", "--model", "m.xml", "--log", "a.csv", "--servo-period", "2ms"],
     "'2ms' is not a finite number in [0, 0.1]; give the number alone, in seconds: 0.002"),
    (["gap", "analyze", "--model", "m.xml", "--log", "a.csv", "--min-gain", "5%"],
     "give the number alone, as a fraction: 0.05"),
    (["gap", "generate", "--logs", "3x"], "'3x' is not an integer in [1, 1000]; give the number "
                                          "alone, without 'x'"),
])
def test_a_number_typed_with_its_unit_is_named_with_the_number_to_type(argv, words, tmp_path,
                                                                       capsys):
    from lowcostdex.cli import USER_ERROR, main

    # before: "'10s' is not a finite number in [1, 3600]" alone
    assert main([*argv, "--out", str(tmp_path / "out")]) == USER_ERROR
    assert words in " ".join(capsys.readouterr().err.split())
    assert not (tmp_path / "out").exists()
