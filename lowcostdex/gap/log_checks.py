"""Checks on entry for measured logs: the limits a log must meet (``MIN_SAMPLES``, plausible
magnitudes per column kind, ...), building a validated ``Trajectory`` from log-format columns
(``trajectory_from_columns``) and the signal checks (frozen, saturated, wrapped, pinned or dead
channels) that name the file, the column and the problem.

Why one module: the repairs and checks run once, in order, on the columns as they enter, and
share the limits at the top; split, those limits and the order would live in two places.
"""

from __future__ import annotations

import math

import numpy as np

from lowcostdex.gap.log_still import (  # noqa: F401 (the limits are read from here too)
    PINNED_RUN,
    PINNED_SPEED,
    PINNED_TRAVEL,
    check_pinned,
    check_stuck,
)
from lowcostdex.gap.log_units import (
    TO_RAD,
    check_degree_grid,
    check_sustained_speed,
    check_velocity_unit,
)
from lowcostdex.gap.trajectory import (
    GAP_FACTOR,
    LogError,
    Trajectory,
    find_gaps,
)

PREFIXES_ACTUATOR = ("goal", "current", "voltage", "temperature", "torque_enable")
PREFIXES_JOINT = ("qpos", "qvel")
CHANNELS = ("current", "voltage", "temperature", "torque_enable")
MIN_SAMPLES = 20
MIN_DURATION = 0.5  # [s]
MAX_SAMPLES = 2_000_000  # per log: bounds memory and run time (about 1 h at 500 Hz)
MAX_DURATION = 3600.0  # [s] per log
MAX_JSON_BYTES = 256 * 2**20  # a BAM log of 6 s is about 250 kB
STEP_RANGE = (5e-5, 0.5)  # [s] plausible median sample step (20 kHz .. 2 Hz)
MIN_MOTION = 0.02  # [rad] some measured joint must move at least this much (peak to peak)
FROZEN_CROSS = 0.2  # [rad] a reading that repeats while the goal passes it by this, both ways
RANGE_MARGIN = 0.2  # [rad] measured positions beyond a limited joint's model range by more
CLIP_PILE = 5.0  # ... and this many times as often as at any value between the extremes
SATURATED_SHARE = 0.2  # a channel at exactly its extreme value in this share of the samples
WRAP_TOLERANCE = 0.25  # [rad] a one-sample jump this close to one turn (2 pi) is a register wrap
MIN_SUPPLY = 3.0  # [V] below every servo's operating range (XL330 3.7 V, SG90 4.8 V)
# plausible magnitudes per column kind (SI units); beyond them the unit is wrong or the data broken
PLAUSIBLE: dict[str, tuple[float, float, str]] = {
    "goal": (-4 * math.pi, 4 * math.pi, "rad"),
    "qpos": (-4 * math.pi, 4 * math.pi, "rad"),
    "qvel": (-100.0, 100.0, "rad/s"),
    "current": (-30.0, 30.0, "A"),
    "voltage": (0.0, 60.0, "V"),
    "temperature": (-40.0, 150.0, "deg C"),
    "torque_enable": (0.0, 1.0, "0/1"),
}
_UNIT_HINTS: dict[str, tuple[tuple[float, str], ...]] = {
    # (largest |value| that fits the other unit, hint)
    "goal": ((400.0, "degrees? write rad"), (65536.0, "raw encoder ticks? write rad")),
    "qpos": ((400.0, "degrees? write rad"), (65536.0, "raw encoder ticks? write rad")),
    "qvel": ((6000.0, "deg/s or rpm? write rad/s"),),
    "current": ((30000.0, "mA? write A"),),
    "voltage": ((600.0, "0.1 V register units? write V"), (60000.0, "mV? write V")),
    "temperature": ((430.0, "kelvin? write deg C"),),
}


def trajectory_from_columns(cols: dict[str, np.ndarray], name: str = "log",
                            rate_goals: frozenset[str] | set[str] = frozenset(),
                            gears: dict[str, float] | None = None) -> Trajectory:
    """Parse log-format columns; raises LogError naming bad columns, NaNs or too little data.
    ``rate_goals``: actuators whose goal is a velocity (an integrating servo's input, rad/s;
    the goal-against-reading checks skip them); ``gears``: actuator -> its gear (the goal is
    in actuator units, gear x the joint angle; default 1)."""
    cols = _normalized_names(cols, name)
    if "time" not in cols:
        raise LogError(f"{name}: missing column 'time' [s]; its columns: "
                       f"{_listed(cols)}; name the time stamps' column 'time' (in seconds)")
    cols, dropped = _without_row_index(cols, name)
    cols, notes, cuts = _repair_rows(cols, name)
    notes = dropped + notes
    acts: dict[str, dict[str, np.ndarray]] = {}
    joints: dict[str, dict[str, np.ndarray]] = {}
    for key, arr in cols.items():
        if key in ("time", "goal_time"):
            continue
        prefix, sep, target = key.partition(":")
        if not sep or not target:
            raise LogError(f"{name}: column {key!r} is not '<kind>:<name>'; kinds: time, "
                           + ", ".join(PREFIXES_ACTUATOR + PREFIXES_JOINT)
                           + "; remove the column or rename it")
        if prefix in PREFIXES_ACTUATOR:
            acts.setdefault(target, {})[prefix] = arr
        elif prefix in PREFIXES_JOINT:
            joints.setdefault(target, {})[prefix] = arr
        else:
            raise LogError(f"{name}: column {key!r} has unknown kind {prefix!r}; valid kinds: "
                           + ", ".join(PREFIXES_ACTUATOR + PREFIXES_JOINT))
    goal_acts = [a for a, d in acts.items() if "goal" in d]
    if not goal_acts:
        raise LogError(f"{name}: no 'goal:<actuator>' column (commanded position [rad])")
    for a, d in acts.items():
        if "goal" not in d:
            raise LogError(f"{name}: channels {sorted(d)} for actuator {a!r} but no 'goal:{a}'")
    meas = [j for j, d in joints.items() if "qpos" in d]
    if not meas:
        raise LogError(f"{name}: no 'qpos:<joint>' column (measured position [rad])")
    for j, d in joints.items():
        if "qpos" not in d:
            raise LogError(f"{name}: 'qvel:{j}' without 'qpos:{j}' (positions logged for: "
                           f"{', '.join(meas)}); name a joint's 'qpos:' and 'qvel:' columns "
                           "after the same joint of the model")
    for key, arr in cols.items():
        bad = ~np.isfinite(arr)
        if bad.any():
            raise LogError(f"{name}: column {key!r} has {int(bad.sum())} NaN/inf values "
                           f"(first at row {int(np.argmax(bad))}): {arr[np.argmax(bad)]:g}, an "
                           "overflow or a failed read logged as inf? leave its cell empty (a "
                           "row with an empty position or goal is dropped and said) or remove "
                           "the row")
    t = np.asarray(cols["time"], dtype=float)
    _check_time(t, name)
    for key, arr in cols.items():
        _check_range(key, arr, name)
    _check_minutes(t, {j: d["qpos"] for j, d in joints.items()},
                   {j: d["qvel"] for j, d in joints.items() if "qvel" in d}, name)
    for j, d in joints.items():
        if "qvel" in d:
            check_velocity_unit(t, d["qpos"], d["qvel"], j, name)
        check_degree_grid(d["qpos"], j, name)
    _check_duration(t, name)
    goal_time = None
    if "goal_time" in cols:
        goal_time = np.asarray(cols["goal_time"], dtype=float)
        if np.any(goal_time < t) or np.any(np.diff(goal_time) <= 0):
            raise LogError(f"{name}: 'goal_time' must be >= 'time' row by row and strictly "
                           "increasing")
    has_qvel = all("qvel" in joints[j] for j in meas)
    channels = {}
    for ch in CHANNELS:
        present = [a for a in goal_acts if ch in acts[a]]
        if present and len(present) != len(goal_acts):
            missing = sorted(set(goal_acts) - set(present))
            raise LogError(f"{name}: channel {ch!r} is missing for actuators {missing}")
        if present:
            channels[ch] = np.stack([acts[a][ch] for a in goal_acts], axis=1)
    traj = Trajectory(
        name=name, time=t,
        goal=np.stack([acts[a]["goal"] for a in goal_acts], axis=1),
        qpos=np.stack([joints[j]["qpos"] for j in meas], axis=1),
        actuators=tuple(goal_acts), joints=tuple(meas),
        qvel=np.stack([joints[j]["qvel"] for j in meas], axis=1) if has_qvel else None,
        channels=channels, goal_time=goal_time,
        meta={"notes": notes, "cuts": cuts} if notes else {})
    check_signals(traj, rate_goals, gears)
    return traj


def _without_row_index(cols: dict[str, np.ndarray], name: str
                       ) -> tuple[dict[str, np.ndarray], list[str]]:
    """Columns without a row index: a column that is not '<kind>:<name>' and numbers the rows
    0..n-1 or 1..n (pandas' ``to_csv`` writes one, named '' or 'Unnamed: 0'; 'index', 'sample')
    carries no data; it is left out and said."""
    out, notes = {}, []
    for key, arr in cols.items():
        n = len(arr)
        kind = key.partition(":")[0]
        if key not in ("time", "goal_time") and kind not in PREFIXES_ACTUATOR + PREFIXES_JOINT \
                and n:
            a = np.sort(np.asarray(arr, dtype=float))
            if np.array_equal(a, np.arange(n)) or np.array_equal(a, np.arange(1, n + 1)):
                notes.append(f"{name}: column {key!r} numbers the rows (a row index); left out")
                continue
        out[key] = arr
    return out, notes


def _listed(cols: dict, n: int = 6) -> str:
    names = list(cols)  # an empty NPZ has none (it read "its columns: ;")
    more = f" and {len(names) - n} more" if len(names) > n else ""
    return ", ".join(repr(k) for k in names[:n]) + more if names else "none (an empty NPZ?)"


def _normalized_names(cols: dict[str, np.ndarray], name: str) -> dict[str, np.ndarray]:
    """Column names as the format spells them: the kind (and 'time') in lower case, no spaces
    around ':' ('Time', 'QPOS : arm' -> 'time', 'qpos:arm'); the joint or actuator name after
    the ':' is kept as written (MJCF names are case-sensitive). Two columns that become one name
    are refused."""
    kinds = PREFIXES_ACTUATOR + PREFIXES_JOINT
    out: dict[str, np.ndarray] = {}
    for key, arr in cols.items():
        kind, sep, target = (part.strip() for part in str(key).partition(":"))
        if sep and kind.lower() in kinds:
            new = f"{kind.lower()}:{target}"
        elif not sep and kind.lower() in ("time", "goal_time"):
            new = kind.lower()
        else:
            new = str(key).strip()
        if new in out:
            raise LogError(f"{name}: columns {new!r} and {key!r} name the same thing")
        out[new] = arr
    return out


MAX_NAN_SHARE = 0.2  # a column empty/NaN in more of the rows is a channel that was not logged
SPARE_CHANNELS = ("current",)  # only checked, never replayed: left out whole, not its rows
# read beside the position but not needed to replay a row: a failed read of one of them keeps
# its row; short gaps are interpolated, a longer one costs the channel (qvel: then estimated
# from the positions, as for a log without velocities)
FILLED_CHANNELS = ("qvel", "voltage", "temperature")
MAX_FILL_RUN = 3  # rows: the longest gap of a FILLED channel interpolated between its readings


def _repair_rows(cols: dict[str, np.ndarray], name: str
                 ) -> tuple[dict[str, np.ndarray], list[str], list[int]]:
    """The repairs that are unambiguous, each said in a note: rows with an empty or NaN value
    (a failed read) are dropped - where the goal may have changed across the dropped rows, the
    log is cut there (``cuts``: rows a new piece starts at, see ``logs.split_at_gaps``) so no
    replay assumes a command it does not know - unless only optional readings are missing: a
    row that lacks only ``SPARE_CHANNELS`` (current) or ``FILLED_CHANNELS`` (qvel, voltage,
    temperature) values is kept (``_fill_gaps``); rows repeated exactly (same time, same values)
    are dropped; rows a few samples out of time order (a logger's threads or buffers) are
    sorted. A time stamp repeated with other values, or time going back further than a
    ``GAP_FACTOR`` x the median step (two logs in one file?), is left to ``_check_time`` to
    refuse. Infinite values are not missing values; they stay (and are refused)."""
    n = len(cols["time"])
    keys = list(cols)
    if n == 0:
        return cols, [], []
    data = np.stack([np.asarray(cols[k], dtype=float) for k in keys], axis=1)
    nan = np.isnan(data)
    notes: list[str] = []
    for c in np.flatnonzero(nan.mean(axis=0) > MAX_NAN_SHARE):
        raise LogError(f"{name}: column {keys[c]!r} is empty or NaN in {int(nan[:, c].sum())} "
                       f"of {n} rows (first at row {int(np.argmax(nan[:, c]))}, 0-based); leave "
                       "the column out if that channel was not logged")
    spare = [c for c, k in enumerate(keys) if k.split(":")[0] in SPARE_CHANNELS]
    core = [c for c, k in enumerate(keys) if k.split(":")[0] not in SPARE_CHANNELS
            + FILLED_CHANNELS]
    saved = nan[:, spare].any(axis=1) & ~nan[:, core].any(axis=1)  # rows only optionals lack
    if saved.any():
        kinds = sorted({keys[c].split(":")[0] for c in spare if nan[saved, c].any()})
        gone = [k for k in keys if k.split(":")[0] in kinds]
        notes.append(f"{name}: {int(saved.sum())} row(s) lack only {', '.join(map(repr, gone))} "
                     f"(first: row {int(np.argmax(saved))}, 0-based): the {'/'.join(kinds)} "
                     "channel is left out and the rows kept (it is only checked, never replayed)")
        keep = [i for i, k in enumerate(keys) if k not in gone]
        keys, data, nan = [keys[i] for i in keep], data[:, keep], nan[:, keep]  # fmt: skip
    cut = np.zeros(n, dtype=bool)
    row = np.arange(n)  # each kept row's number in the file (0-based), for the notes
    optional = np.array([k.split(":")[0] in FILLED_CHANNELS for k in keys], bool)
    bad = nan[:, ~optional].any(axis=1)  # a failed position (or goal, time) read
    if bad.any():
        goals = [i for i, k in enumerate(keys) if k.startswith("goal:")]
        edges = np.flatnonzero(np.diff(np.concatenate([[0], bad.astype(int), [0]])))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            if a == 0 or b == n:
                continue  # at an end: nothing to bridge
            before, run = data[a - 1, goals], data[a:b][:, goals]
            known = ~np.isnan(run)
            held = np.array_equal(run[known], np.broadcast_to(before, run.shape)[known]) and (
                known.all() or np.array_equal(data[b, goals], before))
            cut[b] = not held
        first = int(np.argmax(bad))
        col = keys[int(np.argmax(nan[first]))]
        said = (f"{name}: {int(bad.sum())} row(s) with an empty or NaN value dropped (first: row "
                f"{first}, 0-based, column {col!r}; rows are counted without them from here on)")
        notes.append(said)
        data, cut, row = data[~bad], cut[~bad], row[~bad]
    t = data[:, keys.index("time")]
    dt = np.diff(t)
    if len(dt) and np.any(dt <= 0):
        same = np.concatenate([[False], (dt == 0) & np.all(data[1:] == data[:-1], axis=1)])
        if same.any():
            notes.append(f"{name}: {int(same.sum())} repeated row(s) dropped (same time and "
                         f"values as the row before; first: row {int(np.argmax(same))})")
            data, cut, row = data[~same], cut[~same], row[~same]
            t = data[:, keys.index("time")]
            dt = np.diff(t)
        back = np.maximum.accumulate(t)[:-1] - t[1:]
        step = np.diff(np.sort(t))
        step = float(np.median(step[step > 0])) if np.any(step > 0) else 0.0
        if np.any(back > 0) and back.max() <= GAP_FACTOR * step:
            order = np.argsort(t, kind="stable")
            if np.all(np.diff(t[order]) > 0):
                notes.append(f"{name}: {int(np.sum(order != np.arange(len(t))))} row(s) out of "
                             f"time order (at most {back.max():.3g} s back) sorted by time")
                data, cut, row = data[order], cut[order], row[order]
    keys, data = _fill_gaps(keys, data, row, name, notes)
    out = {k: data[:, i] for i, k in enumerate(keys)}
    return out, notes, [int(i) for i in np.flatnonzero(cut)]


def _fill_gaps(keys: list[str], data: np.ndarray, row: np.ndarray, name: str,
               notes: list[str]) -> tuple[list[str], np.ndarray]:
    """Readings of ``FILLED_CHANNELS`` missing in rows whose position was read: gaps of at most
    ``MAX_FILL_RUN`` rows are interpolated linearly in time between the readings either side
    (held at a log's ends); a channel with a longer gap is left out whole (every joint's or
    actuator's column of it: the Trajectory holds a channel for all of them or none). Each
    repair is said in ``notes``; ``row``: the file's row number of each row of ``data``."""
    t = data[:, keys.index("time")]
    gone: list[str] = []
    for kind in FILLED_CHANNELS:
        cols = [c for c, k in enumerate(keys) if k.split(":")[0] == kind]
        missing = np.isnan(data[:, cols]) if cols else np.zeros((len(t), 0), bool)
        if not missing.any():
            continue
        rows = missing.any(axis=1)
        first = f"first: row {int(row[np.argmax(rows)])}, 0-based"
        longest = max(_longest_run(missing[:, i]) for i in range(len(cols)))
        if longest > MAX_FILL_RUN:
            why = ("its velocities are estimated from the positions, as for a log without "
                   "them" if kind == "qvel" else "effects that need it cannot be fitted")
            notes.append(f"{name}: {kind} readings are missing in {int(rows.sum())} row(s) "
                         f"({first}), {longest} rows in a row at most: the {kind} channel is "
                         f"left out and the rows kept ({why})")
            gone += [keys[c] for c in cols]
            continue
        for i, c in enumerate(cols):
            m = missing[:, i]
            if m.any():
                data[m, c] = np.interp(t[m], t[~m], data[~m, c])
        which = ", ".join(keys[c] for i, c in enumerate(cols) if missing[:, i].any())
        notes.append(f"{name}: {int(missing.sum())} {kind} reading(s) missing in "
                     f"{int(rows.sum())} row(s) ({first}; {which}): interpolated between the "
                     "readings either side, the rows kept")
    keep = [i for i, k in enumerate(keys) if k not in gone]
    return [keys[i] for i in keep], data[:, keep]


def _longest_run(mask: np.ndarray) -> int:
    """The longest run of True in ``mask`` (0 if none)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    return int(np.max(edges[1::2] - edges[::2])) if len(edges) else 0


def _check_time(t: np.ndarray, name: str) -> None:
    """Enough samples, strictly increasing, in seconds (unit told from the median step).

    Gaps are not refused here: ``split_at_gaps`` cuts the log there. The duration is checked by
    ``_check_duration`` (after ``_check_minutes``, which names a log in minutes).
    """
    if len(t) < MIN_SAMPLES:
        raise LogError(f"{name}: too little data: {len(t)} samples; need at least "
                       f"{MIN_SAMPLES} samples and {MIN_DURATION} s")
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        # wall-clock stamps (time.time(): 1.7e9 s) print alike at 9 digits: say them from the
        # log's first stamp
        at = (lambda x: f"{x - t[0]:+.6g} s from the first row") if abs(t[0]) >= 1e4 else (
            lambda x: f"{x:.9g}")
        what = "repeats" if dt[i] == 0 else f"goes back from {at(t[i])}"
        repeats = int(np.sum(dt == 0))
        why = ("duplicate or unsorted rows?" if repeats < 10 else
               f"{repeats} time stamps repeat with other values: rounded too coarsely?")
        if len(dt) > 1 and np.all(dt < 0):
            why = "the rows are in reverse time order: sort them by time"
        if dt[i] < 0 and t[i] - t[i + 1] > 1.0:
            why = "two logs in one file, or shuffled rows? sort the rows or cut the file in two"
        raise LogError(f"{name}: column 'time' must be strictly increasing: row {i + 1} "
                       f"(0-based) {what} to {at(t[i + 1])} ({why})")
    step = float(np.median(dt))
    if not STEP_RANGE[0] <= step <= STEP_RANGE[1]:
        raise LogError(f"{name}: column 'time' must be in seconds, but its median step is "
                       f"{step:.6g}{_time_unit_hint(step)}")


def _check_minutes(t: np.ndarray, qpos: dict[str, np.ndarray], qvel: dict[str, np.ndarray],
                   name: str) -> None:
    """Refuse time stamps in minutes, named as such. A log in minutes has a plausible median step
    (100 Hz: 1.7e-4 "s"), so the step alone cannot tell; the motion can: read as seconds, the
    positions change 60 x faster than the joint moves - faster than any servo (the 99th
    percentile of |dq/dt| above the plausible qvel, and plausible once divided by 60), or, when
    velocities are logged, dq/dt is 30-120 x the logged qvel (rad/s).
    """
    dt = np.diff(t)
    step = float(np.median(dt))
    if not STEP_RANGE[0] <= 60 * step <= STEP_RANGE[1]:
        return
    vmax = PLAUSIBLE["qvel"][1]
    evidence = ""
    for joint, q in qpos.items():
        rate = np.abs(np.diff(q)) / dt
        fast = float(np.percentile(rate, 99))
        v = qvel.get(joint)
        if fast > vmax and fast / 60 <= vmax:
            evidence = (f"read as seconds, 'qpos:{joint}' would move at {fast:.4g} rad/s (99th "
                        f"percentile; servos stay below {vmax:g}), in minutes at {fast / 60:.3g}")
        elif v is not None and np.median(np.abs(v)) > 0:
            moving = np.abs(v[1:]) > 0.1 * float(np.percentile(np.abs(v), 90))
            if moving.sum() >= MIN_SAMPLES:
                ratio = float(np.median(rate[moving]) / np.median(np.abs(v[1:][moving])))
                if 30 <= ratio <= 120:
                    evidence = (f"read as seconds, 'qpos:{joint}' changes {ratio:.3g} x faster "
                                f"than its logged velocity 'qvel:{joint}'")
        if evidence:
            break
    if evidence:
        raise LogError(f"{name}: column 'time' looks like minutes, not seconds: {evidence}; "
                       f"{len(t)} samples over {float(t[-1] - t[0]) * 60:.4g} s at "
                       f"{1 / (60 * step):.4g} Hz if so: multiply the time stamps by 60")


def _check_duration(t: np.ndarray, name: str) -> None:
    """At least MIN_DURATION, at most MAX_DURATION seconds."""
    step = float(np.median(np.diff(t)))
    dur = float(t[-1] - t[0])
    if dur < MIN_DURATION:
        hint = (f" ({1 / step:.4g} Hz: is 'time' in seconds?)" if len(t) >= 10 * MIN_SAMPLES
                else "")
        raise LogError(f"{name}: too little data: {len(t)} samples over {dur:.3g} s{hint}; need "
                       f"at least {MIN_SAMPLES} samples and {MIN_DURATION} s")
    if dur > MAX_DURATION:
        raise LogError(f"{name}: column 'time' spans {dur:.6g} s; at most {MAX_DURATION:g} s "
                       "per log (split the log into shorter ones)")


def _time_unit_hint(step: float) -> str:
    for factor, unit in ((1e3, "ms"), (1e6, "us"), (1e9, "ns")):
        if STEP_RANGE[0] <= step / factor <= STEP_RANGE[1]:
            return (f": {unit}? ({1 / (step / factor):.4g} Hz if so); divide the time stamps by "
                    f"{factor:.0e}")
    return (f" s (a {1 / step:.4g} Hz log); a servo log has steps of "
            f"{STEP_RANGE[0]:g}-{STEP_RANGE[1]:g} s")


def _check_range(key: str, arr: np.ndarray, name: str) -> None:
    """Values of a column within the plausible magnitudes of its kind (wrong units, broken data)."""
    kind = key.partition(":")[0]
    if kind not in PLAUSIBLE:
        return
    lo, hi, unit = PLAUSIBLE[kind]
    if kind == "torque_enable":
        bad = (arr != 0) & (arr != 1)
    else:
        bad = (arr < lo) | (arr > hi)
    if not bad.any():
        return
    i = int(np.argmax(bad))
    if kind == "torque_enable":
        raise LogError(f"{name}: column {key!r} must be 0 or 1, row {i} (0-based) is {arr[i]:g}")
    worst = float(np.max(np.abs(arr)))
    hint = next((h for limit, h in _UNIT_HINTS.get(kind, ()) if worst <= limit),
                "broken data?")
    raise LogError(f"{name}: column {key!r} has {arr[i]:.6g} {unit} at row {i} (0-based); "
                   f"plausible: {lo:g} to {hi:g} {unit} ({hint})")


def check_signals(traj: Trajectory, rate_goals: frozenset[str] | set[str] = frozenset(),
                  gears: dict[str, float] | None = None) -> None:
    """Refuse what no model can be identified from, naming the column and the values.
    Actuators in ``rate_goals`` take a velocity goal (an ``intvelocity`` servo integrates it
    into its setpoint): the checks comparing a goal with its joint's reading skip them; a goal
    of an actuator with a gear (``gears``) is compared as goal / gear.

    * a frozen encoder: a joint's reading repeats exactly (torque on) while its goal passes it
      by more than FROZEN_CROSS on both sides (a servo that stalls under load, its goal on one
      side, is physics: BAM's XL330 holds one reading for 3 s while its goal moves 0.3 rad);
    * a saturated current: at exactly its largest or smallest (non-zero) value in at least
      SATURATED_SHARE of the torque-on samples and CLIP_PILE times as often as at any value
      between the extremes (a clipped sensor or register range; the
      current-dependent effects would fit the clip). Velocities may plateau (a profile velocity,
      the robot's motion bound), so they are not checked;
    * a position register's range: a reading that jumps by one turn (2 pi) between two samples
      (a register that wraps, e.g. 0..4095 ticks), or that is pinned at its largest (smallest)
      value for PINNED_RUN samples with torque on while the goal is beyond it by FROZEN_CROSS,
      where the motor is shown moving on (its logged qvel, at a median |qvel| of PINNED_SPEED,
      integrates to PINNED_TRAVEL beyond the reading while it stands still; real XL330 logs:
      8 mrad in 36 ms at a peak, the velocity filter's lag, and 78 mrad at one 0.024 rad/s count
      through a 3 s stall) or the value is an edge
      of the encoder's one-turn window (tick 0, N - 1, -N/2, N/2 - 1 of N per turn) - a joint
      held by a hard stop reads still, so without either sign a pinned reading is left alone;
    * a stuck read (``log_still.check_stuck``): a reading repeated exactly for PINNED_RUN
      samples while the joint's own logged qvel moves the motor PINNED_TRAVEL from it
      (a failed read logged as the last value);
    * a dead voltage or temperature channel: below MIN_SUPPLY volts (a servo cannot drive its
      joint on it) or exactly 0 deg C throughout, while the motor moves its joint with torque on:
      an unread register logged as 0, or a broken sensor (a steady reading is not one: supply and
      winding temperature are quantised, 0.1 V and 1 deg C, and sit still for minutes);
    * too little motion: no measured joint moves MIN_MOTION peak to peak;
    * positions that change faster than a servo moves (the 99th percentile of |dq/dt| beyond the
      plausible qvel, 100 rad/s): time not in seconds (minutes pass the step check as a 6 kHz
      log) or positions not in rad; without logged velocities the error names degrees too; and
      positions covering a whole turn in one stretch of steps above 50 rad/s
      (``log_units.check_sustained_speed``: a smooth degrees log under 100 deg/s at its 99th
      percentile). A smooth degrees log slower than 50 deg/s on a continuous joint moving less
      than 4 pi (12.6 deg) has no sign of its unit here. (The limit was 50 rad/s without velocities for
      half an hour, e1629d1: it refused tests/test_gap_offer.py's torque arm, a plain MuJoCo
      motor stepping 5 rad at 53 rad/s in 1 % of its rows, and an outside user's stiff arm
      would be refused alike; back at 100, 2026-11-29.)
    Measured logs (BAM's five rigs) repeat a reading for at most 0.32 s and by 0.05 rad of goal.
    """
    name = traj.name
    on = np.ones(len(traj), bool)
    if "torque_enable" in traj.channels:
        on = np.all(traj.channels["torque_enable"] > 0.5, axis=1)
    ids = {a: k for k, a in enumerate(traj.actuators)}
    gear = gears or {}
    for j, joint in enumerate(traj.joints):  # a clip or wrap first: they also look frozen
        _check_wrapped(traj, j)
        if joint in ids and joint not in rate_goals:
            check_pinned(traj, j, traj.goal[:, ids[joint]] / gear.get(joint, 1.0), on,
                         FROZEN_CROSS)
        check_stuck(traj, j)
    for j, joint in enumerate(traj.joints):
        if joint in ids and joint not in rate_goals:
            _check_goal_copied(traj, j, traj.goal[:, ids[joint]] / gear.get(joint, 1.0))
            _check_frozen(traj, j, gear.get(joint, 1.0))
    if "current" in traj.channels:
        for k, col in enumerate(traj.channels["current"].T):
            _check_saturated(name, f"current:{traj.actuators[k]}", col[on])
    for k in range(len(traj.actuators)):
        _check_dead_channels(traj, k, on)
    speed = np.abs(np.diff(traj.qpos, axis=0)) / np.diff(traj.time)[:, None]
    fast = np.percentile(speed, 99, axis=0)
    vmax = PLAUSIBLE["qvel"][1]
    if float(fast.max()) > vmax:
        j = int(np.argmax(fast))
        why = "" if traj.qvel is not None else (
            f" (degrees read as rad move 57 x as fast; if 'qpos' is in degrees, {TO_RAD})")
        raise LogError(f"{name}: column 'qpos:{traj.joints[j]}' moves at up to "
                       f"{fast[j]:.4g} rad/s (99th percentile of its steps); servos move below "
                       f"{vmax:g} rad/s: is 'time' in seconds (not minutes) and 'qpos' in rad?"
                       + why)
    check_sustained_speed(traj)
    motion = np.ptp(traj.qpos, axis=0)
    if float(motion.max()) < MIN_MOTION:
        moved = ", ".join(f"{j} {m:.3g}" for j, m in zip(traj.joints, motion, strict=True))
        raise LogError(f"{name}: too little motion to identify anything: peak-to-peak qpos "
                       f"[rad] {moved}; some joint must move at least {MIN_MOTION} rad")


COPIED_STEP = 0.006  # [rad] goal steps this large (4 ticks of a 4096-tick encoder) ...
COPIED_SHARE = 0.5  # ... met by the reading of the same row this often: the goal was logged


def _check_goal_copied(traj: Trajectory, j: int, goal: np.ndarray) -> None:
    """A position column that is the goal (a logger that read the Goal Position register, or
    wrote the goal into both columns): a row's reading is taken before that row's goal is sent,
    so no servo is already at a new goal when it is read. Refused when the reading sits within a
    tenth of the step at the row's new goal in COPIED_SHARE of the goal steps of at least
    COPIED_STEP (real BAM logs: at most 2.3 % of 560 steps)."""
    q = traj.qpos[:, j]
    dg = np.abs(np.diff(goal))
    k = np.flatnonzero(dg > COPIED_STEP) + 1
    if len(k) < MIN_SAMPLES:
        return
    at = np.abs(q[k] - goal[k]) < 0.1 * dg[k - 1]
    if at.mean() >= COPIED_SHARE:
        joint = traj.joints[j]
        raise LogError(f"{traj.name}: column 'qpos:{joint}' is at the row's new goal in "
                       f"{100 * at.mean():.0f} % of {len(k)} goal steps, before the goal was sent "
                       f"(its reading is taken first): the goal logged as the position (log "
                       f"the servo's Present Position), or each row's goal one row late (a row's "
                       f"goal is the one sent after its reading)?")


def frozen_crossing(traj: Trajectory, j: int, gear: float = 1.0) -> tuple[float, int, int]:
    """The frozen-encoder check's statistic for joint ``j`` (``traj.joints`` order; its actuator
    must be logged): over every stretch of at least 5 samples with torque on where the reading
    repeats exactly, how far the acting goal passes the reading on *both* sides, the smaller of
    the two [rad] (less the log's usual goal - reading offset), and the worst stretch's rows
    [a, b). ``check_signals`` refuses a log where it exceeds FROZEN_CROSS; -inf, 0, 0 without
    such a stretch."""
    t, q = traj.time, traj.qpos[:, j]
    goal = traj.goal[:, traj.actuators.index(traj.joints[j])] / gear
    on = np.ones(len(traj), bool)
    if "torque_enable" in traj.channels:
        on = np.all(traj.channels["torque_enable"] > 0.5, axis=1)
    moving = np.flatnonzero(np.diff(q) != 0)
    resumed = find_gaps(t) + 1  # first rows after a hole in the time stamps
    change = np.union1d(moving + 1, resumed)
    starts = np.concatenate([[0], change])
    stops = np.concatenate([change, [len(q)]])
    # goal and reading differ by a constant where the encoder's zero is off (a mounting offset
    # of a spline tooth, 0.25 rad): measure the crossing from the log's usual difference while
    # the reading moves (a dwell at a turning point is not a stuck read)
    live = moving[on[moving]]
    bias = float(np.median(goal[live] - q[live])) if len(live) else 0.0
    worst = (-math.inf, 0, 0)
    for a, b in zip(starts, stops, strict=True):
        if b - a < 5 or not on[a:b].all():
            continue
        # a row's goal is written after its read: row a - 1's acts at row a, unless a hole
        first = a if (a == 0 or a in resumed) else a - 1  # (its goal is from before the hole)
        err = goal[first:b - 1] - q[a] - bias
        crossing = min(float(err.max()), float(-err.min()))
        if crossing > worst[0]:
            worst = (crossing, int(a), int(b))
    return worst


def _check_frozen(traj: Trajectory, j: int, gear: float = 1.0) -> None:
    crossing, a, b = frozen_crossing(traj, j, gear)
    if crossing > FROZEN_CROSS:
        t, q, joint = traj.time, traj.qpos[:, j], traj.joints[j]
        resumed = a == 0 or a in find_gaps(t) + 1
        acting = traj.goal[a if resumed else a - 1:b - 1, traj.actuators.index(joint)]
        raise LogError(
            f"{traj.name}: column 'qpos:{joint}' is frozen at {q[a]:.6g} rad for "
            f"{t[b - 1] - t[a]:.3g} s (from {t[a]:.6g} s) while 'goal:{joint}' moves over "
            f"[{acting.min():.3g}, {acting.max():.3g}] rad with torque on: the encoder "
            "or its read is stuck (or the joint is blocked); nothing can be identified there")


def _check_saturated(name: str, key: str, col: np.ndarray) -> None:
    if len(col) < MIN_SAMPLES or len(np.unique(col)) < 10:
        return
    values, counts = np.unique(col, return_counts=True)
    for k, what in ((len(values) - 1, "largest"), (0, "smallest")):
        extreme = values[k]
        if extreme == 0:  # at rest, or a sign the register does not carry: not a clip
            continue
        share = counts[k] / len(col)
        # a clip piles the samples up at the edge: far more than at any other value (a small,
        # quantised signal such as a parked joint's current of a few counts does not)
        if share >= SATURATED_SHARE and counts[k] >= CLIP_PILE * counts[1:-1].max():
            raise LogError(f"{name}: column {key!r} sits at its {what} value {extreme:.6g} in "
                           f"{100 * share:.0f} % of the samples with torque on: a saturated "
                           "(clipped) reading; log a range that holds the signal")


def _check_wrapped(traj: Trajectory, j: int) -> None:
    q, t = traj.qpos[:, j], traj.time
    jump = np.diff(q)
    wrap = (np.abs(np.abs(jump) - 2 * math.pi) < WRAP_TOLERANCE) & (
        np.abs(jump) / np.diff(t) > PLAUSIBLE["qvel"][1])
    if wrap.any():
        i = int(np.argmax(wrap))
        raise LogError(f"{traj.name}: column 'qpos:{traj.joints[j]}' jumps by {jump[i]:+.4g} rad "
                       f"(one turn) from row {i} to {i + 1} (0-based, at {t[i + 1]:.6g} s), "
                       f"{int(wrap.sum())} time(s): a position register wrapping at its range; "
                       "unwrap the positions (numpy.unwrap) or log a multi-turn position")


def _check_dead_channels(traj: Trajectory, k: int, on: np.ndarray) -> None:
    """Voltage below MIN_SUPPLY, or temperature exactly 0 deg C throughout, while the joint of
    actuator ``k`` (if measured) moves with torque on."""
    actuator = traj.actuators[k]
    if not on.any():
        return
    if actuator in traj.joints:
        if np.ptp(traj.qpos[on, traj.joints.index(actuator)]) < MIN_MOTION:
            return
    if "voltage" in traj.channels:
        v = traj.channels["voltage"][on, k]
        low = v < MIN_SUPPLY
        if low.mean() >= SATURATED_SHARE:
            raise LogError(f"{traj.name}: column 'voltage:{actuator}' reads "
                           f"{np.median(v[low]):.3g} V in {100 * low.mean():.0f} % of the samples with torque on while the "
                           f"motor moves its joint; no servo runs below {MIN_SUPPLY:g} V: the "
                           "register is not read (0 logged for no data?) or the sensor is broken; "
                           "drop the column or log Present Input Voltage")
    if "temperature" in traj.channels:
        c = traj.channels["temperature"][on, k]
        if np.all(c == 0):
            raise LogError(f"{traj.name}: column 'temperature:{actuator}' reads exactly 0 deg C "
                           "all along while the motor moves its joint with torque on: the "
                           "register is not read (0 logged for no data?) or the sensor is "
                           "broken; drop the column or log Present Temperature")
