"""Bad-input corpus (issue 12): every command on malformed input gives one clear line, exit code 2,
no traceback, and leaves the user's files byte for byte as they were (nothing new written where it
refuses).

``CASES`` is the table: the files a user has (written here as text, with real-world magnitudes and
the odd units real labs produce), the command line, and what must come out. The checks are the
same for every row (``test_bad_input_is_refused_cleanly``).
"""

from __future__ import annotations

import functools
import json
import math
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pytest

from lowcostdex.cli import main


@dataclass(frozen=True)
class Case:
    """One bad input. ``argv`` and file contents may use ``{tmp}`` (the user's folder)."""

    id: str
    argv: tuple[str, ...]
    message: str  # a substring of the one-line error
    files: dict[str, str | bytes | Callable[[], str]] = field(default_factory=dict)
    code: int = 2


# ------------------------------------------------------------------------------------------------
# logs as a lab writes them: a servo (XL330-class: 4096-tick encoder, about 60 ms to follow a
# step) on a bench arm, goals of steps on a sine, sampled at 100 Hz; current in A


ENCODER_STEP = 2 * math.pi / 4096  # [rad]
EPOCH_NS = 1_732_550_400_000_000_000  # 2024-11-25 16:00 UTC in ns: a host clock's time stamps


def servo_log(seconds: float = 8.0, rate: float = 100.0, lag: float = 0.06) -> dict[str, np.ndarray]:
    """Columns of the project's log format for the bench's joint ``arm``: the position follows
    the goal as a first-order lag of ``lag`` s (exact discretisation), read by the encoder."""
    t = np.arange(int(round(seconds * rate))) / rate
    goal = 0.8 * np.sin(2 * np.pi * 0.4 * t) + 0.3 * np.sign(np.sin(2 * np.pi * 0.7 * t))
    q = np.zeros_like(t)
    keep = math.exp(-1 / (rate * lag))
    for k in range(1, len(t)):
        q[k] = keep * q[k - 1] + (1 - keep) * goal[k - 1]
    # [A] holding a 0.2 kg load at 0.1 m (0.56 A per sin q at 0.35 N m/A) plus the P term
    current = np.clip(0.08 + 0.56 * np.sin(q) + 0.9 * (goal - q), -1.4, 1.4)
    return {"time": t, "goal:arm": goal, "qpos:arm": np.round(q / ENCODER_STEP) * ENCODER_STEP,
            "current:arm": np.round(current, 3)}


def with_velocity(cols: dict[str, np.ndarray], lag: float = 0.06) -> dict[str, np.ndarray]:
    """``cols`` plus 'qvel:arm' as a servo's Present Velocity reports it: the first-order lag's
    own rate (goal - q) / lag [rad/s], in 0.229 rev/min counts (0.0240 rad/s)."""
    count = 0.229 * 2 * math.pi / 60
    q, goal = cols["qpos:arm"], cols["goal:arm"]
    return {**cols, "qvel:arm": np.round((goal - q) / lag / count) * count}


def slow_log(seconds: float = 5.0, rate: float = 50.0) -> dict[str, np.ndarray]:
    """A slow sweep (0.5 rad at 0.2 Hz: at most 0.63 rad/s) with its logged velocity."""
    t = np.arange(int(round(seconds * rate))) / rate
    q = 0.5 * np.sin(2 * np.pi * 0.2 * t)
    v = 0.5 * 2 * np.pi * 0.2 * np.cos(2 * np.pi * 0.2 * t)
    return {"time": t, "goal:arm": q + 0.05 * v, "qpos:arm": np.round(q / ENCODER_STEP) * ENCODER_STEP,
            "qvel:arm": np.round(v / 0.0240) * 0.0240}


def window_12bit(q: np.ndarray, zero_tick: int) -> np.ndarray:
    """What a logger reading a 12-bit Present Position (ticks 0..4095, clipped) logs [rad] for a
    joint whose 0 rad sits at ``zero_tick``."""
    ticks = np.clip(np.round(q / ENCODER_STEP) + zero_tick, 0, 4095)
    return (ticks - zero_tick) * ENCODER_STEP


def csv_text(cols: dict[str, np.ndarray], time: Callable[[float], str] = lambda t: f"{t:.4f}",
             sep: str = ",") -> str:
    names = list(cols)
    rows = [sep.join(names)]
    for i in range(len(cols["time"])):
        rows.append(sep.join([time(cols["time"][i])]
                             + [f"{cols[n][i]:.6f}" for n in names[1:]]))
    return "\n".join(rows) + "\n"


def edited(**changes: Callable[[np.ndarray], np.ndarray]) -> dict[str, np.ndarray]:
    """``servo_log()`` with columns replaced: edited(qpos=lambda q: q * 1e9)."""
    cols = servo_log()
    for kind, f in changes.items():
        key = "time" if kind == "time" else f"{kind}:arm"
        cols[key] = f(cols[key].copy())
    return cols


def rows(cols: dict[str, np.ndarray], index) -> dict[str, np.ndarray]:
    return {k: v[index] for k, v in cols.items()}


@functools.cache
def bench_model() -> str:
    from lowcostdex.sim.models.bench import BenchConfig, build_bench

    return build_bench(BenchConfig()).to_xml()


def bam_log(**header) -> dict:
    """A BAM raw log as Rhoban's XL330 bench writes it (0.49 kg at 0.10 m, kp 400, 7.4 V; host
    time stamps at about 190 Hz; bool torque_enable)."""
    cols = servo_log(seconds=6.0, rate=190.0)
    entries = [{"position": float(q), "speed": 0.0, "load": 0, "input_volts": 7.3, "temp": 28,
                "timestamp": float(t), "goal_position": float(g), "torque_enable": True}
               for t, g, q in zip(cols["time"], cols["goal:arm"], cols["qpos:arm"], strict=True)]
    log = {"mass": 0.49, "length": 0.1, "kp": 400, "vin": 7.4, "motor": "xl330",
           "trajectory": "sin_sin", "entries": entries}
    log.update(header)
    return log


def bam_with(field_name: str, value, at: int = 40) -> str:
    log = bam_log()
    log["entries"][at][field_name] = value
    return json.dumps(log)


def analyze(log: str, *extra: str) -> tuple[str, ...]:
    """gap analyze of one log (with the bench model for CSV/NPZ logs)."""
    model = () if log.endswith(".json") else ("--model", "{tmp}/bench.xml")
    return ("gap", "analyze", *model, "--log", f"{{tmp}}/{log}", "--out", "{tmp}/report", *extra)


def csv_case(id: str, text: str, message: str) -> Case:
    return Case(id, analyze("log.csv"), message, files={"bench.xml": bench_model,
                                                        "log.csv": text})


def bam_case(id: str, text: str | bytes, message: str) -> Case:
    return Case(id, analyze("bench_log.json"), message, files={"bench_log.json": text})

# ------------------------------------------------------------------------------------------------
# the table


CASES: list[Case] = [
    Case("unknown option", ("gap", "analyze", "--log", "a.csv", "--out", "{tmp}/o", "--frobnicate"),
         "unrecognized arguments: --frobnicate"),
    Case("number that is not one", ("gap", "analyze", "--log", "a.csv", "--out", "{tmp}/o",
                                    "--max-effects", "three"), "argument --max-effects: 'three' is not an integer"),
    Case("reset-test with 0 trials", ("reset-test", "--trials", "0"), "--trials must be >= 1"),
    # hardware: ports and values
    Case("scan on a missing port", ("scan", "--port", "/dev/does-not-exist"),
         "--port /dev/does-not-exist: no such device"),
    Case("scan on a file that is not a serial port", ("scan", "--port", "{tmp}/notes.txt"),
         "cannot open it as a serial port", files={"notes.txt": "my notes\n"}),
    Case("scan with ids that are not ids", ("scan", "--port", "emulated", "--ids", "10-1x"),
         "'10-1x' is not an id"),
    Case("scan with an id beyond 252", ("scan", "--port", "emulated", "--ids", "250-254"),
         "ids are 0-252, got 253"),
    Case("scan at a negative bit rate", ("scan", "--port", "emulated", "--baud", "-57600"),
         "--baud -57600: the bit rate must be positive"),
    Case("calibrate on a missing port", ("calibrate", "--port", "/dev/ttyUSB7", "--out",
                                         "{tmp}/dclaw.json", "--yes"),
         "--port /dev/ttyUSB7: no such device"),
    Case("calibrate with 0 samples", ("calibrate", "--port", "emulated", "--out", "{tmp}/c.json",
                                      "--yes", "--samples", "0"), "argument --samples: '0'"),
    Case("calibrate over a user's file", ("calibrate", "--port", "emulated", "--hand", "bench",
                                          "--out", "{tmp}/notes.json", "--yes"),
         "is not a hand spec; it is left untouched", files={"notes.json": '{"todo": [1, 2]}'}),
    Case("calibrate into a missing folder", ("calibrate", "--port", "emulated", "--out",
                                             "{tmp}/no/such/dir/c.json", "--yes"),
         "/no/such/dir does not exist"),
    Case("calibrate from a spec that is a CSV", ("calibrate", "--port", "emulated", "--spec",
                                                 "{tmp}/log.csv", "--out", "{tmp}/c.json", "--yes"),
         "{tmp}/log.csv: not a hand spec JSON", files={"log.csv": "time,qpos:arm\n0,1\n"}),
    Case("calibrate from a missing spec", ("calibrate", "--port", "emulated", "--spec",
                                           "{tmp}/dclaw_calibrated.json", "--out", "{tmp}/c.json",
                                           "--yes"), "No such file or directory"),
    Case("record-log on a missing port", ("record-log", "--port", "/dev/ttyACM3", "--out",
                                          "{tmp}/logs"), "--port /dev/ttyACM3: no such device"),
    Case("transfer on a missing port", ("transfer", "--out", "{tmp}/t", "--port", "/dev/ttyUSB7",
                                        "--yes"), "--port /dev/ttyUSB7: no such device"),
    # the robot backends' one rule (lowcostdex.options.robot_selection) in the train commands too:
    # before, `train npg --backend hardware` failed inside the backend with a constructor keyword
    # ("HardwareBackend needs the task and port=...") and a port given to the sim was passed on
    Case("train npg on the robot without a port", ("train", "npg", "--backend", "hardware",
                                                   "--out", "{tmp}/r"),
         "--backend hardware needs --port"),
    Case("train tvlg on the robot without a port", ("train", "tvlg", "--backend", "hardware",
                                                    "--out", "{tmp}/r"),
         "--backend hardware needs --port"),
    Case("train npg in the sim with a port", ("train", "npg", "--backend", "sim", "--port",
                                              "/dev/ttyUSB0", "--out", "{tmp}/r"),
         "--port /dev/ttyUSB0 is for --backend hardware"),
    Case("transfer with a latency of nan ms", ("transfer", "--out", "{tmp}/t", "--port",
                                               "/dev/ttyUSB7", "--latency-ms", "nan"),
         "argument --latency-ms: 'nan' is not a finite number in [0.5, 1000]"),
    Case("emulate with a drop probability of 1.5", ("emulate", "bench", "--drop", "1.5"),
         "argument --drop: '1.5' is not a finite number in [0, 1]"),
    Case("record-log for nan seconds", ("record-log", "--port", "emulated", "--seconds", "nan",
                                        "--out", "{tmp}/logs"), "argument --seconds: 'nan' is not a finite number in (0, 3600]"),
    # gap analyze: the time column
    csv_case("time in ns since the epoch",
             csv_text(servo_log(), time=lambda t: str(EPOCH_NS + round(t * 1e9))),
             ": ns? (100 Hz if so); divide the time stamps by 1e+09"),
    csv_case("time in ms", csv_text(servo_log(), time=lambda t: f"{t * 1e3:.1f}"),
             "median step is 10: ms?"),
    csv_case("time in minutes", csv_text(servo_log(seconds=60), time=lambda t: f"{t / 60:.8f}"),
             "column 'time' looks like minutes, not seconds: read as seconds, 'qpos:arm' would "
             "move at 561.4 rad/s (99th percentile; servos stay below 100), in minutes at 9.36; "
             "6000 samples over 59.99 s at 100 Hz if so: multiply the time stamps by 60"),
    csv_case("8 s in minutes", csv_text(servo_log(), time=lambda t: f"{t / 60:.8f}"),
             "column 'time' looks like minutes, not seconds: read as seconds, 'qpos:arm' would "
             "move at"),
    csv_case("a slow sweep in minutes, with velocities",
             csv_text(slow_log(), time=lambda t: f"{t / 60:.8f}"),
             "column 'time' looks like minutes, not seconds: read as seconds, 'qpos:arm' changes "
             "57.5 x faster than its logged velocity 'qvel:arm'; 250 samples over 4.98 s at 50 Hz "
             "if so: multiply the time stamps by 60"),
    # two rows swapped, a row written twice, a NaN reading: repaired and said since issue 12's
    # second pass (tests/test_careless_cli.py checks the repaired rows against the clean log);
    # a time stamp repeated with other values, rows far out of order: refused there
    csv_case("a gap that leaves no usable stretch",
             csv_text(rows(edited(time=lambda t: t + 30.0 * (t >= 0.3)), slice(0, 60))),
             "time stamps jump (30 s after 0.29 s (row 29)) and no stretch"),
    csv_case("a log of 2 hours", csv_text(servo_log(seconds=7300, rate=4.0)),
             "column 'time' spans 7299.75 s; at most 3600 s per log"),
    # gap analyze: values
    csv_case("positions of 1e9 rad", csv_text(edited(qpos=lambda q: q + 1e9)),
             "column 'qpos:arm' has 1e+09 rad at row 0 (0-based); plausible: -12.5664 to "
             "12.5664 rad (broken data?)"),
    csv_case("positions in degrees", csv_text(edited(qpos=np.degrees, goal=np.degrees)),
             "(degrees? write rad)"),
    csv_case("positions in encoder ticks",
             csv_text(edited(qpos=lambda q: np.round(q / ENCODER_STEP) + 2048)),
             "(raw encoder ticks? write rad)"),
    csv_case("current in mA", csv_text(edited(current=lambda c: c * 1000)),
             "column 'current:arm' has 80 A at row 0 (0-based); plausible: -30 to 30 A (mA? "
             "write A)"),
    csv_case("an inf goal", csv_text(edited(goal=lambda g: np.where(np.arange(800) >= 790,
                                                                     np.inf, g))),
             "column 'goal:arm' has 10 NaN/inf values (first at row 790)"),
    csv_case("a frozen encoder", csv_text(edited(qpos=lambda q: np.where(np.arange(800) >= 200,
                                                                          q[200], q))),
             "column 'qpos:arm' is frozen at -0.48167 rad for 5.99 s (from 2 s) while 'goal:arm' "
             "moves over [-1.1, 1.1] rad"),
    csv_case("a constant position", csv_text(edited(qpos=lambda q: q * 0 + 0.25))
             , "column 'qpos:arm' is frozen at 0.25 rad"),
    csv_case("a current clipped by its sensor",
             csv_text(edited(current=lambda c: np.clip(c, -0.3, 0.3))),
             "column 'current:arm' sits at its largest value 0.3 in"),
    csv_case("a position clipped by a 12-bit register, with velocities",
             csv_text({**with_velocity(servo_log()),
                       "qpos:arm": window_12bit(servo_log()["qpos:arm"], 3600)}),
             "column 'qpos:arm' is pinned at its largest value 0.75932 rad for 0.44 s (from "
             "0.32 s) while 'goal:arm' is up to 0.341 rad beyond it, while 'qvel:arm' takes the "
             "motor 0.346 rad beyond it and back"),  # to 1.105 rad, the lag's true peak
    csv_case("a position clipped at the encoder window's edge",
             csv_text(edited(qpos=lambda q: window_12bit(q, 0))),
             "column 'qpos:arm' is pinned at its smallest value 0 rad for"),
    csv_case("a position register that wraps",
             csv_text(edited(qpos=lambda q: np.mod(q, 2 * np.pi))),
             "column 'qpos:arm' jumps by +6.265 rad (one turn) from row 116 to 117 (0-based, at "
             "1.17 s), 8 time(s): a position register wrapping at its range"),
    csv_case("a voltage column of zeros", csv_text({**servo_log(), "voltage:arm": np.zeros(800)}),
             "column 'voltage:arm' reads 0 V in 100 % of the samples with torque on while the "
             "motor moves its joint"),
    csv_case("a temperature column of zeros",
             csv_text({**servo_log(), "temperature:arm": np.zeros(800)}),
             "column 'temperature:arm' reads exactly 0 deg C all along"),
    csv_case("too little motion to identify anything",
             csv_text(edited(goal=lambda g: 0.004 * g, qpos=lambda q: np.round(
                 0.004 * q / ENCODER_STEP) * ENCODER_STEP)),
             "too little motion to identify anything: peak-to-peak qpos [rad] arm 0.0092"),
    csv_case("too few samples", csv_text(rows(servo_log(), slice(0, 12))),
             "too little data: 12 samples"),
    csv_case("a header and no rows", "time,goal:arm,qpos:arm\n", "too little data: 0 samples"),
    csv_case("an empty file", "", "empty file (no header row)"),
    # a spreadsheet's ';' and decimal commas are read since session 18 (tests/test_careless13.py)
    csv_case("units typed into the cells",
             csv_text(servo_log()).replace("\n0.0100,", "\n0.0100 s,", 1),
             "row 3, column 'time': '0.0100 s' is not a number"),
    csv_case("a binary file named .csv", bytes(range(256)) * 64, "not a text CSV file"),
    # a folder means every log in it (gap.dataset.expand_log_paths); this one holds none
    Case("a log that is a folder", analyze("logs.csv"),
         "logs.csv: a folder without logs (.csv, .npz, .json)",
         files={"bench.xml": bench_model, "logs.csv/readme.txt": "raw data\n"}),
    Case("an NPZ that is not one", analyze("log.npz"), "not a readable NPZ log",
         files={"bench.xml": bench_model, "log.npz": csv_text(servo_log())}),
    # gap analyze: BAM JSON
    bam_case("BAM: an empty file", "", "empty file"),
    bam_case("BAM: a binary file", bytes(range(256)) * 64, "binary data, not text"),
    bam_case("BAM: truncated JSON", json.dumps(bam_log())[:5000], "not a readable BAM JSON log"),
    # layout of Rhoban/bam data/pwm_mx64.json@c50ae40 (PWM duty measurements, not a time series)
    bam_case("BAM: another JSON in the logs' folder",
             json.dumps({"pwm_period": 42.6, "samples": [{"target": 157.24, "position": 165.2,
                         "voltage": 15.0, "period": 4.5, "kp": 5}]}),
             "not a BAM raw log (its keys: pwm_period, samples); a BAM raw log is an object with "
             "mass, length, kp, vin, motor, entries"),
    bam_case("BAM: a list, not an object", json.dumps([bam_log()]), "must be a JSON object, got list"),
    bam_case("BAM: mass with its unit", json.dumps(bam_log(mass="0.49 kg")),
             "'mass': \"0.49 kg\" is not a number"),
    bam_case("BAM: kp null", json.dumps(bam_log(kp=None)), "'kp': null is not a number"),
    bam_case("BAM: a negative length", json.dumps(bam_log(length=-0.1)),
             "'length': -0.1 must be a finite positive number"),
    bam_case("BAM: the motor as a number", json.dumps(bam_log(motor=330)),
             "'motor' must be a string, got 330"),
    bam_case("BAM: entries as an object", json.dumps(bam_log(entries={"0": {}})),
             "'entries' must be a list of samples, got dict"),
    bam_case("BAM: an entry that is a list", json.dumps(bam_log(entries=[[0.0, 0.1, 0.1]] * 30)),
             "entries[0] must be an object"),
    bam_case("BAM: a position as a string", bam_with("position", "0.52"),
             "entries[40].position: \"0.52\" is not a number"),
    bam_case("BAM: torque_enable as text", bam_with("torque_enable", "on"),
             "entries[40].torque_enable: \"on\" is not a number"),
    bam_case("BAM: a NaN position", bam_with("position", float("nan")),
             "entries[40].position: nan must be a finite number"),
    bam_case("BAM: a missing goal", json.dumps(bam_log(entries=[
        {"timestamp": 0.005 * i, "position": 0.0} for i in range(300)])),
        "entries[0] lacks 'goal_position'"),
    bam_case("BAM: time stamps in ms", json.dumps(bam_log(entries=[
        {**e, "timestamp": e["timestamp"] * 1e3} for e in bam_log()["entries"]])),
        "median step is 5.26316: ms?"),
    # CLI numbers
    Case("--min-gain nan", analyze("log.csv", "--min-gain", "nan"),
         "argument --min-gain: 'nan' is not a finite number in (0, 1)"),
    Case("--max-effects -1", analyze("log.csv", "--max-effects", "-1"),
         "argument --max-effects: '-1' is not an integer in [1, 20]"),
    Case("--threads -3", analyze("log.csv", "--threads", "-3"),
         "argument --threads: '-3' is not an integer in [0, 1024]"),
    Case("--seed -1", analyze("log.csv", "--seed", "-1"), "'-1' is not an integer >= 0"),
    Case("generate for 1e9 s", ("gap", "generate", "--duration", "1e9", "--out", "{tmp}/d"),
         "argument --duration: '1e9' is not a finite number in [1, 3600]"),
    Case("generate at 0 Hz", ("gap", "generate", "--rate", "0", "--out", "{tmp}/d"),
         "argument --rate: '0'"),
    # --out: a user's folder is refused untouched, before any work
    Case("analyze into a user's folder", analyze("log.csv")[:-2] + ("--out", "{tmp}/thesis"),
         "already holds files that lowcostdex did not write",
         files={"bench.xml": bench_model, "log.csv": csv_text(servo_log()),
                "thesis/chapter1.tex": "\\chapter{Servo identification}\n"}),
    Case("analyze into the folder of its logs", analyze("log.csv")[:-2] + ("--out", "{tmp}"),
         "already holds files that lowcostdex did not write",
         files={"bench.xml": bench_model, "log.csv": csv_text(servo_log())}),
    Case("analyze into a file", analyze("log.csv")[:-2] + ("--out", "{tmp}/log.csv"),
         "is a file, not a folder",
         files={"bench.xml": bench_model, "log.csv": csv_text(servo_log())}),
    Case("generate into a user's folder", ("gap", "generate", "--out", "{tmp}/data"),
         "already holds files that lowcostdex did not write",
         files={"data/run1.csv": csv_text(servo_log())}),
    Case("record-log into a user's folder", ("record-log", "--port", "emulated", "--logs", "1",
                                             "--out", "{tmp}/logs"),
         "already holds files that lowcostdex did not write (log_0.csv)",
         files={"logs/log_0.csv": csv_text(servo_log())}),
    Case("model over a user's file", ("model", "bench", "--out", "{tmp}/arm.xml"),
         "--out {tmp}/arm.xml already exists and is left untouched",
         files={"arm.xml": "<mujoco model='my tuned arm'/>\n"}),
]


# ------------------------------------------------------------------------------------------------
# the checks


def _snapshot(root):
    return {str(p.relative_to(root)): (p.read_bytes() if p.is_file() else None)
            for p in sorted(root.rglob("*"))}


def _materialize(case: Case, tmp) -> list[str]:
    for name, content in case.files.items():
        path = tmp / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if callable(content):
            content = content()
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content.replace("{tmp}", str(tmp)))
    return [a.replace("{tmp}", str(tmp)) for a in case.argv]


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_bad_input_is_refused_cleanly(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = _materialize(case, tmp_path)
    before = _snapshot(tmp_path)
    code = main(argv)
    out, err = capsys.readouterr()
    assert code == case.code, err
    assert case.message.replace("{tmp}", str(tmp_path)) in err, err
    assert "Traceback" not in err + out
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err  # one line (progress bars are transient and go to stderr too)
    assert ": error: " in lines[0]
    assert _snapshot(tmp_path) == before  # the user's files as they were, nothing new


def test_the_unbroken_logs_load(tmp_path):
    """The control: the table's logs before their edits are accepted (CSV with a spreadsheet's
    byte-order mark, BAM JSON), so each refusal above comes from its edit."""
    from lowcostdex.gap.dataset import load_dataset

    (tmp_path / "bench.xml").write_text(bench_model())
    (tmp_path / "log.csv").write_text("\ufeff" + csv_text(servo_log()), encoding="utf-8")
    ds = load_dataset([tmp_path / "log.csv"], model=tmp_path / "bench.xml")
    assert len(ds.trajectories[0]) == 800 and ds.notes == []
    (tmp_path / "bam.json").write_text(json.dumps(bam_log()))
    ds = load_dataset([tmp_path / "bam.json"])
    assert len(ds.trajectories[0]) == 1140 and ds.trajectories[0].channels["torque_enable"].all()


def test_steady_channels_and_a_hard_stop_are_not_refused():
    """What the clip and dead-channel rules must leave alone: a supply that reads one 0.1 V count
    all along, a winding at 31-32 deg C (quantised channels at rest), and a joint held by a hard
    stop at 0.8 rad while its goal pushes up to 0.3 rad past it - reading still, its Present
    Velocity 0 (a stall is physics, not a clip)."""
    from lowcostdex.gap.logs import trajectory_from_columns

    cols = servo_log()
    n = len(cols["time"])
    steady = {**cols, "voltage:arm": np.full(n, 12.1),
              "temperature:arm": np.where(np.arange(n) < 500, 31.0, 32.0)}
    traj = trajectory_from_columns(steady)
    assert set(traj.channels) == {"current", "voltage", "temperature"}
    stop, lag = 0.8, 0.06
    goal, keep = cols["goal:arm"], math.exp(-1 / (100.0 * lag))
    q = np.zeros(n)
    for k in range(1, n):  # servo_log's lag, stopped at 0.8 rad
        q[k] = min(keep * q[k - 1] + (1 - keep) * goal[k - 1], stop)
    blocked = (q >= stop) & (goal > stop)
    cols["qpos:arm"] = np.round(q / ENCODER_STEP) * ENCODER_STEP
    cols["qvel:arm"] = np.where(blocked, 0.0, (goal - q) / lag)
    assert blocked.sum() > 20 and (goal - stop).max() > 0.29  # held there, the goal beyond
    trajectory_from_columns(cols)
    del cols["qvel:arm"]
    trajectory_from_columns(cols)


def test_a_gap_splits_the_log_and_says_so(tmp_path):
    """Logging paused for 5 s: two pieces, each replayed from its own measured state; a held-out
    log stays held out whole."""
    from lowcostdex.gap.dataset import load_dataset

    (tmp_path / "bench.xml").write_text(bench_model())
    (tmp_path / "log.csv").write_text(csv_text(edited(time=lambda t: t + 5.0 * (t >= 3.0))))
    ds = load_dataset([tmp_path / "log.csv"], model=tmp_path / "bench.xml")
    assert [len(tr) for tr in ds.trajectories] == [300, 500]
    assert ds.trajectories[1].time[0] == pytest.approx(8.0)
    assert ds.sources == [str(tmp_path / "log.csv")] * 2
    assert ds.notes == ["log.csv: time jumps 5.01 s after 2.99 s (row 299); split into 2 "
                        "piece(s)"]


def test_runaway_inputs_are_bounded(tmp_path, monkeypatch):
    """Rows are read up to the cap, then refused (a huge CSV does not fill the memory); the total
    duration of one analysis is bounded."""
    from lowcostdex.gap import dataset, logs

    (tmp_path / "bench.xml").write_text(bench_model())
    (tmp_path / "log.csv").write_text(csv_text(servo_log()))
    monkeypatch.setattr(logs, "MAX_SAMPLES", 500)
    with pytest.raises(logs.LogError, match="more than 500 rows; at most 500 per log"):
        dataset.load_dataset([tmp_path / "log.csv"], model=tmp_path / "bench.xml")
    monkeypatch.setattr(logs, "MAX_SAMPLES", 10**6)
    monkeypatch.setattr(dataset, "MAX_TOTAL_DURATION", 10.0)
    (tmp_path / "log2.csv").write_text(csv_text(servo_log()))  # (one log given twice: refused)
    with pytest.raises(logs.LogError, match="2 logs of 15.98 s in all; one analysis takes at most"):
        dataset.load_dataset([tmp_path / "log.csv", tmp_path / "log2.csv"],
                             model=tmp_path / "bench.xml")


# ------------------------------------------------------------------------------------------------
# the error path itself


def test_a_bug_keeps_its_traceback(monkeypatch):
    import lowcostdex.hardware.cli as hw

    def bug(args):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(hw, "_scan", bug)
    with pytest.raises(ZeroDivisionError):
        main(["scan", "--port", "emulated"])


def test_ctrl_c_is_one_line_and_exit_130(monkeypatch, capsys):
    import lowcostdex.hardware.cli as hw

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(hw, "_scan", interrupted)
    assert main(["scan", "--port", "emulated"]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "lowcostdex scan: error: interrupted (Ctrl-C)"


def test_help_is_not_an_error(capsys):
    assert main(["gap", "analyze", "--help"]) == 0
    assert "--debug" in capsys.readouterr().out


def _run(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "lowcostdex.cli", *argv], capture_output=True,
                          text=True, timeout=120)


def test_scan_on_a_missing_port_is_one_line_for_a_user():
    """Issue 12: this was a 35-line pyserial traceback."""
    run = _run("scan", "--port", "/dev/does-not-exist")
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr.count("\n") == 1 and "Traceback" not in run.stderr
    assert "plug in the USB adapter" in run.stderr and "--port emulated" in run.stderr


def _as_at_a_terminal() -> None:
    """SIGINT back to its default in the child, as a shell gives a command run at a terminal: a
    background job (`pytest ... &`) inherits SIGINT ignored, and Python then never raises
    KeyboardInterrupt, so the signal would test nothing."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_ctrl_c_during_an_analysis_leaves_no_output_and_the_logs_as_they_were(tmp_path):
    """A real SIGINT to a running `gap analyze` (as a user's Ctrl-C): exit 130, one line, no
    traceback, no report or temporary folder left, the inputs byte for byte."""
    import signal

    (tmp_path / "bench.xml").write_text(bench_model())
    (tmp_path / "log.csv").write_text(csv_text(servo_log()))
    before = _snapshot(tmp_path)
    proc = subprocess.Popen(
        [sys.executable, "-m", "lowcostdex.cli", "gap", "analyze", "--model", "bench.xml", "--log",
         "log.csv", "--out", "report"], cwd=tmp_path, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True, preexec_fn=_as_at_a_terminal)
    first = proc.stderr.readline()  # the progress line: the analysis is under way
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert "gap analysis" in first, first + err
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "lowcostdex gap analyze: error: interrupted (Ctrl-C)"
    assert "Traceback" not in err + out
    assert _snapshot(tmp_path) == before


def test_debug_shows_the_traceback_of_a_user_error():
    """As a user runs it (a process): one line without --debug; the traceback with it, before or
    after the subcommand."""
    plain = _run("reset-test", "--trials", "0")
    assert plain.returncode == 2 and "Traceback" not in plain.stderr
    assert plain.stderr.strip() == "lowcostdex reset-test: error: --trials must be >= 1"
    for argv in (("--debug", "reset-test", "--trials", "0"),
                 ("reset-test", "--trials", "0", "--debug")):
        debug = _run(*argv)
        assert debug.returncode == 2
        assert "Traceback" in debug.stderr and "ConfigError: --trials must be >= 1" in debug.stderr
