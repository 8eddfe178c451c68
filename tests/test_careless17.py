"""Careless calls and bad inputs, session 21 (careless17): each test's truth is the user's own file
or folder written here (a log in degrees the way a logger writes one: a 4096-tick encoder read and
multiplied by 360/4096), or measured logs (skipped when absent)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from lowcostdex.gap import LogError, read_log

TICK_DEG = 360 / 4096  # one step of a 4096-tick encoder (Dynamixel X, Feetech STS) in degrees


def _servo_log(amplitude_deg: float = 8.0, seconds: float = 10.0, rate: float = 100.0):
    """A position servo following a slow sine (first order, 30 ms), in degrees: goal, the
    joint's angle, its velocity [deg/s]. Written out here, no project code."""
    t = np.arange(int(seconds * rate)) / rate
    goal = amplitude_deg * np.sin(0.7 * t)
    q = np.zeros_like(t)
    for k in range(1, len(t)):
        q[k] = q[k - 1] + (goal[k - 1] - q[k - 1]) * (1 - math.exp(-(t[k] - t[k - 1]) / 0.03))
    v = np.gradient(q, t)
    return t, goal, q, v


def _csv(path: Path, columns: dict[str, np.ndarray]) -> Path:
    rows = "\n".join(",".join(f"{x:.6f}" for x in r) for r in zip(*columns.values(), strict=True))
    path.write_text(",".join(columns) + "\n" + rows + "\n")
    return path


# ------------------------------------------------------------------------------------------------
# a log in degrees that moves less than 4 pi "rad" (12.6 deg): the plausible range passes it


def test_positions_in_degrees_beside_velocities_in_rad_per_s_are_refused(tmp_path):
    """Before: accepted (the joint 'moved' 8 rad). The logged velocity integrates to pi/180 of
    the positions' distance."""
    t, goal, q, v = _servo_log()
    path = _csv(tmp_path / "log.csv", {"time": t, "goal:j": goal, "qpos:j": q,
                                       "qvel:j": np.radians(v)})
    with pytest.raises(LogError, match=r"positions in degrees beside velocities in rad/s\? "
                                       r"write rad: multiply the 'qpos:' and 'goal:' columns by "
                                       r"pi/180"):
        read_log(path)
    ok = _csv(tmp_path / "rad.csv", {"time": t, "goal:j": np.radians(goal),
                                     "qpos:j": np.radians(q), "qvel:j": np.radians(v)})
    read_log(ok)


@pytest.mark.parametrize("step", [TICK_DEG, 0.088, 300 / 1024])
def test_encoder_readings_in_degrees_are_refused_by_their_grid(tmp_path, step):
    """Before: accepted. Ticks times 360/4096 (or the e-manual's 0.088 deg, an AX's 300/1024)
    lie on a grid of that step; the same ticks in rad step by 0.00153 and are accepted. An
    offset on every reading (a calibration) keeps the grid."""
    t, goal, q, _ = _servo_log()
    ticks = np.round(q / step)
    path = _csv(tmp_path / "log.csv", {"time": t, "goal:j": goal,
                                       "qpos:j": ticks * step + 3.17})
    with pytest.raises(LogError, match=r"column 'qpos:j' reads on a grid of .* an encoder read "
                                       r"in degrees\? .* multiply the 'qpos:' and 'goal:' "
                                       r"columns"):
        read_log(path)
    read_log(path, angle_scale=math.pi / 180)  # the same file read as degrees
    tick_rad = 2 * math.pi / 4096
    ok = _csv(tmp_path / "rad.csv", {"time": t, "goal:j": np.radians(goal),
                                     "qpos:j": np.round(np.radians(q) / tick_rad) * tick_rad})
    read_log(ok)


def test_gap_analyze_names_units_deg_for_encoder_readings_in_degrees(tmp_path, capsys):
    """The CLI's option for a log in degrees is said beside the refusal; nothing written."""
    from lowcostdex.cli import main

    t, goal, q, _ = _servo_log()
    log = _csv(tmp_path / "log.csv", {"time": t, "goal:j": goal,
                                      "qpos:j": np.round(q / TICK_DEG) * TICK_DEG})
    model = _hinge(tmp_path, "-1 1")
    out = tmp_path / "report"
    assert main(["gap", "analyze", "--model", str(model), "--log", str(log), "--out",
                 str(out)]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "an encoder read in degrees?" in err and "or pass --units deg" in err
    assert not out.exists()


def test_a_log_in_rad_read_with_units_deg_is_refused(tmp_path):
    """`gap analyze --units deg` on a log already in rad (encoder ticks x 2 pi/4096): before,
    a 2 rad swing was read as 0.066 rad and analysed. The log in degrees (ticks x 360/4096)
    read with it is accepted (test_encoder_readings_in_degrees_are_refused_by_their_grid)."""
    t, goal, q, _ = _servo_log(amplitude_deg=115.0)
    tick = 2 * math.pi / 4096
    path = _csv(tmp_path / "log.csv", {"time": t, "goal:j": np.radians(goal),
                                       "qpos:j": np.round(np.radians(q) / tick) * tick})
    read_log(path)
    with pytest.raises(LogError, match=r"column 'qpos:j' as written reads on a grid of 2 pi/4096 "
                                       r"rad: .* the log is in rad already; leave out --units "
                                       r"deg"):
        read_log(path, angle_scale=math.pi / 180)


def _hinge(tmp_path: Path, joint_range: str, ctrl: str = "") -> Path:
    model = tmp_path / "model.xml"
    model.write_text(f"""<mujoco><compiler angle="radian"/>
  <worldbody><body pos="0 0 0.2">
    <joint name="j" type="hinge" axis="0 1 0" range="{joint_range}"/>
    <geom type="capsule" fromto="0 0 0 0.05 0 0" size="0.01" mass="0.05"/>
  </body></worldbody>
  <actuator><position name="j" joint="j" kp="3" {ctrl}/></actuator>
</mujoco>""")
    return model


def test_a_smooth_log_in_degrees_beyond_the_joint_range_names_degrees(tmp_path):
    """A filtered log (no encoder grid) in degrees on a joint of range +-0.5 rad: before, the
    refusal asked about a "calibration offset or sign"; read as degrees it fits the range."""
    import mujoco

    from lowcostdex.gap.logs import check_against_model

    t, goal, q, _ = _servo_log()
    log = read_log(_csv(tmp_path / "log.csv", {"time": t, "goal:j": goal, "qpos:j": q}))
    model = mujoco.MjModel.from_xml_path(str(_hinge(tmp_path, "-0.5 0.5")))
    with pytest.raises(LogError, match=r"column 'qpos:j' reads .* outside the model's joint "
                                       r"range .* \(degrees\? read as degrees it spans .* inside "
                                       r"the range: multiply"):
        check_against_model(log, model)


def test_goals_in_degrees_beside_positions_in_rad_are_refused_with_a_model(tmp_path):
    """Goals in degrees, positions converted to rad, no ctrlrange on the servo: before,
    accepted (the replay would command 8 rad on a joint of +-0.5). A goal saturating at the
    range (a servo pushed against its stop) is accepted."""
    import mujoco

    from lowcostdex.gap.logs import check_against_model

    t, goal, q, _ = _servo_log()
    model = mujoco.MjModel.from_xml_path(str(_hinge(tmp_path, "-0.5 0.5")))
    log = read_log(_csv(tmp_path / "log.csv", {"time": t, "goal:j": goal,
                                               "qpos:j": np.radians(q)}))
    with pytest.raises(LogError, match=r"column 'goal:j' reads .* beyond joint 'j''s range .* "
                                       r"\(goals in degrees beside positions in rad: read as "
                                       r"degrees the goals span .* multiply the 'goal:' column "
                                       r"by pi/180"):
        check_against_model(log, model)
    pushed = read_log(_csv(tmp_path / "ok.csv", {"time": t, "goal:j": np.radians(goal) * 1.5,
                                                 "qpos:j": np.radians(q)}))
    check_against_model(pushed, model)


def test_measured_logs_in_rad_pass_and_in_degrees_are_told_by_their_grid():
    """The 4096-tick grid on real servo logs (XL330, STS3032, STS3250, MX): none of them in rad
    is called degrees; each one converted to degrees is."""
    from lowcostdex.gap.log_units import RADIAN_GRIDS, degree_grid

    root = Path(os.environ.get("LOWCOSTDEX_MEASURED_DATA")
                or Path(__file__).resolve().parents[2] / "shared" / "data" / "measured")
    if not root.is_dir():
        pytest.skip(f"measured logs absent ({root})")
    seen = 0
    for path in sorted(root.glob("*/*.json")):
        if not path.read_bytes()[:4096].lstrip().startswith(b"{"):
            continue
        head = json.loads(path.read_text())
        if not isinstance(head, dict) or "entries" not in head:
            continue
        q = np.array([e["position"] for e in head["entries"]], dtype=float)
        assert degree_grid(q) == "", path
        assert degree_grid(np.degrees(q)) != "", path
        assert degree_grid(q, RADIAN_GRIDS) != "", path  # as written: rad
        assert degree_grid(np.degrees(q), RADIAN_GRIDS) == "", path
        seen += 1
    assert seen >= 50


# ------------------------------------------------------------------------------------------------
# `lowcostdex main` with no arguments starts the whole ~25-minute job (README's command adds only
# --out runs/main, the default): it runs, and says first what it will do and where it writes


def test_a_bare_main_says_what_it_runs_and_where_it_writes_before_the_first_stage(
        tmp_path, monkeypatch, capsys):
    """Before: the first line was the bus stage's rule; nothing said the default size takes
    ~25 min of CPU nor that it writes runs/main under the working folder. The first stage is
    stopped here as Ctrl-C would stop it (no stage runs in this test)."""
    import lowcostdex.main_job.job as job
    from lowcostdex.cli import main

    def ctrl_c(ctx):
        """stopped by the test"""
        raise KeyboardInterrupt

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(job, "STAGES", (("bus", ctrl_c), *job.STAGES[1:]))
    assert main(["main"]) == 130
    err = capsys.readouterr().err
    plan = (f"lowcostdex main: stages bus, demos, gap, train, report; task valve-target, size "
            f"default (~25 min of CPU on one core), seed 0, on the emulated D'Claw; writing into "
            f"{tmp_path.resolve() / 'runs' / 'main'}/ (--out)")
    assert plan in err  # one line (soft-wrapped: a long path is not folded into two)
    flat = " ".join(err.split())
    assert flat.index(plan) < flat.index("bus: ") < flat.index("stage bus did not finish")
    assert "--size smoke checks every stage" in flat


# ------------------------------------------------------------------------------------------------
# a log folder that also holds the user's own files; a model path that is a folder


def _rad_log(path: Path, shift: int = 0) -> Path:
    t, goal, q, _ = _servo_log()
    tick = 2 * math.pi / 4096
    return _csv(path, {"time": t, "goal:j": np.roll(np.radians(goal), shift),
                       "qpos:j": np.roll(np.round(np.radians(q) / tick) * tick, shift)})


def test_a_log_folder_with_the_users_other_files_reads_the_logs_only(tmp_path):
    """Before: the folder's calibration table (joint,offset) was read as a log: "calib.csv:
    missing column 'time'" and nothing analysed. Now it is left out and said; a README and a
    sub-folder were already passed over. A long CSV with misspelled channel names is still read
    and refused naming them (tests/test_gap_user_inputs.py)."""
    from lowcostdex.gap.dataset import expand_log_paths, load_dataset

    logs = tmp_path / "logs"
    (logs / "old").mkdir(parents=True)
    _rad_log(logs / "log_0.csv")
    _rad_log(logs / "log_1.csv", shift=150)
    (logs / "calib.csv").write_text("joint,offset\nj,0.1\n")
    (logs / "events.csv").write_text("time,event\n0.5,start\n9.0,stop\n")
    (logs / "README.md").write_text("logs of 2026-11-28\n")
    _rad_log(logs / "old" / "log_0.csv", shift=300)
    notes: list[str] = []
    found = expand_log_paths(logs, notes)
    assert [p.name for p in found] == ["log_0.csv", "log_1.csv"]
    assert any("left out calib.csv, events.csv (no 'goal:' or 'qpos:' column and under 20 rows"
               in n for n in notes)
    model = _hinge(tmp_path, "-1.5 1.5")
    assert len(load_dataset([logs], model=model).trajectories) == 2
    only = tmp_path / "tables"
    only.mkdir()
    (only / "calib.csv").write_text("joint,offset\nj,0.1\n")
    with pytest.raises(LogError, match="a folder without logs: its CSV files calib.csv have no "
                                       "'goal:' or 'qpos:' column and under 20 rows"):
        expand_log_paths(only)


def test_a_model_folder_names_the_mjcf_inside_and_an_mjcf_with_includes_loads(tmp_path):
    """`--model model/` of a folder holding arm.xml (which includes parts/body.xml): before,
    "a folder, not an MJCF model file" without the file to give. The include is read relative
    to the model's own folder (MuJoCo's rule), from any working folder."""
    from lowcostdex.gap.dataset import load_dataset

    folder = tmp_path / "model"
    (folder / "parts").mkdir(parents=True)
    (folder / "arm.xml").write_text("""<mujoco><compiler angle="radian"/>
  <include file="parts/body.xml"/>
  <actuator><position name="j" joint="j" kp="3"/></actuator>
</mujoco>""")
    (folder / "parts" / "body.xml").write_text("""<mujoco><worldbody><body pos="0 0 0.2">
    <joint name="j" type="hinge" axis="0 1 0" range="-1.5 1.5"/>
    <geom type="capsule" fromto="0 0 0 0.05 0 0" size="0.01" mass="0.05"/>
  </body></worldbody></mujoco>""")
    log = _rad_log(tmp_path / "log_0.csv")
    with pytest.raises(LogError, match=r"a folder, not an MJCF model file \(\.xml\); it holds "
                                       r"arm\.xml: give the top one, e\.g\. --model .*arm\.xml"):
        load_dataset([log], model=folder)
    assert len(load_dataset([log], model=folder / "arm.xml").trajectories) == 1


# ------------------------------------------------------------------------------------------------
# NaN / inf / "no value" markers in a CSV log's columns


def _one_cell(tmp_path: Path, cell: str, column: int = 2) -> Path:
    t, goal, q, _ = _servo_log()
    rows = [[f"{a:.3f}", f"{b:.6f}", f"{c:.6f}"]
            for a, b, c in zip(t, np.radians(goal), np.radians(q), strict=True)]
    rows[500][column] = cell
    path = tmp_path / "log.csv"
    path.write_text("time,goal:j,qpos:j\n" + "\n".join(",".join(r) for r in rows) + "\n")
    return path


@pytest.mark.parametrize("cell", ["", "nan", "NaN", "#N/A", "NA", "N/A", "n/a", "null", "None",
                                  "<NA>"])
def test_a_missing_value_marker_is_a_failed_read_like_an_empty_cell(tmp_path, cell):
    """pandas.read_csv reads these cells as missing (its default na_values): a spreadsheet's
    #N/A, R's NA, a JSON null, Python's None. Before: an empty cell or 'nan' dropped its row
    with a note, while '#N/A', 'NA', 'N/A', 'null', 'None', '<NA>' refused the whole log
    ("'#N/A' is not a number")."""
    traj = read_log(_one_cell(tmp_path, cell))
    assert len(traj.time) == 999
    assert any("1 row(s) with an empty or NaN value dropped (first: row 500" in n
               for n in traj.meta["notes"])


@pytest.mark.parametrize("cell,column", [("inf", 2), ("-inf", 1), ("Infinity", 2)])
def test_an_infinite_value_is_refused_naming_the_row_and_the_fix(tmp_path, cell, column):
    """An inf is no missing value (an overflow, a logger's sentinel): refused, as before, and
    now with what to write instead."""
    with pytest.raises(LogError, match=r"has 1 NaN/inf values \(first at row 500\): -?inf, an "
                                       r"overflow or a failed read logged as inf\? leave its cell "
                                       r"empty"):
        read_log(_one_cell(tmp_path, cell, column))


# ------------------------------------------------------------------------------------------------
# the Allegro's hardware backend without --port: its port is a CAN channel, not a serial device


@pytest.mark.parametrize("argv", [
    ["record-log", "--hand", "allegro", "--backend", "hardware", "--out", "logs"],
    ["record-demos", "--hand", "allegro", "--backend", "hardware", "--episodes", "1", "--out",
     "demos.h5"],
    ["train", "npg", "--env", "lowcostdex/AllegroTurnValve-v0", "--backend", "hardware",
     "--out", "runs/npg"],
])
def test_the_allegro_on_hardware_without_a_port_is_told_its_can_channel(argv, tmp_path,
                                                                         monkeypatch, capsys):
    """Before: "needs --port (e.g. /dev/ttyUSB0; `lowcostdex scan` lists candidate ports)" -
    a D'Claw's serial device, which the Allegro's commands then refuse, and a scan of Dynamixel
    buses. Nothing is written."""
    from lowcostdex.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "--backend hardware needs --port, the Allegro's CAN channel (e.g. can0; `ip link` " \
           "lists them)" in err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------------
# a demonstration file recorded on the other hand given to a D'Claw training


def test_demos_of_the_allegro_given_to_a_dclaw_training_say_what_to_type(tmp_path, capsys):
    """Before: refused naming both envs only. Now also the two ways on: train the demos' env,
    or the record-demos command for the run's env. Nothing written."""
    import dataclasses

    import gymnasium as gym

    from lowcostdex.cli import main
    from lowcostdex.demonstrations.dataset import save_demos, teacher_episodes
    from lowcostdex.demonstrations.file import DatasetInfo

    env = gym.make("lowcostdex/AllegroTurnValve-v0", max_episode_steps=5)
    try:
        still = np.zeros(env.action_space.shape, np.float32)
        episodes = [dataclasses.replace(e, success=np.ones_like(e.success))  # as if solved
                    for e in teacher_episodes(env, lambda e, obs: still, seeds=range(1),
                                              only_successful=False)]
        save_demos(tmp_path / "allegro.h5", episodes, DatasetInfo.from_env(env, "scripted_teacher"))
    finally:
        env.close()
    out = tmp_path / "run"
    assert main(["train", "dapg", "--demos", str(tmp_path / "allegro.h5"), "--out", str(out),
                 "--n-iter", "1"]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert ("these demonstrations are of another env; this run trains "
            "'lowcostdex/DClawTurnValve-v0': train their env (--env "
            "lowcostdex/AllegroTurnValve-v0; TrainConfig.env_id), or record demonstrations of "
            "lowcostdex/DClawTurnValve-v0 (`lowcostdex record-demos --help` lists each hand's "
            "tasks)") in err
    assert not out.exists()


# ------------------------------------------------------------------------------------------------
# every command's --help: exit 0, and every option taking a number says what it is


def _commands():
    import argparse

    from lowcostdex.cli import build_parser

    def walk(parser, path):
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        yield path, parser
        for sub in subs:
            for name, child in sub.choices.items():
                yield from walk(child, [*path, name])

    return list(walk(build_parser(), []))


def test_every_commands_help_exits_0_and_describes_its_number_options(capsys):
    """Before: `train npg|dapg|ppo --help` listed --gamma, --gae-lambda, --init-log-std, --lam0,
    --lam1, --lr, --clip-coef, --ent-coef (and tvlg's --prior-strength) with no word of what
    they are, their range or default."""
    from lowcostdex.cli import main

    bare = []
    for path, parser in _commands():
        try:
            code = main([*path, "--help"])
        except SystemExit as done:
            code = done.code
        assert code == 0, path
        assert "usage: lowcostdex" in capsys.readouterr().out
        for action in parser._actions:
            numeric = action.type is float or "number" in getattr(action.type, "__name__", "")
            if action.option_strings and numeric and not action.help:
                bare.append(f"{' '.join(path)} {action.option_strings[-1]}")
    assert bare == []


# ------------------------------------------------------------------------------------------------
# a config's refusal names the flag the user typed; `model --out x.urdf`


@pytest.mark.parametrize("argv,said", [
    (["train", "npg", "--n-iter", "0"], "--n-iter: n_iter=0 must be an integer in [1, inf)"),
    (["train", "npg", "--gamma", "2"], "--gamma: gamma=2.0 must be a finite number in [0, 1]"),
    (["train", "ppo", "--lr", "-1"], "--lr: lr=-1.0 must be a finite number in (0, inf)"),
])
def test_a_setting_refused_by_the_config_names_its_flag(argv, said, tmp_path, capsys):
    """Before: "n_iter=0 must be ..." - the config's field, not the flag the user typed."""
    from lowcostdex.cli import main

    assert main([*argv, "--out", str(tmp_path / "run")]) == 2
    assert said in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_model_out_with_another_formats_suffix_is_refused(tmp_path, capsys):
    """Before: `model dclaw --out hand.urdf` wrote MJCF XML into hand.urdf."""
    from lowcostdex.cli import main

    assert main(["model", "dclaw", "--out", str(tmp_path / "hand.urdf")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert f"writes MJCF XML, not URDF; name the file {tmp_path / 'hand.xml'}" in err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------------
# a log of another robot than the model


def test_a_dclaw_log_against_the_allegro_model_names_the_model_to_write(tmp_path, capsys):
    """A D'Claw finger's log (ff_top, ff_middle, ff_bottom, as record-log names them) with the
    Allegro's model: before, "'goal:ff_top': no actuator 'ff_top' in the model; actuators:
    index_0, ..." Now: none of the log's actuators is in the model, and the command writing the
    model of the logged fingers - which the same log then passes."""
    import mujoco

    from lowcostdex.cli import main
    from lowcostdex.gap.logs import check_against_model

    t, goal, q, _ = _servo_log(amplitude_deg=15.0)
    cols = {"time": t}
    for k, joint in enumerate(("ff_top", "ff_middle", "ff_bottom")):
        cols[f"goal:{joint}"] = np.radians(goal) * (1 - 0.2 * k)
        cols[f"qpos:{joint}"] = np.radians(q) * (1 - 0.2 * k)
    log = read_log(_csv(tmp_path / "log_0.csv", cols))
    assert main(["model", "allegro", "--station", "none", "--out", str(tmp_path / "a.xml")]) == 0
    allegro = mujoco.MjModel.from_xml_path(str(tmp_path / "a.xml"))
    with pytest.raises(LogError) as err:
        check_against_model(log, allegro)
    said = str(err.value)
    assert "none of the log's actuators (ff_top, ff_middle, ff_bottom) is in the model" in said
    command = said.split("`")[1]
    assert command == ("lowcostdex model dclaw --station none --fingers ff --out dclaw.xml")
    argv = command.split()[1:-1] + [str(tmp_path / "dclaw.xml")]
    assert main(argv) == 0
    check_against_model(log, mujoco.MjModel.from_xml_path(str(tmp_path / "dclaw.xml")))


def test_record_log_joints_named_twice_are_refused(tmp_path, capsys):
    """Before: `--joints ff_top,ff_top` (a typo for ff_top,ff_middle) recorded ff_top alone."""
    from lowcostdex.cli import main

    out = tmp_path / "logs"
    assert main(["record-log", "--joints", "ff_top,ff_top", "--out", str(out)]) == 2
    assert "--joints ff_top,ff_top names ff_top more than once" in capsys.readouterr().err
    assert not out.exists()
