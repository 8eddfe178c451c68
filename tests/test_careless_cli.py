"""A user's own files through the CLI (issue 12): the odd layouts, units and models a lab really
produces, each run as a user runs it (``python -m lowcostdex.cli`` in a subprocess).

Every case ends one of two ways: a correct result (the repaired log reads exactly as the clean
log it came from; a model's own logs analyse to "no discrepancy"), or exit code 2 with ONE line
naming the problem and the fix, no traceback, and the user's files byte for byte as they were.
``tests/test_bad_inputs.py`` holds the earlier table (time units, magnitudes, frozen or clipped
channels, BAM JSON fields, --out folders); the cases here are the ones it did not cover.

The truth is outside the code under test: the logs are written here from the bench's first-order
servo (``test_bad_inputs.servo_log``) or simulated by plain MuJoCo on the user's MJCF, and the
expected messages and repaired rows are written out.
"""

from __future__ import annotations

import functools
import json
import math
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import pytest
from test_bad_inputs import bam_log, bench_model, csv_text, edited, rows, servo_log


def _run(argv, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lowcostdex.cli", *argv], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)


def _snapshot(root: Path) -> dict:
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


# ------------------------------------------------------------------------------------------------
# a user's own MJCF: a two-link arm on plain position servos, and the ways users write it


ARM = """<mujoco model="user_arm"><option timestep="0.002"/>
<worldbody>
 <body name="upper"><inertial pos="0 0 -0.05" mass="0.1" diaginertia="1e-4 1e-4 1e-5"/>
  <joint name="shoulder" axis="1 0 0" damping="0.01"/>
  <body name="lower" pos="0 0 -0.1"><inertial pos="0 0 -0.05" mass="0.05" diaginertia="5e-5 5e-5 5e-6"/>
   <joint name="elbow" axis="1 0 0" damping="0.01"/>
  </body></body>{extra}
</worldbody>{tendon}
<actuator>{acts}</actuator></mujoco>"""
SHOULDER = '<position name="shoulder" joint="shoulder" kp="2"/>'
ELBOW = '<position name="elbow" joint="elbow" kp="1"/>'
MODELS = {
    "plain": dict(acts=SHOULDER + ELBOW),
    "free joint": dict(acts=SHOULDER + ELBOW, extra='<body name="ball" pos="0.3 0 0"><freejoint '
                       'name="ball"/><geom size="0.02" mass="0.01"/></body>'),
    "tendon": dict(acts=SHOULDER + '<position name="elbow" tendon="elbow_t" kp="1"/>',
                   tendon='<tendon><fixed name="elbow_t"><joint joint="elbow" coef="1"/></fixed>'
                          '</tendon>'),
    "two actuators": dict(acts=SHOULDER + ELBOW + '<position name="elbow2" joint="elbow" '
                          'kp="0.5"/>'),
    "ctrlrange": dict(acts=SHOULDER.replace('kp="2"', 'kp="2" ctrlrange="-0.5 0.5"')
                      + ELBOW),
    "motor gear 50": dict(acts=SHOULDER + '<motor name="elbow" joint="elbow" gear="50"/>'),
    "velocity servo": dict(acts=SHOULDER + '<velocity name="elbow" joint="elbow" kv="0.1"/>'),
}


def arm_xml(kind: str) -> str:
    return ARM.format(**{"extra": "", "tendon": "", **MODELS[kind]})


@functools.cache
def arm_log(kind: str, seconds: float, phase: float = 0.0, scale: float = 1.0) -> str:
    """A log of the arm as plain MuJoCo runs it: goals (sines plus steps, held between rows)
    written at 100 Hz, joint angles and velocities read at each row."""
    m = mujoco.MjModel.from_xml_string(arm_xml(kind))
    d = mujoco.MjData(m)
    n, rate = int(seconds * 100), 100.0
    t = np.arange(n) / rate
    names = [m.actuator(i).name for i in range(m.nu)]
    goals = {a: scale * (0.6 * np.sin(2 * np.pi * (0.3 + 0.2 * i) * t + phase)
                         + 0.2 * np.sign(np.sin(2 * np.pi * 0.5 * t + phase)))
             for i, a in enumerate(names)}
    q, v = np.zeros((n, 2)), np.zeros((n, 2))
    for k in range(n):
        q[k] = d.joint("shoulder").qpos[0], d.joint("elbow").qpos[0]
        v[k] = d.joint("shoulder").qvel[0], d.joint("elbow").qvel[0]
        d.ctrl[:] = [goals[a][k] for a in names]
        for _ in range(int(round(1 / (rate * m.opt.timestep)))):
            mujoco.mj_step(m, d)
    return csv_text({"time": t, **{f"goal:{a}": goals[a] for a in names},
                     "qpos:shoulder": q[:, 0], "qpos:elbow": q[:, 1],
                     "qvel:shoulder": v[:, 0], "qvel:elbow": v[:, 1]})


# ------------------------------------------------------------------------------------------------
# the refusals


@dataclass(frozen=True)
class Case:
    id: str
    argv: tuple[str, ...]
    message: str  # a substring of the one line
    files: dict = field(default_factory=dict)


def analyze(*extra: str, log: str = "log.csv", model: str = "bench.xml") -> tuple[str, ...]:
    return ("gap", "analyze", "--model", model, "--log", log, "--out", "report", *extra)


def log_case(id: str, text: str, message: str) -> Case:
    return Case(id, analyze(), message, {"bench.xml": bench_model(), "log.csv": text})


def arm_case(id: str, kind: str, text: str, message: str) -> Case:
    return Case(id, analyze(model="arm.xml"), message, {"arm.xml": arm_xml(kind), "log.csv": text})


def _held_goals() -> dict[str, np.ndarray]:
    """servo_log with its goals held for 0.5 s at a time (a step sequence)."""
    return edited(goal=lambda g: np.repeat(g[::50], 50))


def _in_degrees(text: str) -> str:
    """The log with its goal and qpos columns in degrees (a logger that kept the servo's unit).
    Below 4 pi (12.6 "rad", a swing of +-12 deg) the magnitude alone cannot tell; the model's
    ctrlrange can."""
    lines = text.splitlines()
    head = lines[0].split(",")
    keep = [k for k, h in enumerate(head) if not h.startswith("qvel:")]  # only angles logged
    out = [",".join(head[k] for k in keep)]
    for ln in lines[1:]:
        cells = ln.split(",")
        out.append(",".join(f"{math.degrees(float(cells[k])):.4f}"
                            if head[k].split(":")[0] in ("goal", "qpos") else cells[k]
                            for k in keep))
    return "\n".join(out) + "\n"


CASES = [
    log_case("time in microseconds",
             csv_text(servo_log(), time=lambda t: str(round(t * 1e6))),
             "median step is 10000: us? (100 Hz if so); divide the time stamps by 1e+06"),
    log_case("time in ms since the epoch",
             csv_text(servo_log(), time=lambda t: str(round((1_732_550_400 + t) * 1e3))),
             "median step is 10: ms? (100 Hz if so); divide the time stamps by 1e+03"),
    log_case("rows written newest first",
             csv_text(rows(servo_log(), slice(None, None, -1))),
             "column 'time' must be strictly increasing: row 1 (0-based) goes back from 7.99 "
             "to 7.98"),
    log_case("two runs in one file",
             csv_text({k: np.concatenate([v, v]) for k, v in servo_log().items()}),
             "row 800 (0-based) goes back from 7.99 to 0 (two logs in one file, or shuffled "
             "rows? sort the rows or cut the file in two)"),
    log_case("time stamps rounded to 0.1 s", csv_text(servo_log(), time=lambda t: f"{t:.1f}"),
             "row 1 (0-based) repeats to 0 (719 time stamps repeat with other values: rounded "
             "too coarsely?)"),
    log_case("one time stamp twice with other values",
             csv_text({**servo_log(), "time": np.where(np.arange(800) == 300, 2.99,
                                                       servo_log()["time"])}),
             "row 300 (0-based) repeats to 2.99 (duplicate or unsorted rows?)"),
    log_case("the time column named 'timestamp'",
             csv_text(servo_log()).replace("time,", "timestamp,", 1),
             "missing column 'time' [s]; its columns: 'timestamp', 'goal:arm', 'qpos:arm', "
             "'current:arm'; name the time stamps' column 'time' (in seconds)"),
    log_case("a channel that was not logged (empty cells)",
             csv_text(servo_log()).replace("\n", ",\n").replace("current:arm,\n",
                                                               "current:arm,voltage:arm\n"),
             "column 'voltage:arm' is empty or NaN in 800 of 800 rows (first at row 0, "
             "0-based); leave the column out if that channel was not logged"),
    log_case("a column of another kind", csv_text({**servo_log(), "pwm": np.zeros(800)}),
             "column 'pwm' is not '<kind>:<name>'; kinds: time, goal, current, voltage, "
             "temperature, torque_enable, qpos, qvel; remove the column or rename it"),
    log_case("one constant goal: the joint never moves",
             csv_text({"time": servo_log()["time"], "goal:arm": np.full(800, 0.3),
                       "qpos:arm": np.full(800, 0.3)}),
             "too little motion to identify anything: peak-to-peak qpos [rad] arm 0; some "
             "joint must move at least 0.02 rad"),
    log_case("the goal logged as the position",
             csv_text({**servo_log(), "qpos:arm": servo_log()["goal:arm"]}),
             "column 'qpos:arm' is at the row's new goal in 100 % of 652 goal steps, before the "
             "goal was sent (its reading is taken first): the goal logged as the position (log "
             "the servo's Present Position), or each row's goal one row late"),
    log_case("'Time' and 'time' both", csv_text(servo_log()).replace("time,goal:arm",
                                                                     "time,Time", 1),
             "columns 'time' and 'Time' name the same thing"),
    # the user's MJCF against the logs
    arm_case("a motor with gear 50 where the logs hold position goals", "motor gear 50",
             arm_log("plain", 3.0),
             "actuator 'elbow' is a motor: its input is a force or torque (x gear 50), not a "
             "position; the log's 'goal:elbow' is a position goal [rad]: model the servo as "
             "<position kp=...>"),
    arm_case("a velocity servo where the logs hold position goals", "velocity servo",
             arm_log("plain", 3.0), "actuator 'elbow' is a velocity servo (its input is a "
             "velocity)"),
    arm_case("goals in degrees against a model without joint limits", "ctrlrange",
             # at scale 0.1 the degrees log moves 68.7 "rad/s" and the speed check (no qvel: 50
             # rad/s) refuses it first; at 0.05 (about 34) only the model's ctrlrange can tell
             _in_degrees(arm_log("plain", 3.0, scale=0.05)),
             "column 'goal:shoulder' reads 1.5211 at row 31 (0-based), outside the model's "
             "ctrlrange [-0.5, 0.5] by more than its width (degrees? write rad"),
    arm_case("a joint in the logs the MJCF lacks", "plain",
             arm_log("plain", 3.0).replace("qpos:elbow", "qpos:wrist").replace("qvel:elbow",
                                                                            "qvel:wrist"),
             "'qpos:wrist': no joint 'wrist' in the model; joints: shoulder, elbow"),
    # gap identify: its --json output and its inputs
    Case("identify --json over a user's file",
         ("gap", "identify", "--log", "bam.json", "--json", "notes.json"),
         "--json notes.json already exists and is not a 'gap identify' output; it is left "
         "untouched", {"bam.json": json.dumps(bam_log()), "notes.json": '{"todo": [1, 2]}'}),
    Case("identify --json into a missing folder",
         ("gap", "identify", "--log", "bam.json", "--json", "results/identified.json"),
         "--json results/identified.json: the folder results does not exist",
         {"bam.json": json.dumps(bam_log())}),
    Case("identify on a project-format CSV", ("gap", "identify", "--log", "log.csv"),
         "log.csv: not a BAM raw-log JSON; --bench and gap identify take BAM JSON logs "
         "(project-format CSV/NPZ logs: gap analyze --model)", {"log.csv": csv_text(servo_log())}),
    # the full model name of BAM's motor is read as BAM's name since issue 12's third pass
    # (test_careless_commands); another gear ratio of the same family is not that motor
    Case("BAM motor of another gear ratio",
         ("gap", "analyze", "--log", "bam.json", "--out", "report"),
         "unknown BAM motor 'XL330-M077'; valid: mx106 (MX-106(1.0)), mx64 (MX-64(1.0)), "
         "sts3032 (STS3032), sts3215 (STS3215), sts3250 (STS3250), xl330 (XL330-M288)",
         {"bam.json": json.dumps(bam_log(motor="XL330-M077"))}),
    # other commands
    Case("record-log --effects that is not JSON",
         ("record-log", "--port", "emulated", "--effects", "notes.txt", "--out", "logs"),
         "--effects notes.txt: not a readable JSON file", {"notes.txt": "latency 20 ms\n"}),
    Case("record-log --effects with a misspelt key",
         ("record-log", "--port", "emulated", "--effects", "fx.json", "--out", "logs"),
         "--effects fx.json: entry 0: unknown effect key 'param'; valid: effect, joints, "
         "params, in_mjcf, interval",
         {"fx.json": json.dumps([{"effect": "latency", "joints": ["ff_top"],
                                  "param": {"delay": 0.02}}])}),
    Case("emulate --effects with a NaN parameter",
         ("emulate", "bench", "--effects", "fx.json", "--quiet"),
         "--effects fx.json: entry 0: effect latency: parameter 'delay' must be finite",
         {"fx.json": '[{"effect": "latency", "joints": ["bench"], "params": {"delay": NaN}}]'}),
    Case("record-demos --spec with the emulated hand",
         ("record-demos", "--episodes", "1", "--out", "demos.h5", "--spec", "dclaw.json"),
         "--spec dclaw.json: a hand spec (calibration) is for a real robot (--port DEVICE)",
         {"dclaw.json": "{}"}),
    Case("record-demos --successes beyond --episodes",
         ("record-demos", "--episodes", "1", "--successes", "5", "--out", "demos.h5"),
         "--successes 5 can never be reached: --episodes 1 is the most episodes tried"),
    Case("a hand spec with a motor id written as text",
         ("record-log", "--port", "emulated", "--spec", "spec.json", "--out", "logs"),
         "joint ff_top: motor_id must be an integer bus id in [0, 252], got '10'",
         {"spec.json": lambda: _spec(lambda d: d["joints"][0].update(motor_id="10"))}),
    Case("main with a negative seed", ("main", "--seed", "-1", "--out", "run"),
         "argument --seed: '-1' is not an integer >= 0"),
    Case("main with an empty stage list", ("main", "--stages", "", "--out", "run"),
         "--stages '' names no stage; give a comma-separated subset of bus, demos, gap, train, "
         "report"),
    Case("main's report alone on a folder no stage ran in", ("main", "--stages", "report",
                                                              "--out", "run"),
         "stage 'report' has nothing to report: no stage ran now or finished earlier in run"),
    Case("main with a misspelled option", ("main", "--sizes", "smoke", "--out", "run"),
         "lowcostdex main: error: unrecognized arguments: --sizes smoke; --sizes: did you mean "
         "--size"),
    Case("train npg with an option it does not take", ("train", "npg", "--env",
                                                       "lowcostdex/DClawTurnValve-v0", "--out",
                                                       "run", "--epochs", "3"),
         "lowcostdex train npg: error: unrecognized arguments: --epochs 3"),
    Case("emulate at a negative bit rate", ("emulate", "bench", "--baud", "-1", "--quiet"),
         "--baud -1: the bit rate must be positive"),
    Case("emulate at a bit rate no motor runs at", ("emulate", "bench", "--baud", "250000",
                                                    "--quiet"),
         "--baud 250000: the emulated motors run at one of 9600, 57600, 115200, 1000000, "
         "2000000, 3000000, 4000000, 4500000 bit/s"),
    Case("a hand spec without joints",
         ("record-log", "--port", "emulated", "--spec", "spec.json", "--out", "logs"),
         "hand dclaw: no joints", {"spec.json": lambda: _spec(lambda d: d.update(joints=[]))}),
]


def _spec(change) -> str:
    from lowcostdex.hands import hand_spec

    d = json.loads(hand_spec("dclaw").to_json())
    change(d)
    return json.dumps(d)


def _without_elbow_reading() -> str:
    lines = arm_log("plain", 3.0).splitlines()
    keep = [i for i, h in enumerate(lines[0].split(",")) if h not in ("qpos:elbow", "qvel:elbow")]
    return "\n".join(",".join(ln.split(",")[i] for i in keep) for ln in lines) + "\n"


CASES.append(arm_case(
    "an actuated joint the logs lack", "plain", _without_elbow_reading(),
    "joint 'elbow' is driven by actuator 'elbow' but the log has no 'qpos:elbow' column: every "
    "replay would start it at the model's initial pose; log its position too"))


def _materialize(files: dict, root: Path) -> None:
    for name, content in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        content = content() if callable(content) else content
        path.write_bytes(content if isinstance(content, bytes) else content.encode())


def _check_refusal(case: Case, code: int, out: str, err: str, before: dict, root: Path) -> None:
    assert code == 2, err
    assert "Traceback" not in err + out
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("[progress]")]
    assert len(lines) == 1, err
    assert ": error: " in lines[0] and case.message in lines[0], lines[0]
    assert _snapshot(root) == before  # the user's files as they were, nothing new


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_a_careless_call_is_refused_in_one_line(case, tmp_path, capsys, monkeypatch):
    """In this process, through the CLI's ``main`` (the error path a process takes, below)."""
    from lowcostdex.cli import main

    monkeypatch.chdir(tmp_path)
    _materialize(case.files, tmp_path)
    before = _snapshot(tmp_path)
    code = main(list(case.argv))
    out, err = capsys.readouterr()
    _check_refusal(case, code, out, err, before, tmp_path)


AS_A_PROCESS = ("two runs in one file", "a motor with gear 50 where the logs hold position goals",
                "identify --json over a user's file", "record-log --effects that is not JSON")


@pytest.mark.parametrize("name", AS_A_PROCESS)
def test_a_careless_call_is_refused_in_one_line_as_a_process(name, tmp_path):
    """The same refusals from a process a user starts: exit status 2, one line on stderr."""
    case = next(c for c in CASES if c.id == name)
    _materialize(case.files, tmp_path)
    before = _snapshot(tmp_path)
    run = _run(case.argv, tmp_path, timeout=120)
    _check_refusal(case, run.returncode, run.stdout, run.stderr, before, tmp_path)


# ------------------------------------------------------------------------------------------------
# repaired, and said: the repaired log reads exactly as the clean log it came from


def _load(tmp: Path, text: str, model: str | None = None):
    from lowcostdex.gap.dataset import load_dataset

    (tmp / "bench.xml").write_text(model or bench_model())
    (tmp / "log.csv").write_bytes(text.encode())
    return load_dataset([tmp / "log.csv"], model=tmp / "bench.xml")


def _same(a, b) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("time", "goal", "qpos")) \
        and a.channels.keys() == b.channels.keys() \
        and all(np.array_equal(a.channels[k], b.channels[k]) for k in a.channels)


def test_a_spreadsheet_layout_reads_as_the_clean_log(tmp_path):
    """Windows line ends, a byte-order mark, a comment line and blank lines, a trailing ',' on
    every row, columns in another order, upper-case and spaced names; tabs between columns: the
    same log, no note (nothing in the data was changed)."""
    cols = servo_log()
    clean = _load(tmp_path, csv_text(cols)).trajectories[0]
    order = (2, 0, 3, 1)  # the clean text's columns time, goal, qpos, current reordered
    body = "\n".join(",".join(ln.split(",")[i] for i in order)
                     for ln in csv_text(cols).splitlines()) + "\n"
    assert body.startswith("qpos:arm,time,current:arm,goal:arm\n")
    body = body.replace("qpos:arm,time,current:arm,goal:arm",
                        "QPOS : arm, Time ,Current:arm,GOAL:arm")
    body = "\ufeff# bench arm, 2024-11-25\n" + body.replace("\n", ",\n") + "\n\n"
    ds = _load(tmp_path, body.replace("\n", "\r\n"))
    assert ds.notes == []
    assert _same(ds.trajectories[0], clean)
    ds = _load(tmp_path, csv_text(cols, sep="\t"))  # a tab-separated export (was refused)
    assert ds.notes == [] and _same(ds.trajectories[0], clean)


def test_a_row_index_column_is_left_out(tmp_path):
    """pandas' ``df.to_csv(path)`` writes the index as a first column named '' (0..n-1); read
    back and written again it is 'Unnamed: 0'. It numbers the rows and carries no data."""
    cols = servo_log()
    clean = _load(tmp_path, csv_text(cols)).trajectories[0]
    lines = csv_text(cols).splitlines()
    for head, first in (("", 0), ("Unnamed: 0", 0), ("sample", 1)):
        text = "\n".join([f"{head},{lines[0]}"] + [f"{k + first},{ln}" for k, ln in
                                                    enumerate(lines[1:])]) + "\n"
        ds = _load(tmp_path, text)
        assert ds.notes == [f"log.csv: column {head!r} numbers the rows (a row index); left out"]
        assert _same(ds.trajectories[0], clean)


def test_rows_out_of_order_are_sorted_and_repeats_dropped(tmp_path):
    """Two rows swapped (a logger's threads) and one row written twice: sorted and dropped,
    each said; the result is the clean log row for row."""
    cols = servo_log()
    clean = _load(tmp_path, csv_text(cols)).trajectories[0]
    ds = _load(tmp_path, csv_text(rows(cols, np.r_[0:300, 301, 300, 302:500, 499, 500:800])))
    assert ds.notes == ["log.csv: 1 repeated row(s) dropped (same time and values as the row "
                        "before; first: row 500)",
                        "log.csv: 2 row(s) out of time order (at most 0.01 s back) sorted by "
                        "time"]
    assert len(ds.trajectories) == 1 and _same(ds.trajectories[0], clean)


def test_a_failed_read_is_dropped_and_the_log_cut_only_where_the_goal_is_unknown(tmp_path):
    """A row of empty cells (a failed read) under a held goal: dropped, the log stays whole (the
    goal held across it is known). A NaN reading where the goal changed at that row: dropped and
    the log cut there, so no replay holds the previous goal over a step it did not see."""
    cols = _held_goals()
    text = csv_text(cols).splitlines()
    text[1 + 320] = "3.2000,,,"  # row 320: inside the goal held from 3.0 to 3.5 s
    clean = _load(tmp_path, csv_text(cols)).trajectories[0]
    ds = _load(tmp_path, "\n".join(text) + "\n")
    assert ds.notes == ["log.csv: 1 row(s) with an empty or NaN value dropped (first: row 320, "
                        "0-based, column 'goal:arm'; rows are counted without them from here on)"]
    assert [len(tr) for tr in ds.trajectories] == [799]
    keep = np.r_[0:320, 321:800]
    assert np.array_equal(ds.trajectories[0].qpos, clean.qpos[keep])
    assert np.array_equal(ds.trajectories[0].goal, clean.goal[keep])

    cols = servo_log()  # the goal changes at every row
    cols["qpos:arm"] = np.where(np.arange(800) == 417, np.nan, cols["qpos:arm"])
    ds = _load(tmp_path, csv_text(cols))
    assert [len(tr) for tr in ds.trajectories] == [417, 382]
    assert ds.trajectories[1].time[0] == pytest.approx(4.18)
    assert ds.notes[1] == ("log.csv: dropped rows where the goal may have changed before 4.18 s "
                           "(row 417); split into 2 piece(s)")


def test_joints_no_effect_can_act_on_are_named(tmp_path):
    """A joint under two actuators replays as modelled; the analysis says no candidate effect is
    placed on it. A joint driven through one tendon's actuator carries effects (gap-tendon,
    session 29: its servo's on the actuator; before, none) and the note says how. A free joint
    (a floating object) and joints without limits need no word."""
    for kind, note, joints in (
            ("tendon", "joint 'elbow' is driven through tendon elbow_t: the servo's effects act "
             "on that actuator's own coordinate", ("shoulder", "elbow")),
            ("two actuators", "joint 'elbow' is driven by 2 actuators", ("shoulder",))):
        ds = _load(tmp_path, arm_log(kind, 3.0), model=arm_xml(kind))
        assert len(ds.notes) == 1 and ds.notes[0].startswith(note), ds.notes
        assert ds.effect_joints == joints
    assert _load(tmp_path, arm_log("free joint", 3.0), model=arm_xml("free joint")).notes == []


@pytest.mark.parametrize("kind", ["tendon", "two actuators"])
def test_a_model_s_own_logs_analyse_to_no_discrepancy(kind, tmp_path):
    """End to end, as a user runs it: logs that plain MuJoCo made from the user's own MJCF (a
    tendon actuator; a joint under two actuators) analysed against that MJCF: exit 0, the note,
    no cause named, the nominal replay on the logs (was: a ValueError traceback writing the
    report, after the analysis)."""
    (tmp_path / "arm.xml").write_text(arm_xml(kind))
    for k, name in enumerate("abc"):
        (tmp_path / f"{name}.csv").write_text(arm_log(kind, 3.0, phase=float(k)))
    run = _run(("gap", "analyze", "--model", "arm.xml", "--log", "a.csv", "b.csv", "c.csv", "--out",
                "report", "--max-effects", "1", "--top-k", "1", "--candidates",
                "latency,coulomb_friction"), tmp_path)
    assert run.returncode == 0, run.stderr
    assert "Traceback" not in run.stderr
    assert "lowcostdex gap analyze: note: joint 'elbow' is driven " in run.stderr
    report = json.loads((tmp_path / "report" / "report.json").read_text())
    assert report["causes"] == []
    assert report["joints"] == ["shoulder", "elbow"]
    assert report["baseline"]["heldout_rmse"] < 1e-3  # [rad] the model's own logs replay on it


CUBE_OBJ = "".join(f"v {x} {y} {z}\n" for z in (-0.01, 0.01) for x, y in
                   ((-0.01, -0.01), (0.01, -0.01), (0.01, 0.01), (-0.01, 0.01))) + \
    "f 1 2 3 4\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n"


def test_a_model_with_its_meshes_in_a_folder_beside_it(tmp_path):
    """A user's MJCF with ``meshdir="assets"`` (meshes beside the model, as robot models ship),
    analysed from another working directory: was "ValueError: Error opening file
    'assets/cube.obj'" (a traceback) when the data set compiled its copy of the model."""
    from lowcostdex.gap.dataset import load_dataset

    robot = tmp_path / "my robot"
    (robot / "assets").mkdir(parents=True)
    (robot / "assets" / "cube.obj").write_text(CUBE_OBJ)
    xml = arm_xml("plain").replace("<option", '<compiler meshdir="assets"/><asset><mesh '
                                   'name="cube" file="cube.obj"/></asset><option', 1)
    xml = xml.replace('damping="0.01"/>\n  </body></body>', 'damping="0.01"/>\n  <geom type="mesh" '
                      'mesh="cube" contype="0" conaffinity="0" mass="0"/></body></body>', 1)
    (robot / "arm.xml").write_text(xml)
    (robot / "log.csv").write_text(arm_log("plain", 3.0))
    ds = load_dataset([robot / "log.csv"], model=robot / "arm.xml")  # cwd: the test's, not robot
    assert ds.compiled("model").nmesh == 1
    assert ds.with_timestep(0.5).compiled("model").nmesh == 1


def test_paths_with_spaces_and_accents(tmp_path):
    """A folder named as people name folders: the output goes there, the inputs are read."""
    root = tmp_path / "mes données" / "séance 1"
    root.mkdir(parents=True)
    run = _run(("gap", "generate", "--logs", "1", "--duration", "2", "--out",
                str(root / "données générées")), tmp_path)
    assert run.returncode == 0, run.stderr
    logs = sorted((root / "données générées").glob("*.csv"))
    assert len(logs) == 1 and (root / "données générées" / "model.xml").is_file()
    run = _run(("model", "bench", "--out", str(root / "modèle du banc.xml")), tmp_path)
    assert run.returncode == 0, run.stderr
    assert mujoco.MjModel.from_xml_path(str(root / "modèle du banc.xml")).nu == 1


def test_a_log_given_twice_is_used_once(tmp_path):
    """A folder and a file in it, and a copy under another name: each log once, said; a copy
    in the fit and in the held-out test would score the fit on its own data."""
    from lowcostdex.gap.cli import distinct_logs

    (tmp_path / "logs").mkdir()
    for name, cols in (("a.csv", servo_log()), ("b.csv", _held_goals())):
        (tmp_path / "logs" / name).write_text(csv_text(cols))
    (tmp_path / "a copy.csv").write_text(csv_text(servo_log()))
    logs, notes = distinct_logs([str(tmp_path / "logs"), str(tmp_path / "logs" / "b.csv"),
                                 str(tmp_path / "a copy.csv")])
    assert logs == [str(tmp_path / "logs" / "a.csv"), str(tmp_path / "logs" / "b.csv")]
    assert notes == [f"{tmp_path}/logs/b.csv: named twice; used once (a copy would be fitted "
                     "and tested at once)",
                     f"{tmp_path}/a copy.csv: the same bytes as {tmp_path}/logs/a.csv; used "
                     "once (a copy would be fitted and tested at once)"]


def test_identify_json_may_replace_its_own_previous_output(tmp_path):
    """The refusal above is for a user's file; a previous ``gap identify --json`` output is
    replaced (the check runs before the fit)."""
    from lowcostdex.gap.cli import IDENTIFY_KEYS, _check_json_out

    old = tmp_path / "identified.json"
    old.write_text(json.dumps(dict.fromkeys(IDENTIFY_KEYS, {})))
    _check_json_out(old)  # no error: replaced after the fit


def test_a_read_only_folder_is_refused_before_the_work(tmp_path):
    """Was: minutes of analysis, then a PermissionError when the report was written. The
    folder is one this process cannot create a file in: a chmod 555 folder, or as root (who
    writes there) a read-only mount (``test_careless_leftovers._read_only_folder``)."""
    from test_careless_leftovers import _read_only_folder

    (tmp_path / "bench.xml").write_text(bench_model())
    (tmp_path / "log.csv").write_text(csv_text(servo_log()))
    ro = _read_only_folder(tmp_path)
    try:
        for out in (ro, ro / "report"):
            run = _run(analyze()[:-1] + (str(out),), tmp_path, timeout=120)
            assert run.returncode == 2, run.stderr
            assert f"--out {out}: no permission to write in {ro.resolve()}" in run.stderr
    finally:
        if ro.is_relative_to(tmp_path):
            ro.chmod(0o755)
