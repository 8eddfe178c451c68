"""Measured servo logs: the project's CSV/NPZ format, BAM raw-log JSON, validation, ZOH resampling.

The project's log format (one file = one trajectory) has one row per sample and columns

    time                    [s]     strictly increasing (host clock when the row's values
                                    were sampled)
    goal:<actuator>         [rad]   goal position written right after the row was read
    goal_time               [s]     (optional) when that goal reached the motors; absent: at
                                    ``time``. On a bus the goal follows the read's replies and
                                    its own packet, a few ms that otherwise look like latency.
    qpos:<joint>            [rad]   measured joint position
    qvel:<joint>            [rad/s] measured joint velocity (optional)
    current:<actuator>      [A]     (optional)
    voltage:<actuator>      [V]     measured supply at the servo (optional)
    temperature:<actuator>  [deg C] (optional)
    torque_enable:<actuator> 0/1    (optional; 1 when absent)

as CSV (a header row of these names) or NPZ (one 1-D array per name). Goals are held between rows
(zero-order hold), never interpolated. BAM raw-log JSON (Rhoban/bam's pendulum benches) is mapped
onto the servo bench (``lowcostdex.sim.models.bench``) from its header (mass, length, arm_mass,
kp, vin, motor); see ``read_bam``.

This module reads and writes the files and cuts logs at gaps; it re-exports the parts that live
beside it: ``trajectory`` (the ``Trajectory`` type, ZOH resampling), ``log_checks`` (the checks
on entry and their limits), ``log_csv`` (reading a CSV log) and ``bam_logs`` (BAM JSON).
"""

from __future__ import annotations

import csv
import math
import numbers
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np

from lowcostdex.gap import log_units as units
from lowcostdex.gap.bam_logs import BAM_MOTORS, is_bam, read_bam
from lowcostdex.gap.log_checks import (
    CHANNELS,
    CLIP_PILE,
    FROZEN_CROSS,
    MAX_DURATION,
    MAX_JSON_BYTES,
    MAX_SAMPLES,
    MIN_DURATION,
    MIN_MOTION,
    MIN_SAMPLES,
    MIN_SUPPLY,
    PINNED_RUN,
    PINNED_SPEED,
    PINNED_TRAVEL,
    PLAUSIBLE,
    PREFIXES_ACTUATOR,
    PREFIXES_JOINT,
    RANGE_MARGIN,
    SATURATED_SHARE,
    STEP_RANGE,
    WRAP_TOLERANCE,
    check_signals,
    trajectory_from_columns,
)
from lowcostdex.gap.log_csv import MAX_COLUMNS, is_channel, read_csv
from lowcostdex.gap.log_paths import (
    csv_under_another_name,
    folder_not_log,
    model_for,
    more_of_the_hand,
    no_such_log,
)
from lowcostdex.gap.trajectory import (
    GAP_FACTOR,
    GAP_MIN,
    LogError,
    Trajectory,
    find_gaps,
    quantization_step,
    zoh,
    zoh_index,
)
from lowcostdex.outdir import user_path

__all__ = [
    "BAM_MOTORS", "CHANNELS", "CLIP_PILE", "FROZEN_CROSS", "GAP_FACTOR", "GAP_MIN", "LogError",
    "MAX_DURATION", "MAX_JSON_BYTES", "MAX_SAMPLES", "MIN_DURATION", "MIN_MOTION", "MIN_SAMPLES",
    "MIN_SUPPLY", "PINNED_RUN", "PINNED_SPEED", "PINNED_TRAVEL", "PLAUSIBLE", "PREFIXES_ACTUATOR",
    "PREFIXES_JOINT", "RANGE_MARGIN", "SATURATED_SHARE", "STEP_RANGE", "Trajectory",
    "WRAP_TOLERANCE", "check_against_model", "check_signals", "estimate_velocity", "find_gaps",
    "actuator_gears", "is_bam", "quantization_step", "rate_goal_actuators", "read_bam", "read_columns", "read_log",
    "rest_at_start", "split_at_gaps",
    "trajectory_from_columns", "write_log", "zoh", "zoh_index",
]


# ------------------------------------------------------------------------------------------------
# reading and writing the project format


def read_columns(path: Path) -> dict[str, np.ndarray]:
    """Read a CSV or NPZ log into {column: float array}."""
    return _read_columns(path)[0]


def _read_columns(path: Path) -> tuple[dict[str, np.ndarray], list[str]]:
    """``read_columns`` and its notes (a CSV's text columns left out)."""
    path = user_path(path)
    notes: list[str] = []
    if not path.exists():
        raise no_such_log(path)
    suffix = path.suffix.lower()
    if path.is_dir():
        raise folder_not_log(path)
    if suffix == ".npz":
        text = _check_npz_shapes(path)
        notes = [f"{path.name}: array {k!r} holds text, not a log channel; left out"
                 for k in text]
        try:
            with np.load(path, allow_pickle=False) as z:
                cols = {k: np.asarray(z[k], dtype=float) for k in z.files if k not in text}
        except (OSError, ValueError, TypeError, EOFError) as exc:  # not a zip, object arrays
            raise LogError(f"{path}: not a readable NPZ log ({exc})") from None
    elif suffix == ".csv":
        cols, notes = read_csv(path, MAX_SAMPLES)
    else:
        hint = (" (a LeRobot dataset's episode file? write each episode as a CSV with one "
                "column per joint: 'time', 'goal:<actuator>', 'qpos:<joint>')"
                if suffix == ".parquet" else csv_under_another_name(path))
        raise LogError(f"{path}: unknown log type {suffix!r}; valid: .csv, .npz, .json (BAM)"
                       + hint)
    for k, v in cols.items():
        if v.ndim != 1:
            raise LogError(f"{path}: column {k!r} must be 1-D, got shape {v.shape}")
    lengths = {len(v) for v in cols.values()}
    if len(lengths) > 1:
        raise LogError(f"{path}: columns have different lengths {sorted(lengths)}")
    if lengths and max(lengths) > MAX_SAMPLES:
        raise LogError(f"{path}: {max(lengths)} samples; at most {MAX_SAMPLES} per log "
                       "(split the log into shorter ones)")
    return cols, notes


def _check_npz_shapes(path: Path) -> dict[str, np.dtype]:
    """Refuse an NPZ whose arrays are not columns of at most ``MAX_SAMPLES`` numbers, or that
    holds more than ``MAX_COLUMNS`` of them, from the arrays' headers alone: loading first let a
    31 MB file of compressed zeros ask for 7 GB (and end in a MemoryError traceback).
    Returns the arrays of text that are not channels (a user's notes: left out)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as zf:
            members = [m for m in zf.infolist() if m.filename.endswith(".npy")]
            text: dict[str, np.dtype] = {}
            if len(members) > MAX_COLUMNS:
                raise LogError(f"{path}: {len(members)} arrays; a log has at most {MAX_COLUMNS} "
                               "columns")
            for m in members:
                with zf.open(m) as f:
                    version = np.lib.format.read_magic(f)
                    read = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                            else np.lib.format.read_array_header_2_0)
                    shape, _, dtype = read(f)
                name = m.filename[:-4]
                if len(shape) != 1:
                    raise LogError(f"{path}: column {name!r} must be 1-D, got shape {shape}")
                if shape[0] > MAX_SAMPLES:
                    raise LogError(f"{path}: column {name!r} has {shape[0]} samples; at most "
                                   f"{MAX_SAMPLES} per log (split the log into shorter ones)")
                if dtype.kind in "US" and not is_channel(name):  # a user's note: left out
                    text[name] = dtype
                elif dtype.kind not in "biuf":
                    raise LogError(f"{path}: column {name!r} holds {dtype} values, not numbers")
        return text
    except LogError:
        raise
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as exc:
        raise LogError(f"{path}: not a readable NPZ log ({exc})") from None


def split_at_gaps(traj: Trajectory) -> tuple[list[Trajectory], list[str]]:
    """Cut a trajectory where its time stamps jump (logging paused): each piece replays from its
    own measured state. Pieces too short to use are left out.

    Returns:
      (pieces, notes): the usable pieces (the trajectory itself when it has no gap) and one line
      per gap saying where it is and what was done.
    Raises:
      LogError: no piece is long enough (the message names the gaps).
    """
    gaps = find_gaps(traj.time)
    cuts = sorted(set(int(c) for c in traj.meta.get("cuts", ())) - {int(i) + 1 for i in gaps})
    if not len(gaps) and not cuts:
        return [traj], []
    t = traj.time
    # wall-clock stamps (time.time(): 1.7e9 s) print as 1.7327e+09 s: say those from the start
    at = (lambda i: f"{t[i] - t[0]:.6g} s into the log") if abs(t[0]) >= 1e4 else (
        lambda i: f"{t[i]:.6g} s")
    said = ", ".join(f"{t[i + 1] - t[i]:.3g} s after {at(i)} (row {i})" for i in gaps[:3])
    said += f" and {len(gaps) - 3} more" if len(gaps) > 3 else ""
    if cuts:
        said += (", and " if len(gaps) else "") + (
            f"dropped rows where the goal may have changed before {at(cuts[0])} (row "
            f"{cuts[0]})" + (f" and {len(cuts) - 1} more" if len(cuts) > 1 else ""))
    edges = sorted({0, *(int(i) + 1 for i in gaps), *cuts, len(t)})
    pieces, dropped = [], 0
    for k, (a, b) in enumerate(zip(edges[:-1], edges[1:], strict=True)):
        if b - a >= MIN_SAMPLES and t[b - 1] - t[a] >= MIN_DURATION:
            piece = traj.slice(a, b, name=f"{traj.name}#{k + 1}")
            if a > 0:  # its first row is inside the log: not a start from rest
                piece = replace(piece, meta={**traj.meta, "mid_log": True})
            pieces.append(piece)
        else:
            dropped += 1
    if not pieces:
        raise LogError(f"{traj.name}: time stamps jump ({said}) and no stretch between the "
                       f"jumps has {MIN_SAMPLES} samples over {MIN_DURATION} s"
                       if len(gaps) and not cuts else
                       f"{traj.name}: the log is cut at {said} and no stretch between the "
                       f"cuts has {MIN_SAMPLES} samples over {MIN_DURATION} s")
    note = (f"{traj.name}: {'time jumps ' if len(gaps) else ''}{said}; split into "
            f"{len(pieces)} piece(s)"
            + (f", {dropped} too short to use left out" if dropped else ""))
    return pieces, [note]


def read_log(path: str | Path, rate_goals: frozenset[str] | set[str] = frozenset(),
             gears: dict[str, float] | None = None, angle_scale: float = 1.0,
             time_scale: float = 1.0, force_goals: frozenset[str] = frozenset()) -> Trajectory:
    """Read one log (CSV, NPZ or BAM JSON; BAM logs carry their bench setup in ``meta``).
    ``rate_goals``: actuators whose goal is a velocity [rad/s] (integrating servos);
    ``gears``: actuator -> gear (its goal is gear x the joint angle); ``angle_scale``: rad per
    unit of a project-format log's goal, qpos and qvel columns (pi/180: logged in degrees);
    ``time_scale``: seconds per unit of its 'time' and 'goal_time' columns (1e-3: integer
    milliseconds); qvel stays per second; ``force_goals``: actuators whose goal is a force [N m]."""
    for name, value, e_g in (("angle_scale", angle_scale, "math.pi / 180 for degrees"),
                             ("time_scale", time_scale, "1e-3 for milliseconds")):
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
        if not ok or not math.isfinite(value) or value <= 0:  # "deg" was read as a number
            raise LogError(f"read_log {name}={value!r} must be a positive number ({e_g}; "
                           "load_dataset takes angle_unit='deg' and time_unit='ms')")
    path = user_path(path)
    if path.suffix.lower() == ".json":
        return read_bam(path)[0]
    cols, notes = _read_columns(path)
    if angle_scale != 1.0:
        for key, arr in cols.items():  # a log in rad given as degrees
            kind, _, joint = (t.strip() for t in str(key).partition(":"))
            if kind.lower() == "qpos" and joint:
                units.check_not_radians(np.asarray(arr, float), joint, path.name)
            if joint and kind.lower() in ("goal", "qpos", "qvel") and not (  # a motor's goal:
                    kind.lower() == "goal" and joint in force_goals):  # a torque, no angle
                cols[key] = np.asarray(arr, float) * angle_scale
    if time_scale != 1.0:
        cols = {k: (np.asarray(v, float) * time_scale
                    if str(k).strip().lower() in ("time", "goal_time") else v)
                for k, v in cols.items()}
    try:
        traj = trajectory_from_columns(cols, name=path.name, rate_goals=rate_goals, gears=gears)
    except LogError as exc:  # the time stamps may be the text column left out: say so
        text = [n.split(": ", 1)[1] for n in notes if n.endswith("not a log channel; left out")]
        if text and "missing column 'time'" in str(exc):
            raise LogError(f"{exc} (dates and times there are read as seconds); "
                           + "; ".join(text)) from None
        raise
    if notes:
        traj.meta["notes"] = [*notes, *traj.meta.get("notes", [])]
    return traj


def rate_goal_actuators(model: mujoco.MjModel) -> frozenset[str]:
    """Actuators whose input is a velocity that they integrate into a position setpoint (an
    ``intvelocity``, or any non-dcmotor actuator with integrator dynamics): their log goal is
    in rad/s."""
    dyn = model.actuator_dyntype == mujoco.mjtDyn.mjDYN_INTEGRATOR
    dc = model.actuator_gaintype == mujoco.mjtGain.mjGAIN_DCMOTOR
    return frozenset(model.actuator(int(a)).name for a in np.flatnonzero(dyn & ~dc))


def actuator_gears(model: mujoco.MjModel) -> dict[str, float]:
    """Actuator name -> gear, for actuators whose gear is not 1 (their goal is in actuator
    units: gear x the joint angle)."""
    return {model.actuator(i).name: float(model.actuator_gear[i, 0]) for i in range(model.nu)
            if model.actuator_gear[i, 0] not in (0.0, 1.0)}


def write_log(path: str | Path, traj: Trajectory) -> Path:
    """Write a trajectory in the project format (CSV or NPZ by suffix)."""
    if isinstance(path, Trajectory) and not isinstance(traj, Trajectory):
        raise LogError("write_log(path, traj): the path comes first")
    if not isinstance(traj, Trajectory):
        raise LogError(f"write_log(path, traj) writes a lowcostdex.gap.Trajectory (name, time "
                       f"[s], goal and qpos [rad] arrays, actuator and joint names), not "
                       f"{type(traj).__name__}")
    path = user_path(path)
    cols = traj.to_columns()
    if path.suffix.lower() == ".npz":
        np.savez_compressed(path, **cols)
    elif path.suffix.lower() == ".csv":
        names = list(cols)
        data = np.stack([cols[n] for n in names], axis=1)
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(names)
            for row in data:
                w.writerow([repr(float(x)) for x in row])
    else:
        raise LogError(f"{path}: unknown log type {path.suffix!r}; valid: .csv, .npz")
    return path


def check_against_model(traj: Trajectory, model: mujoco.MjModel) -> None:
    """Check that the log's names exist in ``model`` and that every actuator has a goal.

    A goal is the actuator's ctrl: a position goal for position servos, a force/torque for a
    ``motor``, a velocity for a ``velocity`` actuator. Position goals logged for a ``motor`` or
    ``velocity`` actuator (they track the joint's angle) are refused: the model does not
    describe the servo that took them.

    Raises:
      LogError naming the unknown or missing names and listing the model's.
    """
    act_names = [model.actuator(i).name for i in range(model.nu)]
    jnt_names = [model.joint(i).name for i in range(model.njnt)]
    if traj.actuators and not act_names:  # "actuators: " and nothing after it said nothing
        j = traj.actuators[0]
        raise LogError(f"{traj.name}: 'goal:{j}': the model has no actuators; the logged goals "
                       f"need one per joint, e.g. <actuator><position name=\"{j}\" "
                       f"joint=\"{j}\" kp=\"...\"/></actuator> (the servo's position gain)")
    for a in traj.actuators:
        if a not in act_names:
            other = more_of_the_hand(traj.actuators) if set(traj.actuators) & set(
                act_names) else (  # another robot's log
                f"; none of the log's actuators ({', '.join(traj.actuators)}) is in the model: "
                f"a log of another robot, or another robot's model? {model_for(traj.actuators)}")
            raise LogError(f"{traj.name}: 'goal:{a}': no actuator {a!r} in the model; "
                           f"actuators: {', '.join(act_names)}{other}")
    for j in traj.joints:
        if j not in jnt_names:
            hint = ""
            if j in act_names and model.actuator_trntype[act_names.index(j)] == \
                    mujoco.mjtTrn.mjTRN_JOINT:  # named after the servo, not its joint
                driven = model.joint(int(model.actuator_trnid[act_names.index(j), 0])).name
                hint = (f" ({j!r} is the actuator driving joint {driven!r}: name the column "
                        f"'qpos:{driven}')")
            raise LogError(f"{traj.name}: 'qpos:{j}': no joint {j!r} in the model; "
                           f"joints: {', '.join(jnt_names)}{hint}")
        jid = model.joint(j).id
        jt = model.jnt_type[jid]
        if int(jt) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
            raise LogError(f"{traj.name}: joint {j!r} is not a hinge or slide joint")
        if model.jnt_limited[jid]:
            lo, hi = model.jnt_range[jid]
            q = traj.qpos[:, traj.joints.index(j)]
            bad = (q < lo - RANGE_MARGIN) | (q > hi + RANGE_MARGIN)
            if bad.any():
                i = int(np.argmax(bad))
                why = "calibration offset or sign, or another joint's column?"
                deg = np.radians(q)
                # a range of radians read as degrees is at most 2 pi deg (0.11 rad) wide: then
                # the model is off; else a log whose degrees fit the range is in degrees
                tiny = hi - lo <= math.radians(2 * math.pi) and np.ptp(q) > 2 * (hi - lo)
                if not tiny and np.all((deg >= lo - RANGE_MARGIN) & (deg <= hi + RANGE_MARGIN)):
                    why = (f"degrees? read as degrees it spans [{deg.min():.4g}, "
                           f"{deg.max():.4g}] rad, inside the range: {units.TO_RAD}")
                elif np.ptp(q) > 2 * (hi - lo):  # a range in degrees read as rad would be this
                    why = (f"the model's range is {hi - lo:.3g} rad wide while the joint moves "
                           f"{np.ptp(q):.3g} rad: MJCF reads joint 'range' in degrees unless "
                           "<compiler angle=\"radian\"/>")
                raise LogError(f"{traj.name}: column 'qpos:{j}' reads {q[i]:.6g} rad at row {i} "
                               f"(0-based), outside the model's joint range [{lo:.4g}, "
                               f"{hi:.4g}] rad by more than {RANGE_MARGIN} rad ({why})")
    missing = [a for a in act_names if a not in traj.actuators]
    for a in missing:  # a second actuator on a logged servo's joint: say which and the fix
        i = act_names.index(a)
        beside = [b for b in traj.actuators if b in act_names and _same_joint(model, i,
                                                                              act_names.index(b))]
        if beside:
            raise LogError(f"{traj.name}: actuator {a!r} drives the joint of the logged actuator "
                           f"{beside[0]!r} but has no 'goal:{a}' column: one servo per joint "
                           "is analysed; fold it into that servo (a damper: kv on the "
                           "<position>, or biasprm[2] on the <general>) or remove it, or log "
                           "its command")
    if missing:
        raise LogError(f"{traj.name}: no goal for actuators {missing}; the log must command "
                       "every actuator of the model: give a model of the logged joints only "
                       "(the project's hands: `lowcostdex model dclaw|allegro --station none "
                       "--fingers <the logged fingers>`)")
    rate = rate_goal_actuators(model)
    for i in range(model.nu):
        if model.actuator_ctrllimited[i] and act_names[i] in traj.actuators:
            lo, hi = (float(x) for x in model.actuator_ctrlrange[i])
            g = traj.goal[:, traj.actuators.index(act_names[i])]
            far = (g < lo - max(hi - lo, RANGE_MARGIN)) | (g > hi + max(hi - lo, RANGE_MARGIN))
            if far.any():  # a servo saturating stays near its range; this is another unit
                r = int(np.argmax(far))
                raise LogError(f"{traj.name}: column 'goal:{act_names[i]}' reads {g[r]:.6g} at "
                               f"row {r} (0-based), outside the model's ctrlrange [{lo:.4g}, "
                               f"{hi:.4g}] by more than its width (degrees? write rad; MuJoCo "
                               "would clamp it)")
        kind = units.not_a_position_servo(model, i)
        joint = (model.joint(int(model.actuator_trnid[i, 0])).name
                 if model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT else None)
        if kind == "a muscle" or (kind and joint in traj.joints and _position_like(
                traj.goal[:, traj.actuators.index(act_names[i])],
                traj.qpos[:, traj.joints.index(joint)])):
            raise LogError(f"{traj.name}: actuator {act_names[i]!r} is {kind}; the log's "
                           f"'goal:{act_names[i]}' is a position goal [rad]: model the servo as "
                           "<position kp=...> (or <general> with biastype=\"affine\" and a "
                           "-kp position term, or <intvelocity>) and re-run (its goals track "
                           f"'qpos:{joint}'; a log of this actuator's own input, a force/torque "
                           "or velocity, is replayed as it is)")
        if not kind and joint is not None and act_names[i] not in rate:  # goals in degrees
            units.check_goal_degrees(traj, model, i, joint, RANGE_MARGIN)
        if joint is not None:
            if joint not in traj.joints:
                raise LogError(f"{traj.name}: joint {joint!r} is driven by actuator "
                               f"{act_names[i]!r} but the log has no 'qpos:{joint}' column: every "
                               "replay would start it at the model's initial pose; log its "
                               "position too")
    units.check_model_speed(traj, model)  # degrees on a continuous joint


def model_needed(path: Path) -> LogError:
    """The error for project-format logs given without a model: with the ``lowcostdex model``
    command when the log's actuators are named as one of the project's hands (a record-log
    folder), read from the first log ``path``; before, only "need --model MODEL.xml"."""
    try:
        names = tuple(k.partition(":")[2].strip() for k in _read_columns(path)[0]
                      if k.lower().startswith("goal:"))
    except LogError:  # unreadable: the model is what is asked for here
        names = ()
    what = model_for(names) if names else ""
    return LogError("project-format logs need --model MODEL.xml (the MJCF of the robot that "
                    "wrote them)" + (f"; {what}" if what.startswith("its names") else ""))


def _same_joint(model: mujoco.MjModel, a: int, b: int) -> bool:
    """Whether actuators ``a`` and ``b`` both drive one joint."""
    return bool(model.actuator_trntype[a] == model.actuator_trntype[b]
                == mujoco.mjtTrn.mjTRN_JOINT
                and model.actuator_trnid[a, 0] == model.actuator_trnid[b, 0])


def _position_like(goal: np.ndarray, q: np.ndarray) -> bool:
    """Whether a ``motor`` or ``velocity`` actuator's logged inputs (T,) look like position goals
    of its joint's angles ``q`` (T,) [rad] rather than the forces/torques or velocities those
    actuators take: correlated with the angle (> 0.8), of the angle's spread (within 2x) and
    centred on it (within one spread). A torque log of a hanging arm correlates with its angle
    too, but its torques [N m] match the angles' spread and centre only by coincidence."""
    ok = np.isfinite(goal) & np.isfinite(q)
    g, x = goal[ok], q[ok]
    sg, sx = float(np.std(g)), float(np.std(x))
    if len(g) < 3 or sg == 0.0 or sx == 0.0:
        return False
    corr = float(np.mean((g - g.mean()) * (x - x.mean())) / (sg * sx))
    return corr > 0.8 and 0.5 < sg / sx < 2.0 and abs(g.mean() - x.mean()) < sx


def estimate_velocity(time: np.ndarray, qpos: np.ndarray, window: float = 0.02,
                      goal: np.ndarray | None = None) -> np.ndarray:
    """Velocity [rad/s] by a local linear fit over +-``window`` s (robust to quantization).

    At the start of a log the window is one-sided, and a line through it reads the response to
    the first goals as the velocity at the first sample: a joint at rest when its log started,
    stepping 0.3 rad toward its first goal (50 mrad in the next 10 ms sample), was given
    2.5 rad/s, and the replay of that episode started moving (held-out RMSE 2.0-2.6 mrad where
    the true model gives the 1.0 mrad read noise; a 3-point quadratic gave -2.2 rad/s: the step
    is faster than the samples). With ``goal`` (T, nu; goal k acts from row k to row k+1),
    the samples near the start use only rows under the command that acts at that sample: the
    velocity comes from the motion that command left, not from the next one's response.
    A step written at row 0 itself cannot be told from motion before the log: without a
    measured velocity the first sample then reads the step's mean speed over the first row.
    A joint whose quantised reading moves by exactly one encoder step over those rows keeps the
    line through the whole window (the rows under one command cannot tell a flicker from slow
    motion): where the goal changes every row (a host PD's torques at 333 Hz), the rows under
    one command are two, and a read flickering by one 4096-tick step gave +-0.51 rad/s; an
    Allegro-like finger's open-loop torque replay from that state drifted 39 mrad RMS on its
    light distal joint (gap_truth_sim6's clean_torque_333hz, held-out 11.8 mrad, 27x the noise
    floor, on a clean case).

    The window is at least 1.75 median row periods (a 100 Hz log keeps +-20 ms): at 50 Hz (rows
    20 ms +-20 % apart) a +-20 ms window often held the row alone, and the velocity was set to 0
    there; episodes of a 2-link arm then started from rest while moving at 0.7 rad/s (redteam's
    clean arm, position-only at 50 Hz: nominal replay 67.7 mrad off, 4.9 with the neighbours).

    Args:
      time: (T,) [s]; qpos: (T, n) [rad]; goal: (T, nu) goals [rad] or None.
    Returns:
      (T, n) velocity estimates.
    """
    if len(time) > 1:
        window = max(window, 1.75 * float(np.median(np.diff(np.asarray(time, float)))))
    v = _linear_slope(time, qpos, window)
    if goal is None or len(time) < 2:
        return v
    plain = v.copy()
    t = np.asarray(time, float)
    q = np.asarray(qpos, float)
    g = np.asarray(goal, float)
    step = quantization_step(q)
    for i in np.flatnonzero(t - t[0] < window):
        cmd = g[max(i - 1, 0)]  # acting at row i (row 0: the first goal, acting right after it)
        lo = hi = i  # rows lo..hi: every interval between them under ``cmd`` (k -> k+1: goal k)
        while lo > 0 and t[i] - t[lo - 1] <= window and np.array_equal(g[lo - 1], cmd):
            lo -= 1
        while hi + 1 < len(t) and t[hi + 1] - t[i] <= window and np.array_equal(g[hi], cmd):
            hi += 1
        if hi > lo:
            tt, qq = t[lo:hi + 1], q[lo:hi + 1]
            dt = tt - tt.mean()
            v[i] = (dt @ (qq - qq.mean(axis=0))) / (dt @ dt)
            # one encoder step under the command: a flicker or slow motion, the rows under
            # it cannot tell; the line through the whole window reads it
            moved = np.abs(qq[-1] - qq[0])
            flick = (moved > 0) & (moved <= 1.01 * step)
            v[i, flick] = plain[i, flick]
    return v


def rest_at_start(time: np.ndarray, qpos: np.ndarray, step: np.ndarray) -> np.ndarray:
    """(n,) joints to take at rest at a log's first row when the log has no velocity.

    A log that opens with a goal step (the first goal, written right after the first read, far
    from the first reading) shows in its first rows the response to that step, not the motion
    before the log: the line fit of ``estimate_velocity`` then starts the replay already moving
    at the step's mean speed over the first row. A LEAP-like finger logged at 50 Hz from rest
    got -0.6 to 2.4 rad/s at its first rows; the true model's open-loop replay was 5-12 mrad
    off over the first 0.4 s and 1.36 mrad over whole logs, 0.81 from rest (reading floor
    0.67). A joint is taken at rest when its first row moves toward the first goal without
    reaching it and the motion is not steady (the second row's speed differs from the first's
    by more than 10 % and the readings' resolution): a joint already moving at constant speed
    when its log began keeps its line fit (the data cannot tell the rest).

    Args:
      time: (T,) [s]; qpos: (T, n) [rad]; step: (n,) first goal minus first reading per joint,
        in joint units [rad] (NaN: no position goal on that joint).
    """
    t = np.asarray(time, float)
    q = np.asarray(qpos, float)
    step = np.asarray(step, float)
    out = np.zeros(q.shape[1], bool)
    if len(t) < 3 or not (t[1] > t[0] and t[2] > t[1]):
        return out
    dq = np.abs(np.diff(q, axis=0))
    res = np.array([min(float(np.min(c[c > 0], initial=np.inf)), 2 * np.pi / 4096)
                    for c in dq.T])  # a reading's resolution: its smallest step, <= a tick
    h01, h12 = t[1] - t[0], t[2] - t[1]
    v01, v12 = (q[1] - q[0]) / h01, (q[2] - q[1]) / h12
    steady = np.abs(v12 - v01) <= 0.1 * np.abs(v01) + res * (1 / h01 + 1 / h12)
    with np.errstate(invalid="ignore"):
        toward = (v01 * step > 0) & (np.abs(step) > np.abs(q[1] - q[0]))
    return toward & ~steady


def _linear_slope(time: np.ndarray, qpos: np.ndarray, window: float) -> np.ndarray:
    """Slope of a least-squares line through the samples within +-``window`` of each one.

    Times are taken from the log's first stamp: the running sums below square them, and on
    ``time.time()`` stamps (1.7e9 s) t * t (3e18) keeps no digit of a 20 ms window's spread
    (n sum t^2 - (sum t)^2 was rounding noise: every slope came out ~0, so a LEAP-like finger
    logged at 50 Hz on epoch stamps got qvel 0 on every row, moving or not). From the first
    stamp the relative error is about 12 eps (L / window)^2 for a log L s long: 1e-5 for an
    hour at +-40 ms.
    """
    t = np.asarray(time, float)
    if len(t):
        t = t - t[0]
    q = np.asarray(qpos, float)
    lo = np.searchsorted(t, t - window, side="left")
    hi = np.searchsorted(t, t + window, side="right")
    cs_t = np.concatenate([[0.0], np.cumsum(t)])
    cs_tt = np.concatenate([[0.0], np.cumsum(t * t)])
    cs_q = np.vstack([np.zeros((1, q.shape[1])), np.cumsum(q, axis=0)])
    cs_tq = np.vstack([np.zeros((1, q.shape[1])), np.cumsum(t[:, None] * q, axis=0)])
    n = (hi - lo).astype(float)
    st, stt = cs_t[hi] - cs_t[lo], cs_tt[hi] - cs_tt[lo]
    sq, stq = cs_q[hi] - cs_q[lo], cs_tq[hi] - cs_tq[lo]
    den = n * stt - st * st
    with np.errstate(divide="ignore", invalid="ignore"):
        v = (n[:, None] * stq - st[:, None] * sq) / den[:, None]
    return np.where(np.isfinite(v) & (n[:, None] >= 2), v, 0.0)


