"""Careless calls, session 26 (issues 13, 11): each test failed on the code before its fix. The
physics a test needs is written out here in plain MuJoCo, a killed run is a real process killed
with SIGKILL, and an output folder's expected contents are the files the test itself lists."""

from __future__ import annotations

import importlib.util
import math
import pathlib
import signal
import subprocess
import sys

import mujoco
import numpy as np
import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.outdir import MARKER, PREVIOUS, OutputRefused, staged_output
from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.plant import Plant

ROOT = pathlib.Path(__file__).resolve().parents[1]
_ARM = """<mujoco><worldbody><body><joint name="j" type="hinge" damping="0.1"/>
<geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0" mass="0.1"/></body></worldbody>
<actuator><position name="a" joint="j" kp="2"/></actuator></mujoco>"""


@pytest.mark.parametrize("name,values", [("gain_error", {"scale": math.nan}),
                                         ("coulomb_friction", {"frictionloss": math.inf}),
                                         ("latency", {"delay": -math.inf})])
def test_a_plant_refuses_effect_values_that_are_not_finite(name, values):
    # before: a NaN gain ran into "simulation diverged at t=0.0020s" (no word of the effect),
    # an infinite friction ran silently
    model = mujoco.MjModel.from_xml_string(_ARM)
    with pytest.raises(ConfigError, match=rf"effect {name}: parameter '{next(iter(values))}' "
                                          r"must be finite, got \[-?(nan|inf)\]"):
        Plant(model, [AppliedEffect(name, ("j",), values)])
    plant = Plant(model)
    with pytest.raises(ConfigError, match="must be finite"):
        plant.set_effects([AppliedEffect(name, ("j",), values)])
    # an infinite null (the effect off: a velocity limit's speed) stays accepted
    Plant(model, [AppliedEffect("velocity_limit", ("j",), {})]).step(np.array([0.5]), 10)


_KILLED = """
import sys, time
from lowcostdex.outdir import staged_output
with staged_output(sys.argv[1], "gap analyze") as tmp:
    (tmp / "report.json").write_text("{}")
    print("writing", flush=True)
    time.sleep(60)
"""


def test_a_killed_runs_unfinished_output_is_named_with_what_to_type(tmp_path):
    # before: the next run went ahead and the killed run's hidden .out.partial-* folder stayed
    # beside --out for good, unnamed
    out = tmp_path / "out"
    run = subprocess.Popen([sys.executable, "-c", _KILLED, str(out)], stdout=subprocess.PIPE,
                           text=True)
    try:
        assert run.stdout.readline() == "writing\n"
        # while that run writes, another run into the same folder is not refused
        with staged_output(out, "gap analyze") as tmp:
            (tmp / "report.json").write_text("{}")
    finally:
        run.send_signal(signal.SIGKILL)
        run.wait()
        run.stdout.close()
    (left,) = tmp_path.glob(".out.partial-*")
    with pytest.raises(OutputRefused, match=rf"{left.name} beside it was left by an earlier run "
                                            r"into this folder that was stopped before it "
                                            rf"finished .*rm -r {left}"):
        with staged_output(out, "gap analyze"):
            pass
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "report.json"]  # untouched


def test_a_finished_output_stopped_in_its_last_move_is_put_back_by_the_command_named(tmp_path):
    # killed between moving the old output into the new one's previous/ and moving the new one
    # into place: --out is gone and both outputs sit in the hidden folder (the same moves as
    # outdir.staged_output's, made here by hand); before, the next run wrote a fresh --out
    out = tmp_path / "out"
    with staged_output(out, "gap analyze") as tmp:
        (tmp / "report.json").write_text("{}")
    left = tmp_path / ".out.partial-abc"
    (left / PREVIOUS).mkdir(parents=True)
    (left / MARKER).write_text((out / MARKER).read_text())
    out.rename(left / PREVIOUS / "20261129-050000")
    with pytest.raises(OutputRefused, match=rf"a finished output .* mv {left} {out}"):
        with staged_output(out, "gap analyze"):
            pass


def _demo():
    spec = importlib.util.spec_from_file_location("gap_own_mjcf", ROOT / "demos" / "gap_own_mjcf.py")
    demo = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(demo)
    return demo


def test_the_own_mjcf_demo_runs_again_into_its_own_folder(tmp_path, monkeypatch):
    # before: the demo's second run into runs/gap_own_mjcf (its default) stopped at "--out ...
    # is not empty; give a new folder"; now the earlier run moves into previous/<time>/
    demo = _demo()
    calls = []
    monkeypatch.setattr(demo, "cli_main", lambda argv: calls.append(argv) or 3)  # no analysis
    out = tmp_path / "run"
    monkeypatch.setattr(sys, "argv", ["gap_own_mjcf.py", "--out", str(out)])
    for _ in range(2):
        with pytest.raises(SystemExit) as e:
            demo.main()
        assert e.value.code == 3
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "logs", "model.xml", PREVIOUS]
    (earlier,) = (out / PREVIOUS).iterdir()
    assert sorted(p.name for p in earlier.iterdir()) == [MARKER, "logs", "model.xml"]
    assert len(list((out / "logs").glob("*.csv"))) == 6 and len(calls) == 2


_TURNTABLE = """<mujoco><compiler angle="radian"/><option timestep="0.001"/>
<worldbody><body><joint name="j" type="hinge" axis="0 0 1" damping="0.2"/>
<geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0" mass="0.1"/></body></worldbody>
<actuator><position name="j" joint="j" kp="3" forcerange="-0.5 0.5"/></actuator></mujoco>"""


def test_a_slow_log_in_degrees_on_a_continuous_joint_is_refused_by_its_models_top_speed(
        tmp_path):
    # a turntable (no range) on a position servo, 0.5 N m against 0.2 N m s/rad of damping:
    # under 0.5 N m / 0.2 + gravity's 0.05 / 0.2 = 2.75 rad/s whatever the goal. Its log, a 0.15
    # rad 0.5 Hz sine (0.47 rad/s at its peak), written in degrees: 8.6 deg, 27 deg/s, no grid,
    # no velocities: before, read and accepted as a joint swinging 8.6 rad at 27 rad/s
    from lowcostdex.gap.logs import check_against_model, read_log
    from lowcostdex.gap.trajectory import LogError

    model = mujoco.MjModel.from_xml_string(_TURNTABLE)
    data = mujoco.MjData(model)
    t = np.arange(0.0, 4.0, 0.01)
    goal = 0.15 * np.sin(np.pi * t)
    q = np.empty_like(t)
    for k, g in enumerate(goal):  # plain MuJoCo, 10 steps per 10 ms log row
        data.ctrl[0] = g
        mujoco.mj_step(model, data, nstep=10)
        q[k] = data.qpos[0]
    for unit, scale in (("deg", 180 / math.pi), ("rad", 1.0)):
        rows = ["time,goal:j,qpos:j"] + [f"{a:.2f},{b * scale:.7f},{c * scale:.7f}"
                                         for a, b, c in zip(t, goal, q, strict=True)]
        (tmp_path / f"{unit}.csv").write_text("\n".join(rows) + "\n")
    log = read_log(tmp_path / "deg.csv")  # no sign of its unit in the log alone
    with pytest.raises(LogError, match=r"'qpos:j' moves at \d+\.?\d* rad/s or faster .* x the "
                                       r"fastest its model can drive it.* stop it at 2.7\d rad/s"
                                       r".*in degrees\? .*numpy.radians"):
        check_against_model(log, model)
    check_against_model(read_log(tmp_path / "rad.csv"), model)  # the same log in rad: read


def _slow_sine(path):
    """A 2 s log of the turntable at 100 Hz: a 0.2 rad sine and its reading 0.1 s behind."""
    t = np.arange(0.0, 2.0, 0.01)
    path.write_text("time,goal:j,qpos:j\n" + "".join(
        f"{a:.2f},{0.2 * math.sin(a):.6f},{0.2 * math.sin(a - 0.1):.6f}\n" for a in t))


def test_make_vec_names_the_lowcostdex_id_of_a_bare_env_name():
    # before: gymnasium's "NameNotFound: Environment `DClawTurnValve` doesn't exist." (the ids
    # live under lowcostdex/, as `lowcostdex envs` lists them)
    from lowcostdex.sim.vector import make_vec

    with pytest.raises(ConfigError, match=r"unknown env 'DClawTurnValve-v0'; make_vec batches: "
                                          r".*did you mean 'lowcostdex/DClawTurnValve-v0'"):
        make_vec("DClawTurnValve-v0", num_envs=2)


def test_load_dataset_names_what_to_pass_for_a_compiled_model_or_its_xml_text(tmp_path):
    # before: load_dataset(logs, model=MjModel) ended in Path's bare TypeError, and the XML
    # text itself in "<mujoco ...(the whole text)...: no such model file"
    from lowcostdex.gap import load_dataset
    from lowcostdex.gap.trajectory import LogError

    (tmp_path / "m.xml").write_text(_TURNTABLE)
    _slow_sine(tmp_path / "a.csv")
    log = [tmp_path / "a.csv"]
    for model, said in ((mujoco.MjModel.from_xml_string(_TURNTABLE), "not MjModel; save it"),
                        (mujoco.MjSpec.from_string(_TURNTABLE), "not MjSpec; save it"),
                        (_TURNTABLE, "not its XML text; write the text to a file")):
        with pytest.raises(LogError, match=rf"model: give the MJCF file's path.*{said}"):
            load_dataset(log, model=model)
    assert load_dataset(log, model=tmp_path / "m.xml").trajectories[0].joints == ("j",)


def test_an_emulated_robots_faults_given_as_a_dict_are_read_as_its_settings():
    # before: gym.make(..., backend="emulated", faults={"drop": 0.1}) ended in "AttributeError:
    # 'dict' object has no attribute 'any'" (robot_config and reset_config took dicts), and
    # FaultConfig(drop="0.1") in a TypeError comparing a str
    import gymnasium as gym

    import lowcostdex  # noqa: F401  (registers the ids)
    from lowcostdex.hardware.emulated.chain import FaultConfig

    env = gym.make("lowcostdex/DClawTurnValve-v0", backend="emulated", faults={"drop": 0.1})
    try:
        assert env.unwrapped.backend.chain.faults == FaultConfig(drop=0.1)
    finally:
        env.close()
    with pytest.raises(ConfigError, match=r"FaultConfig setting 'dorp'.*drop"):
        gym.make("lowcostdex/DClawTurnValve-v0", backend="emulated", faults={"dorp": 0.1})
    with pytest.raises(ConfigError, match=r"fault probability drop='0.1' must be a finite number "
                                          r"in \[0, 1\]"):
        FaultConfig(drop="0.1")


def test_resume_into_a_folder_without_a_checkpoint_says_a_new_run_starts(tmp_path, capsys):
    # before: train(config, "runs/npx", resume=True) (a misspelt run folder) started a new run
    # from iteration 0 without a word; the trainers call load_latest with log=print
    from lowcostdex.algos.experiment import Run

    run = Run.open(tmp_path / "npx", config={"algo": "npg", "seed": 0}, resume=True)
    try:
        assert run.load_latest() is None
    finally:
        run.close()
    assert capsys.readouterr().out.startswith(f"nothing to resume in {tmp_path / 'npx'} (no "
                                              "checkpoint saved there): a new run starts at "
                                              "iteration 0")


def test_time_unit_ms_on_a_log_in_seconds_says_to_leave_it_out(tmp_path, capsys):
    # before: "column 'time' must be in seconds, but its median step is 1e-05 s (a 1e+05 Hz
    # log)" with no word of the --time-unit ms that made it so
    from lowcostdex.cli import main

    (tmp_path / "m.xml").write_text(_TURNTABLE)
    _slow_sine(tmp_path / "a.csv")
    code = main(["gap", "analyze", "--model", str(tmp_path / "m.xml"), "--log",
                 str(tmp_path / "a.csv"), "--out", str(tmp_path / "r"), "--time-unit", "ms"])
    assert code == 2 and not (tmp_path / "r").exists()
    assert capsys.readouterr().err.endswith(
        "read as ms (--time-unit ms): if 'time' is in seconds already, leave out --time-unit\n")


def test_load_extended_reads_the_folder_of_its_effects_json(tmp_path):
    # README's --effects takes report/extended/effects.json; before, load_extended of that very
    # file said "effects.json: no effects.json (not an extended model folder)"
    from lowcostdex.gap import load_extended, save_extended

    save_extended(tmp_path / "extended", {"model": _TURNTABLE},
                  [AppliedEffect("latency", ("j",), {"delay": 0.01})])
    ext = load_extended(tmp_path / "extended" / "effects.json")
    assert [e.name for e in ext.effects] == ["latency"]
    with pytest.raises(ConfigError, match=r"nope: no such folder \(not an extended model folder"):
        load_extended(tmp_path / "nope")


def test_effects_options_read_a_gap_reports_folder_or_its_report_json(tmp_path):
    # `lowcostdex emulate dclaw --effects report` (or report/report.json): before, "[Errno 21]
    # Is a directory" and "must hold a JSON list of effects ..., got dict"
    from lowcostdex.errors import InputError
    from lowcostdex.gap import save_extended
    from lowcostdex.sim.effects.randomization import read_effects

    report = tmp_path / "report"
    save_extended(report / "extended", {"model": _TURNTABLE},
                  [AppliedEffect("latency", ("j",), {"delay": 0.01})])
    (report / "report.json").write_text("{}")
    for given in (report, report / "report.json", report / "extended"):
        assert [e.name for e in read_effects(str(given))] == ["latency"]
    with pytest.raises(InputError, match="a folder without effects.json"):
        read_effects(str(tmp_path))


def test_emulate_bench_refuses_a_station_it_has_not(tmp_path):
    # before: `lowcostdex emulate bench --station valve` served the one-servo bench and dropped
    # the station unsaid (a subprocess with a timeout: the old code serves until stopped)
    run = subprocess.run([sys.executable, "-m", "lowcostdex.cli", "emulate", "bench",
                          "--station", "valve", "--quiet"], capture_output=True, text=True,
                         timeout=60, cwd=tmp_path)
    assert run.returncode == 2 and "Traceback" not in run.stderr
    assert "--station valve: the bench is one servo and its arm, with no station" in run.stderr


def test_record_log_on_the_allegro_refuses_a_dynamixel_bit_rate(tmp_path, capsys):
    # before: `record-log --hand allegro --baud 57600` recorded on CAN, the bit rate dropped
    from lowcostdex.cli import main

    code = main(["record-log", "--hand", "allegro", "--port", "emulated", "--baud", "57600",
                 "--logs", "1", "--seconds", "1", "--out", str(tmp_path / "logs")])
    assert code == 2 and not (tmp_path / "logs").exists()
    assert "--baud 57600 is the D'Claw's Dynamixel bit rate; the Allegro's CAN bit rate is set " \
           "on its interface" in capsys.readouterr().err


def test_reset_test_on_a_real_port_refuses_no_effects(capsys):
    # before: `reset-test --port /dev/ttyUSB0 --no-effects` ran on the robot, the option (the
    # emulated robot's servo effects) dropped unsaid; here refused before the port is opened
    from lowcostdex.cli import main

    assert main(["reset-test", "--port", "/dev/ttyUSB9", "--no-effects"]) == 2
    assert "--no-effects is for --port emulated (its default servo effects); the robot on " \
           "/dev/ttyUSB9 has its own" in capsys.readouterr().err


_TORQUE_ARM = """<mujoco><option timestep="0.002"/><worldbody><body>
<joint name="j" type="hinge" axis="0 0 1" damping="0.05"/>
<geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0" mass="0.1"/></body></worldbody>
<actuator><motor name="m" joint="j" ctrlrange="-0.05 0.05" ctrllimited="true"/>
</actuator></mujoco>"""


def test_degrees_scale_a_motors_angles_but_not_its_torque_goal(tmp_path):
    # before (gap-sim13's find): `--units deg` multiplied EVERY goal column by pi/180, also a
    # <motor>'s torque [N m]: a torque-controlled rig logged in degrees was replayed with
    # torques 57x too small, silently. The log here is plain MuJoCo driven by the torques the
    # test writes; its angles are written in degrees.
    from lowcostdex.gap.dataset import load_dataset
    model = mujoco.MjModel.from_xml_string(_TORQUE_ARM)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    torques = np.repeat(rng.uniform(-0.04, 0.04, 40), 25)  # 0.5 s holds at 50 Hz samples
    rows = ["time,goal:m,qpos:j"]
    for tau in torques:
        rows.append(f"{data.time:.4f},{tau:.6f},{math.degrees(data.qpos[0]):.6f}")
        data.ctrl[0] = tau
        for _ in range(10):  # 20 ms per sample
            mujoco.mj_step(model, data)
    (tmp_path / "logs").mkdir()
    (tmp_path / "logs" / "torque.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "arm.xml").write_text(_TORQUE_ARM)
    ds = load_dataset(tmp_path / "logs", model=tmp_path / "arm.xml", angle_unit="deg")
    traj = ds.trajectories[0]
    logged = np.array([[float(r.split(",")[1]), float(r.split(",")[2])] for r in rows[1:]])
    np.testing.assert_allclose(traj.goal[:, 0], logged[:, 0], atol=1e-9)  # N m, as logged
    np.testing.assert_allclose(traj.qpos[:, 0], np.radians(logged[:, 1]), atol=1e-9)
