"""Issue 12's leftovers after the careless sessions: each mistake a clean refusal or a correct
run, its truth outside the code under test (the files on disk, exit codes, values written out
here, the emulated motors' side).

- ``train --resume`` with ``--n-iter`` below the iterations done trained nothing, rewrote
  config.json to the smaller budget and printed the old outcome as if it had run;
- ``calibrate --spec X --out X`` replaced the spec it started from;
- a failed velocity, voltage or temperature read dropped its whole row (and cut the log where
  the goal changed across it), though the position - what the replay needs - was read;
- a read-only ``--out`` (as root permissions do not stop a write: a path under a file instead);
- Allegro (python-can virtual bus) and hardware-backend hand specs get the D'Claw's checks.
"""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from test_bad_inputs import bench_model, csv_text, servo_log, with_velocity

from lowcostdex.cli import USER_ERROR, main

POINTMASS = "lowcostdex_test/PointMass-v0"
TINY = ("--n-traj", "2", "--eval-every", "1", "--eval-episodes", "1", "--hidden", "8",
        "--no-progress")


@pytest.fixture(autouse=True)
def _pointmass_registered():
    if POINTMASS not in gym.registry:
        gym.register(POINTMASS, entry_point="pointmass:PointMass", max_episode_steps=30)


def snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


def one_error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("[progress]")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# ------------------------------------------------------------------------------------------------
# train --resume --n-iter below what the run has done


def test_resume_with_fewer_iterations_than_done_is_refused_and_the_run_left_as_it_is(
        tmp_path, capsys):
    """A run of 3 iterations (checkpoints after iterations 0..2 on disk, 3 metric rows) resumed
    with --n-iter 2: it trained nothing and rewrote config.json to n_iter 2 while its
    checkpoints say 3. Now exit 2, one line naming both numbers, every file byte for byte
    as it was. The same --n-iter 3 (a finished run resumed, e.g. after a crash in its last
    writes) runs and says there is nothing to train; --n-iter 4 trains one more iteration."""
    out = tmp_path / "run"
    argv = ["train", "npg", "--env", POINTMASS, "--out", str(out), *TINY]
    assert main([*argv, "--n-iter", "3"]) == 0
    assert sorted(p.name for p in (out / "checkpoints").glob("ckpt_*.pt"))[-1] == "ckpt_000002.pt"
    before = snapshot(tmp_path)
    capsys.readouterr()
    for n_iter in ("2", "1"):
        assert main([*argv, "--n-iter", n_iter, "--resume"]) == USER_ERROR
        line = one_error_line(capsys.readouterr().err)
        assert line == (f"lowcostdex train npg: error: cannot resume {out} with n_iter={n_iter} "
                        "(--n-iter): the run has done 3 iterations already (checkpoint after "
                        "iteration 2); give --n-iter above 3 to train more. The run is left as "
                        "it is"), line
        assert snapshot(tmp_path) == before
    assert main([*argv, "--n-iter", "3", "--resume"]) == 0
    err = capsys.readouterr().err
    assert (f"lowcostdex train npg: note: the run in {out} had done its 3 iterations (--n-iter "
            "3): nothing was trained, its final outputs were written again; give --n-iter above "
            "3 to train more") in err, err
    assert len((out / "metrics.csv").read_text().splitlines()) == 1 + 3
    assert main([*argv, "--n-iter", "4", "--resume"]) == 0
    assert "note:" not in capsys.readouterr().err
    assert len((out / "metrics.csv").read_text().splitlines()) == 1 + 4
    assert json.loads((out / "config.json").read_text())["n_iter"] == 4


def test_resume_below_the_iterations_done_is_refused_for_ppo_too(tmp_path, capsys):
    """The refusal is in the run folder's check every trainer calls (PPO on the valve here)."""
    out = tmp_path / "run"
    argv = ["train", "ppo", "--out", str(out), "--num-envs", "2",
            "--num-minibatches", "1", "--update-epochs", "1", "--hidden", "8",
            "--eval-every", "1", "--eval-episodes", "1", "--threads", "1", "--no-progress"]
    assert main([*argv, "--n-iter", "2"]) == 0
    before = snapshot(tmp_path)
    capsys.readouterr()
    assert main([*argv, "--n-iter", "1", "--resume"]) == USER_ERROR
    assert "the run has done 2 iterations already" in one_error_line(capsys.readouterr().err)
    assert snapshot(tmp_path) == before


# ------------------------------------------------------------------------------------------------
# calibrate --spec X --out X


def test_calibrate_onto_its_own_spec_is_refused_and_a_new_name_works(tmp_path, capsys,
                                                                      monkeypatch):
    from lowcostdex.hands import dclaw_spec

    monkeypatch.chdir(tmp_path)
    spec = tmp_path / "spec.json"
    spec.write_text(dclaw_spec().to_json())
    (tmp_path / "link.json").symlink_to(spec)
    before = snapshot(tmp_path)
    for out in ("spec.json", str(spec), "./spec.json", "link.json"):
        code = main(["calibrate", "--spec", "spec.json", "--out", out, "--port", "emulated",
                     "--yes"])
        assert code == USER_ERROR
        line = one_error_line(capsys.readouterr().err)
        assert (f"--out {out} is the --spec file itself: calibrating would replace the spec it "
                "starts from") in line, line
        assert snapshot(tmp_path) == before
    assert main(["calibrate", "--spec", "spec.json", "--out", "new.json", "--port", "emulated",
                 "--yes"]) == 0
    assert spec.read_bytes() == before["spec.json"]
    assert json.loads((tmp_path / "new.json").read_text())["name"] == "dclaw"


# ------------------------------------------------------------------------------------------------
# failed optional reads in a log: the row stays


def _channels_log() -> dict[str, np.ndarray]:
    """The bench log with the servo's velocity, supply voltage (12 V sagging 0.1 V per A of
    current) and temperature (35 deg C rising 1 deg C per 2 s, 1 deg C steps), as an X-series
    servo's Present registers give them."""
    cols = with_velocity(servo_log())
    cols["voltage:arm"] = np.round(12.0 - 0.1 * np.abs(cols["current:arm"]), 1)
    cols["temperature:arm"] = np.floor(35.0 + cols["time"] / 2.0)
    return cols


def _load(tmp_path: Path, cols: dict[str, np.ndarray]):
    from lowcostdex.gap.dataset import load_dataset

    (tmp_path / "bench.xml").write_text(bench_model())
    (tmp_path / "log.csv").write_text(csv_text(cols))
    return load_dataset([tmp_path / "log.csv"], model=tmp_path / "bench.xml")


def test_a_failed_optional_read_keeps_its_row_and_short_gaps_are_interpolated(tmp_path):
    """Velocity missing in row 300, voltage in rows 410-411, temperature in row 799 (the last):
    all 800 rows are kept with the clean log's time, goal and position; the missing values are
    the straight line between the readings either side (rows are 10 ms apart: the mean of the
    two neighbours for one row, 1/3 and 2/3 of the way for two), the last held; one note per
    channel names the rows. Before: the rows were dropped and the log cut in two at row 300
    (the goal changes at every row)."""
    clean = _channels_log()
    cols = {k: v.copy() for k, v in clean.items()}
    cols["qvel:arm"][300] = np.nan
    cols["voltage:arm"][410:412] = np.nan
    cols["temperature:arm"][799] = np.nan
    ds = _load(tmp_path, cols)
    (tr,) = ds.trajectories
    assert len(tr.time) == 800
    for k, key in (("time", "time"), ("goal", "goal:arm"), ("qpos", "qpos:arm")):
        got = getattr(tr, k).ravel()
        assert np.allclose(got, clean[key], atol=1e-6), k  # the CSV keeps 6 decimals
    v = clean["qvel:arm"]
    assert tr.qvel[300, 0] == pytest.approx((v[299] + v[301]) / 2, abs=1e-6)
    u = clean["voltage:arm"]
    assert tr.channels["voltage"][410:412, 0] == pytest.approx(
        [u[409] + (u[412] - u[409]) / 3, u[409] + 2 * (u[412] - u[409]) / 3], abs=1e-6)
    assert tr.channels["temperature"][799, 0] == clean["temperature:arm"][798]
    assert np.array_equal(np.delete(tr.qvel[:, 0], 300), np.delete(v, 300).round(6))
    assert ds.notes == [
        "log.csv: 1 qvel reading(s) missing in 1 row(s) (first: row 300, 0-based; qvel:arm): "
        "interpolated between the readings either side, the rows kept",
        "log.csv: 2 voltage reading(s) missing in 2 row(s) (first: row 410, 0-based; "
        "voltage:arm): interpolated between the readings either side, the rows kept",
        "log.csv: 1 temperature reading(s) missing in 1 row(s) (first: row 799, 0-based; "
        "temperature:arm): interpolated between the readings either side, the rows kept"]


def test_a_long_velocity_gap_costs_the_velocity_channel_not_the_rows(tmp_path):
    """Velocity missing in 10 rows in a row (100 ms: too long to draw a line through a servo's
    response): the rows are kept and the velocity of the whole log is what the data set gives
    a log without velocities (the same log with the qvel column deleted); a temperature gap
    that long costs the temperature channel. A failed POSITION read still drops its row."""
    clean = _channels_log()
    cols = {k: v.copy() for k, v in clean.items()}
    cols["qvel:arm"][500:510] = np.nan
    cols["temperature:arm"][100:110] = np.nan
    ds = _load(tmp_path, cols)
    (tr,) = ds.trajectories
    assert len(tr.time) == 800 and "temperature" not in tr.channels
    assert "voltage" in tr.channels
    without = {k: v for k, v in clean.items() if k not in ("qvel:arm", "temperature:arm")}
    (ref,) = _load(tmp_path, without).trajectories
    assert np.array_equal(tr.qvel, ref.qvel)
    assert ds.notes == [
        "log.csv: qvel readings are missing in 10 row(s) (first: row 500, 0-based), 10 rows in "
        "a row at most: the qvel channel is left out and the rows kept (its velocities are "
        "estimated from the positions, as for a log without them)",
        "log.csv: temperature readings are missing in 10 row(s) (first: row 100, 0-based), 10 "
        "rows in a row at most: the temperature channel is left out and the rows kept (effects "
        "that need it cannot be fitted)"]
    cols = {k: v.copy() for k, v in clean.items()}
    cols["qpos:arm"][200] = np.nan
    cols["qvel:arm"][200] = np.nan
    assert [len(t) for t in _load(tmp_path, cols).trajectories] == [200, 599]


# ------------------------------------------------------------------------------------------------
# an --out that cannot be written: under a file (what root meets too), a read-only folder


def _user_folder(root: Path) -> None:
    from test_bad_inputs import bam_log

    (root / "notes.txt").write_text("my notes\n")
    (root / "bench.xml").write_text(bench_model())
    (root / "log.csv").write_text(csv_text(servo_log()))
    (root / "bam.json").write_text(json.dumps(bam_log()))


def _out_commands(out: str) -> dict[str, list[str]]:
    """Every command that writes, its output at ``out`` + a name."""
    return {
        "gap analyze": ["gap", "analyze", "--model", "bench.xml", "--log", "log.csv", "--out",
                        f"{out}/report"],
        "gap identify --json": ["gap", "identify", "--log", "bam.json", "--json",
                                f"{out}/id.json"],
        "train npg": ["train", "npg", "--env", POINTMASS, "--out", f"{out}/run", "--n-iter", "1",
                      *TINY],
        "train tvlg": ["train", "tvlg", "--out", f"{out}/run", "--n-iter", "1", "--no-progress"],
        "record-demos": ["record-demos", "--episodes", "1", "--out", f"{out}/demos.h5"],
        "record-log": ["record-log", "--port", "emulated", "--logs", "1", "--seconds", "1",
                       "--out", f"{out}/logs"],
        "main": ["main", "--out", f"{out}/job"],
        "transfer": ["transfer", "--out", f"{out}/transfer"],
        "model": ["model", "dclaw", "--out", f"{out}/dclaw.xml"],
        "calibrate": ["calibrate", "--port", "emulated", "--yes", "--out", f"{out}/spec.json"],
        "reset-test --json": ["reset-test", "--trials", "1", "--json", f"{out}/summary.json"],
    }


@pytest.mark.parametrize("command", list(_out_commands("x")))
def test_an_output_under_a_file_is_refused_before_the_work(command, tmp_path, capsys,
                                                           monkeypatch):
    """``--out notes.txt/report`` (a file where a folder should be): refused in one line naming
    the file, exit 2, before any work, the folder byte for byte as it was. Before, the lines
    read "no permission to write in notes.txt" or "the folder notes.txt does not exist" (it
    does: as a file) or "cannot open ...: Not a directory"."""
    monkeypatch.chdir(tmp_path)
    _user_folder(tmp_path)
    before = snapshot(tmp_path)
    assert main(_out_commands("notes.txt")[command]) == USER_ERROR
    line = one_error_line(capsys.readouterr().err)
    assert "notes.txt is a file, not a folder" in line, line
    assert snapshot(tmp_path) == before


def _read_only_folder(tmp_path: Path) -> Path:
    """A folder this process cannot write in, found by trying to create a file there: a
    chmod 555 folder for a normal user; as root (who writes in those), a read-only mount."""
    import os
    import tempfile

    candidates = [tmp_path / "ro"] if os.geteuid() != 0 else [Path("/proc/sys"),
                                                             Path("/sys/fs/cgroup")]
    if os.geteuid() != 0:
        candidates[0].mkdir()
        candidates[0].chmod(0o555)
    for folder in candidates:
        try:
            fd, name = tempfile.mkstemp(dir=folder)
        except OSError:
            return folder
        os.close(fd)
        os.unlink(name)
    pytest.skip(f"no read-only folder found as uid {os.geteuid()} (tried "
                f"{', '.join(map(str, candidates))}): root writes wherever permissions forbid")


@pytest.mark.parametrize("command", ["gap analyze", "train npg", "record-demos", "model", "main",
                                     "reset-test --json"])
def test_an_output_in_a_read_only_folder_is_refused_before_the_work(command, tmp_path, capsys,
                                                                     monkeypatch):
    monkeypatch.chdir(tmp_path)
    _user_folder(tmp_path)
    folder = _read_only_folder(tmp_path)
    before = snapshot(tmp_path)
    try:
        assert main(_out_commands(str(folder))[command]) == USER_ERROR
    finally:
        if folder.is_relative_to(tmp_path):
            folder.chmod(0o755)
    line = one_error_line(capsys.readouterr().err)
    assert f"no permission to write in {folder.resolve()}" in line, line
    assert snapshot(tmp_path) == before


# ------------------------------------------------------------------------------------------------
# Allegro hand specs (python-can virtual bus): the D'Claw's checks


# the Allegro v4 right hand's joint ranges [rad] (allegro_hand_description URDF), typed in here
URDF_INDEX_1 = (-0.196, 1.61)
# FINGER_POSE positions: int16 counts of 333.3/65536 deg (the v4 C++ driver) -> at most
# 32768 * 333.3 / 65536 deg = 166.65 deg
INT16_REACH = 32768 * 333.3 / 65536 * np.pi / 180


def allegro_spec_with(edit) -> callable:
    def write(path: Path) -> None:
        from lowcostdex.hands import allegro_spec

        raw = json.loads(allegro_spec().to_json())
        edit(raw)
        path.write_text(json.dumps(raw))
    return write


ALLEGRO_NAMES = [f"{f}_{k}" for f in ("index", "middle", "ring", "thumb") for k in range(4)]
ALLEGRO_CASES = {
    # limits wider than the hand: the Allegro model takes its ranges from the spec, so nothing
    # stopped +-4 rad (the D'Claw's are refused by the motor's turn and the model)
    "limits of +-4 rad": (lambda d: d["joints"][0].update(low=-4.0, high=4.0),
                          "joint index_0: limits [-4.0, 4.0] rad leave the Allegro's joint range "
                          "[-0.47, 0.47] rad (published URDF: the mechanical stops)"),
    "a limit past the stop": (lambda d: d["joints"][1].update(high=2.5),
                              f"joint index_1: limits [-0.196, 2.5] rad leave the Allegro's joint "
                              f"range [{URDF_INDEX_1[0]}, {URDF_INDEX_1[1]}] rad"),
    "an offset putting readings beyond int16": (
        lambda d: d["joints"][0]["calibration"].update(offset=10.0),
        f"outside what the hand reports (+-{INT16_REACH:.4f} rad, int16 counts)"),
    "a motor id that is no CAN slot": (lambda d: d["joints"][0].update(motor_id=20),
                                       "joint index_0: motor_id 20 is not an Allegro joint slot "
                                       "(0..15"),
    "two joints on one slot": (lambda d: d["joints"][1].update(motor_id=0),
                               "joints index_0 and index_1 are both on motor id 0"),
    "max_velocity 1e6": (lambda d: d["joints"][0].update(max_velocity=1e6),
                         "joint index_0: max_velocity 1000000.0 rad/s is outside (0, 50.0]"),
    "a NaN calibration offset": (lambda d: d["joints"][0]["calibration"].update(offset=float("nan")),
                                 "calibration offset must be a finite number, got nan"),
    "joints out of action order": (
        lambda d: d["joints"].__setitem__(slice(0, 2), d["joints"][1::-1]),
        f"are not the Allegro's 16 in action order: {', '.join(ALLEGRO_NAMES)}"),
    "a valve motor as aux joint": (
        lambda d: d.update(aux_joints=[{"name": "valve", "motor_id": 50, "low": -3, "high": 3}]),
        "aux_joints valve: the Allegro has no motors beside its 16 joints on CAN"),
}


@pytest.mark.parametrize("case", list(ALLEGRO_CASES))
def test_a_bad_allegro_spec_is_refused_by_record_log_before_anything_is_written(
        case, tmp_path, capsys):
    edit, message = ALLEGRO_CASES[case]
    allegro_spec_with(edit)(tmp_path / "spec.json")
    before = snapshot(tmp_path)
    code = main(["record-log", "--hand", "allegro", "--port", "emulated", "--spec",
                 str(tmp_path / "spec.json"), "--logs", "1", "--seconds", "1", "--out",
                 str(tmp_path / "logs")])
    assert code == USER_ERROR
    line = one_error_line(capsys.readouterr().err)
    assert line.startswith(f"lowcostdex record-log: error: --spec {tmp_path / 'spec.json'}: "), line
    assert message in line, line
    assert snapshot(tmp_path) == before


def test_hardware_backends_take_a_spec_file_or_dict_and_refuse_a_wrong_one(tmp_path):
    """``gym.make(..., backend="hardware", hand=...)``: a spec's path or its JSON dict (an env
    keyword from a JSON config, ``--env-kwarg hand=spec.json``) raised AttributeError ('str'
    object has no attribute 'aux_joints'); now read and checked like ``--spec``. The Allegro's
    is used by the robot (checked on the emulated hand served on a virtual CAN channel); the
    D'Claw's passes to the port (a missing one: BusError naming it)."""
    import threading
    import time

    from lowcostdex.errors import ConfigError, InputError
    from lowcostdex.hands import dclaw_spec
    from lowcostdex.hardware.allegro.emulator import EmulatedAllegro
    from lowcostdex.hardware.bus import BusError
    from lowcostdex.sim.envs.allegro_tasks import AllegroTurnValve

    narrow = tmp_path / "allegro.json"
    allegro_spec_with(lambda d: d["joints"][0].update(low=-0.3, high=0.3))(narrow)
    (tmp_path / "dclaw.json").write_text(dclaw_spec().to_json())
    dclaw = "lowcostdex/DClawTurnValve-v0"
    allegro = "lowcostdex/AllegroTurnValve-v0"
    for hand in (str(tmp_path / "dclaw.json"), json.loads(dclaw_spec().to_json())):
        with pytest.raises(BusError, match="/dev/ttyUSB9"):
            gym.make(dclaw, backend="hardware", port="/dev/ttyUSB9", hand=hand)
    for hand, error, words in (
            (str(narrow), ConfigError, "hand=: a 'allegro' hand spec given for the 'dclaw' hand"),
            (3, ConfigError, "hand= must be a HandSpec, the path of a hand spec JSON or its dict"),
            (str(tmp_path / "missing.json"), InputError, "cannot read it (No such file")):
        with pytest.raises(error) as exc:
            gym.make(dclaw, backend="hardware", port="/dev/ttyUSB9", hand=hand)
        assert words in str(exc.value)
    bad = json.loads(narrow.read_text())
    bad["joints"][1]["high"] = 2.5
    with pytest.raises(ConfigError, match=r"hand=: joint index_1: limits \[-0.196, 2.5\] rad "
                                          "leave the Allegro's joint range"):
        gym.make(allegro, backend="hardware", channel="c", interface="virtual",
                 tracker=lambda: 0.0, hand=bad)
    channel = f"allegro-spec-{time.monotonic_ns()}"
    emu = EmulatedAllegro(AllegroTurnValve().build_spec().compile(), channel=channel)
    stop = threading.Event()
    server = threading.Thread(target=emu.serve, args=(stop,), daemon=True)
    server.start()
    try:
        for hand in (str(narrow), json.loads(narrow.read_text())):
            env = gym.make(allegro, backend="hardware", interface="virtual", channel=channel,
                           tracker=lambda: 0.0, hand=hand)
            joint = env.unwrapped.backend.robot.hand.joint("index_0")
            assert (joint.low, joint.high) == (-0.3, 0.3)
            env.close()
    finally:
        stop.set()
        server.join(2.0)
        emu.close()


# ------------------------------------------------------------------------------------------------
# the README's "When things go wrong" says what the code does


def test_the_readme_s_when_things_go_wrong_section_states_what_the_code_does(tmp_path, capsys):
    """Issue 12's "Done when" asks for a short section (messages, resume, watchdog); each number
    it gives a user is read from the README (and from docs/troubleshooting.md, the long list it
    links) and compared with the code: exit codes, the message form (one real refusal), the
    thermal thresholds of an X430 (80 deg C firmware limit), the watchdog's 100 ms and 3 stops
    per episode, the 3-row gap interpolated in a log."""
    import dataclasses
    import re

    from lowcostdex.errors import INTERRUPTED
    from lowcostdex.gap.log_checks import MAX_FILL_RUN
    from lowcostdex.hardware.dynamixel.config import DynamixelConfig
    from lowcostdex.hardware.robot.backend import RobotBackend
    from lowcostdex.hardware.robot.guards import ThermalConfig
    from lowcostdex.motors import motor_spec

    root = Path(__file__).parents[1]
    readme = (root / "README.md").read_text()
    section = readme.split("## When things go wrong", 1)[1].split("\n## ", 1)[0]
    # short (the word): what a user needs here, the long list in the linked file
    assert len(section.strip().splitlines()) <= 25, len(section.strip().splitlines())
    assert "(docs/troubleshooting.md)" in section
    detail = (root / "docs" / "troubleshooting.md").read_text()
    for topic in ("--debug", "--resume", "Ctrl-C", "watchdog", "--out"):
        assert topic in section, topic
    assert "exits with code 2" in section and USER_ERROR == 2
    assert "(exit code 130)" in section and INTERRUPTED == 130
    code = main(["scan", "--port", str(tmp_path / "ttyUSB7")])
    line = one_error_line(capsys.readouterr().err)
    assert code == USER_ERROR and re.match(r"lowcostdex scan: error: \S", line), line
    assert "`lowcostdex CMD: error: ...`" in section
    limit, t = motor_spec("XH430-W350").thermal.limit, ThermalConfig()
    said = re.search(  # any line wrap
        r"reaches (\d+) deg C \(X430 servos; the firmware shuts down at (\d+)\), relaxes a motor at "
        r"once at (\d+), and resumes when every motor is below (\d+)".replace(" ", r"\s+"),
        section)
    assert said, "the thermal sentence changed"
    assert [float(x) for x in said.groups()] == [limit - t.warn_margin, limit,
                                                 limit - t.critical_margin, limit - t.resume_margin]
    watchdog = next(f.default for f in dataclasses.fields(DynamixelConfig)
                    if f.name == "watchdog_ms")
    assert f"watchdog ({watchdog} ms by default)" in section
    assert f"(up to {RobotBackend.MAX_WATCHDOG_STOPS} stops per episode" in section
    assert f"gaps of up to {MAX_FILL_RUN} rows interpolated" in detail
    assert f"(up to {RobotBackend.MAX_WATCHDOG_STOPS} stops per episode" in detail
    assert "exits with code 2" in detail and "(exit code 130)" in detail


# ------------------------------------------------------------------------------------------------
# issue 12: "demos were recorded with all of these" (hand specs): record-demos on a real port


def dclaw_spec_with(edit) -> callable:
    def write(path: Path) -> None:
        from lowcostdex.hands import dclaw_spec

        raw = json.loads(dclaw_spec().to_json())
        edit(raw)
        path.write_text(json.dumps(raw))
    return write


DCLAW_SPEC_CASES = {  # the four, each against the D'Claw's published numbers
    "limits of +-4 rad": (lambda d: d["joints"][0].update(low=-4.0, high=4.0),
                          "joint ff_top: limits [-4.0, 4.0] rad span 8.000 rad of motor 10, more "
                          "than its one turn (6.2832 rad)"),
    "max_velocity 1e6": (lambda d: d["joints"][0].update(max_velocity=1e6),
                         "joint ff_top: max_velocity 1000000.0 rad/s is outside (0, 50.0]"),
    "a NaN calibration offset": (lambda d: d["joints"][4]["calibration"].update(
        offset=float("nan")), "calibration offset must be a finite number, got nan"),
    "two joints on one motor id": (lambda d: d["joints"][1].update(motor_id=10),
                                   "joints ff_top and ff_middle are both on motor id 10"),
}


@pytest.mark.parametrize("case", list(DCLAW_SPEC_CASES))
def test_record_demos_on_a_robot_refuses_a_bad_hand_spec_before_the_port(case, tmp_path, capsys):
    """The port is a pty (a serial device nothing answers on): the spec is refused before
    anything is sent (a real robot never receives its limits), nothing written."""
    import os

    edit, message = DCLAW_SPEC_CASES[case]
    dclaw_spec_with(edit)(tmp_path / "spec.json")
    before = snapshot(tmp_path)
    master, slave = os.openpty()
    try:
        code = main(["record-demos", "--port", os.ttyname(slave), "--spec",
                     str(tmp_path / "spec.json"), "--episodes", "1", "--out",
                     str(tmp_path / "demos.h5")])
    finally:
        os.close(master)
        os.close(slave)
    assert code == USER_ERROR
    line = one_error_line(capsys.readouterr().err)
    assert f"--spec {tmp_path / 'spec.json'}: " in line and message in line, line
    assert snapshot(tmp_path) == before


# ------------------------------------------------------------------------------------------------
# issue 12 item 4 for PPO (npg/dapg: test_train_faults.py; tvlg: test_local_models_train.py)

PPO_TINY = ("--num-envs", "2", "--num-minibatches", "1", "--update-epochs", "1", "--hidden", "8",
            "--eval-every", "1", "--eval-episodes", "1", "--threads", "1", "--no-progress")


def test_ppo_ctrl_c_prints_its_resume_command_and_a_cut_checkpoint_is_skipped(
        tmp_path, capsys, monkeypatch):
    """Ctrl-C in PPO's third iteration: exit 130, "saved the state after iteration 1" and the
    command that resumes; that command (with a larger --n-iter) finishes the run, 4 metric
    rows. Then the newest checkpoint is cut to half its bytes (a crash while writing): a resume
    says it skipped it and continues from the older one."""
    import shlex

    from lowcostdex.algos import ppo
    from lowcostdex.errors import INTERRUPTED

    out = tmp_path / "run"
    rollout, calls = ppo._Agent.rollout, [0]

    def interrupted(self, env, k):
        calls[0] += 1
        if calls[0] == 3:
            raise KeyboardInterrupt
        return rollout(self, env, k)

    monkeypatch.setattr(ppo._Agent, "rollout", interrupted)
    assert main(["train", "ppo", "--out", str(out), "--n-iter", "3", *PPO_TINY]) == INTERRUPTED
    err = capsys.readouterr().err
    assert "interrupted (Ctrl-C); saved the state after iteration 1" in err, err
    again = shlex.split(err.strip().splitlines()[-1])
    assert again[:3] == ["lowcostdex", "train", "ppo"] and again[-1] == "--resume", again
    monkeypatch.setattr(ppo._Agent, "rollout", rollout)
    assert main([*again[1:], "--n-iter", "4"]) == 0
    assert len((out / "metrics.csv").read_text().splitlines()) == 1 + 4
    newest = sorted((out / "checkpoints").glob("ckpt_*.pt"))[-1]
    assert newest.name == "ckpt_000003.pt"
    newest.write_bytes(newest.read_bytes()[: newest.stat().st_size // 2])
    capsys.readouterr()
    assert main([*again[1:], "--n-iter", "5"]) == 0
    out_text = capsys.readouterr().out
    assert "resuming" in out_text and "skipped ckpt_000003.pt (does not load: corrupt or cut " \
        "short" in out_text, out_text
    assert len((out / "metrics.csv").read_text().splitlines()) == 1 + 5


def test_ctrl_c_during_record_log_keeps_the_finished_logs_and_the_next_run_keeps_them_too(
        tmp_path, capsys, monkeypatch):
    """Ctrl-C in the second of 3 identification logs: exit 130, one line; the first log is on
    disk whole (it loads as a log of the joints asked for); a new run in the same folder keeps
    it under previous/ rather than writing over it."""
    from lowcostdex.errors import INTERRUPTED
    from lowcostdex.gap.logs import read_log
    from lowcostdex.hardware.robot import trace

    record, calls = trace.record, [0]

    def interrupted(*args, **kwargs):
        calls[0] += 1
        if calls[0] == 2:
            raise KeyboardInterrupt
        return record(*args, **kwargs)

    monkeypatch.setattr(trace, "record", interrupted)
    out = tmp_path / "logs"
    argv = ["record-log", "--port", "emulated", "--logs", "3", "--seconds", "1", "--out",
            str(out)]
    assert main(argv) == INTERRUPTED
    err = capsys.readouterr().err
    assert [ln for ln in err.splitlines() if "interrupted" in ln] == [
        f"lowcostdex record-log: interrupted (Ctrl-C); the 1 finished log(s) (log_0.csv) are in "
        f"{out}; a new run there keeps them in {out / 'previous'}/"], err
    assert "Traceback" not in err
    first = (out / "log_0.csv").read_bytes()
    assert not (out / "log_1.csv").exists()
    traj = read_log(out / "log_0.csv")
    assert traj.joints == ("ff_top", "ff_middle", "ff_bottom") and len(traj.time) >= 20
    monkeypatch.setattr(trace, "record", record)
    assert main([*argv[:4], "1", *argv[5:]]) == 0
    kept = list(out.glob("previous/*/log_0.csv"))
    assert len(kept) == 1 and kept[0].read_bytes() == first
