"""A gap-analysis data set: nominal models, measured trajectories, windows and splits.

A *window* is a stretch of one trajectory replayed from its measured state at the first sample.
*Episodes* are the units of held-out evaluation and of the bootstrap (a whole trajectory, or a
chunk of a long one), replayed open loop; fitting replays *segments* (shorter windows, multiple
shooting) so that all of them run in parallel in one batch and long-horizon drift cannot trap the
fit. Splits (train / select / test) are made over episodes, never over samples.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import mujoco
import numpy as np

from lowcostdex.errors import ConfigError, check_bool, check_number
from lowcostdex.gap.bam_logs import check_one_motor
from lowcostdex.gap.log_paths import (  # noqa: F401 (LOG_SUFFIXES re-exported)
    LOG_SUFFIXES,
    expand_log_paths,
    model_path,
    no_such_log,
)
from lowcostdex.gap.log_units import actuators_taking, speed_unchecked
from lowcostdex.gap.logs import (
    LogError,
    Trajectory,
    actuator_gears,
    check_against_model,
    estimate_velocity,
    is_bam,
    model_needed,
    rate_goal_actuators,
    read_bam,
    read_log,
    rest_at_start,
    split_at_gaps,
)
from lowcostdex.sim.effects import Targets
from lowcostdex.sim.effects.base import tendon_actuators
from lowcostdex.sim.models.bench import build_bench
from lowcostdex.sim.servo import MAX_SERVO_PERIOD

ANGLE_UNITS = {"rad": 1.0, "deg": np.pi / 180.0}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
"""Seconds per unit of a project-format log's 'time' (and 'goal_time') column: a logger's
``millis()``, ``micros()`` or ``time.monotonic_ns()`` stamps are read as they were written."""
"""Units ``load_dataset`` reads project-format logs' angles in: rad per unit."""

MAX_TOTAL_DURATION = 4 * 3600.0
"""Most seconds of logs one analysis takes (its run time grows with them)."""

@dataclass(frozen=True)
class Window:
    """Samples [start, stop) of trajectory ``traj``; residuals count from ``score_from``."""

    traj: int
    start: int
    stop: int
    score_from: int

    @property
    def n_scored(self) -> int:
        return self.stop - self.score_from


@dataclass
class Dataset:
    """Nominal models (MJCF strings by key) and the trajectories that replay on them.

    Attributes:
      models: {key: MJCF XML} of the nominal models.
      trajectories: measured trajectories; ``trajectory.model`` names its model.
      sources: input file of each trajectory.
      notes: what loading did to the logs that a user should know (e.g. a log split at a gap).
      servo_period: the servos' update period [s] replays use (``sim.servo.ServoClock``: the
        position law sampled and its force held between firmware cycles); 0: continuous.
    """

    models: dict[str, str]
    trajectories: list[Trajectory]
    sources: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    servo_period: float = 0.0

    def __post_init__(self) -> None:
        check_number("servo period [s]", self.servo_period, 0.0, MAX_SERVO_PERIOD)  # None, '2'
        if not self.trajectories:
            raise LogError("no trajectories given")
        for tr in self.trajectories:
            if tr.model not in self.models:
                raise ConfigError(f"trajectory {tr.name}: unknown model {tr.model!r}; "
                                  f"models: {sorted(self.models)}")
        self._compiled: dict[str, mujoco.MjModel] = {}
        _check_same_names(self.trajectories, self.compiled)  # else: the model's advice
        for tr in self.trajectories:                          # would fit one log's set only
            check_against_model(tr, self.compiled(tr.model))
            if tr.qvel is None:
                tr.qvel = estimate_velocity(tr.time, tr.qpos, goal=tr.goal)
                tr.qvel[0, rest_at_start(tr.time, tr.qpos,
                                         _first_step(tr, self.compiled(tr.model)))] = 0.0
        _check_same_names(self.trajectories)

    def compiled(self, key: str) -> mujoco.MjModel:
        """The nominal model ``key`` compiled (cached)."""
        if key not in self._compiled:
            self._compiled[key] = mujoco.MjSpec.from_string(self.models[key]).compile()
        return self._compiled[key]

    @property
    def joints(self) -> tuple[str, ...]:
        return self.trajectories[0].joints

    @property
    def effect_joints(self) -> tuple[str, ...]:
        """Measured joints driven by exactly one actuator, on the joint or (none there) on one
        tendon over it (a servo shared by the joints its cable crosses): where effects act."""
        m = self.compiled(self.trajectories[0].model)
        drive = {j: _drive(m, m.joint(j).id) for j in self.joints}
        out = [j for j in self.joints if drive[j][0] == 1 or (drive[j][0], len(drive[j][1])) == (0, 1)]
        if not out:
            how = "; ".join(f"{j!r} " + (f"through tendons {', '.join(via)}" if via else
                                        f"by {n or 'no'} joint actuator{'s' * (n != 1)}")
                            for j, (n, via) in drive.items())
            raise LogError(f"no measured joint is driven by exactly one actuator ({how}): effects act on joints with one servo of their own or on one tendon")
        return tuple(out)

    @property
    def actuators(self) -> tuple[str, ...]:
        return self.trajectories[0].actuators

    def channels(self) -> set[str]:
        """Channels present in every trajectory."""
        sets = [set(tr.channels) for tr in self.trajectories]
        return set.intersection(*sets)

    @property
    def timestep(self) -> float:
        return float(self.compiled(self.trajectories[0].model).opt.timestep)

    def duration(self) -> float:
        return float(sum(tr.duration for tr in self.trajectories))

    def with_timestep(self, factor: float) -> Dataset:
        """The same logs on models whose physics step is ``factor`` times theirs (the
        trajectories are shared, not copied)."""
        if not factor > 0:
            raise ConfigError(f"timestep factor must be > 0, got {factor}")
        models = {}
        for key, xml in self.models.items():
            spec = mujoco.MjSpec.from_string(xml)
            spec.option.timestep = float(self.compiled(key).opt.timestep) * factor
            models[key] = spec.to_xml()
        return Dataset(models, self.trajectories, list(self.sources), list(self.notes),
                       self.servo_period)


MAX_BENCH_TIMESTEP = 0.05
"""[s] Largest physics step ``load_dataset(timestep=...)`` takes (BAM's grid is 5 ms)."""


def _goals_not_positions(model: mujoco.MjModel) -> frozenset[str]:
    """Actuators whose log goal is not a position (an integrating servo's or a ``velocity``
    actuator's rate, a ``motor``'s torque): the goal-against-reading log checks skip them (a
    velocity-mode joint a latency holds reads one tick while its command jumps, gap-sim13)."""
    return rate_goal_actuators(model) | actuators_taking(model, ("velocity", "muscle", "force"))


def load_dataset(paths: str | Path | Sequence[str | Path], model: str | Path | None = None,
                 bench: bool | None = None, timestep: float | None = None,
                 servo_period: float = 0.0, angle_unit: str = "rad",
                 time_unit: str = "s") -> Dataset:
    """Read logs and their model(s).

    Args:
      paths: log files (CSV/NPZ in the project format, or BAM JSON); one path or a folder or a
        glob pattern (``"logs/*.csv"``) is taken too: a folder means every log in it.
      model: MJCF file for project-format logs (required for them).
      bench: True: the logs are BAM JSON mapped onto the bench; None: auto-detect.
      timestep: physics step for BAM benches [s] (default: the bench's).
      servo_period: the servos' firmware update period [s] (``Dataset.servo_period``; 0:
        the actuator law continuous).
      angle_unit: "rad" or "deg": the unit of project-format logs' goal and qpos columns (and
        of qvel per second); degrees are turned into rad on reading (hinge joints only).
      time_unit: "s", "ms", "us" or "ns": the unit of project-format logs' 'time' (and
        'goal_time') stamps (``TIME_UNITS``); integer stamps of a clock that did not start at 0
        are fine (the first row need not be 0).
    Logs whose time stamps jump (logging paused) are split there (``split_at_gaps``; said in
    ``Dataset.notes``); the total duration is bounded by ``MAX_TOTAL_DURATION``.

    Raises:
      LogError with the file and problem.
    """
    if angle_unit not in ANGLE_UNITS:
        raise ConfigError(f"angle unit {angle_unit!r}; valid: {', '.join(ANGLE_UNITS)}")
    if time_unit not in TIME_UNITS:
        raise ConfigError(f"time unit {time_unit!r}; valid: {', '.join(TIME_UNITS)}")
    paths = expand_log_paths(paths, once=True)
    for p in paths:
        if not p.exists():
            raise no_such_log(p)
    if timestep is not None:  # a physics step: 1 (meant as ms) would run a 1 s Euler step
        check_number("timestep [s]", timestep, 0, MAX_BENCH_TIMESTEP, low_open=True)
    if bench is not None:  # bench='no' read BAM logs
        check_bool("bench", bench)
    bam = [is_bam(p) for p in paths]
    if angle_unit != "rad" and any(bam):
        raise LogError("BAM raw logs are in rad by their format; --units deg is for "
                       "project-format logs (CSV/NPZ)")
    if time_unit != "s" and any(bam):
        raise LogError("BAM raw logs are in seconds by their format; --time-unit is for "
                       "project-format logs (CSV/NPZ)")
    if bench is None:
        bench = all(bam)
        if any(bam) and not all(bam):
            for p, b in zip(paths, bam, strict=True):  # a JSON that is no BAM log: say what
                if b:                                  # it holds (the project's columns?)
                    read_bam(p, timestep=timestep)
            raise LogError("mixing BAM JSON logs and project logs in one analysis is not "
                           "supported")
    models: dict[str, str] = {}
    trajs: list[Trajectory] = []
    if bench:
        for p, b in zip(paths, bam, strict=True):
            if not b:
                raise LogError(f"{p}: not a BAM raw-log JSON; --bench and gap identify take BAM "
                               "JSON logs (project-format CSV/NPZ logs: gap analyze --model)")
            tr, cfg = read_bam(p, timestep=timestep)
            if tr.model not in models:
                models[tr.model] = build_bench(cfg).to_xml()
            trajs.append(tr)
        check_one_motor(trajs)  # one servo model per analysis, as BAM fits one actuator
    else:
        if model is None:
            raise model_needed(paths[0])
        model = model_path(model)
        if model.is_dir():
            xmls = sorted(p.name for p in model.iterdir() if p.suffix.lower() == ".xml")
            inside = (f"; it holds {', '.join(xmls[:5])}: give the top one, e.g. --model "
                      f"{model / xmls[0]}" if xmls else "")
            raise LogError(f"{model}: a folder, not an MJCF model file (.xml){inside}")
        try:
            spec = mujoco.MjSpec.from_file(str(model))
            compiled = spec.compile()
        except Exception as exc:  # mujoco raises ValueError with the parser message
            hint = ("; give the rig's MJCF model (.xml; `lowcostdex model` writes the project's)"
                    if model.suffix.lower() not in (".xml", ".urdf", ".mjb") else "")
            raise LogError(f"{model}: cannot load the model: {exc}{hint}") from None
        _absolute_asset_dirs(spec, model)
        models["model"] = spec.to_xml()
        rate, gears = _goals_not_positions(compiled), actuator_gears(compiled)
        scale = ANGLE_UNITS[angle_unit]
        if scale != 1.0:
            slides = [compiled.joint(j).name for j in range(compiled.njnt)
                      if compiled.jnt_type[j] == mujoco.mjtJoint.mjJNT_SLIDE]
            if slides:
                raise LogError(f"--units deg: the model has slide joints ({', '.join(slides)}) "
                               "whose positions are lengths: log angles in rad instead")
        forces = actuators_taking(compiled, ("force", "muscle"))  # N m goals: not in degrees
        trajs = [read_log(p, rate, gears, scale, TIME_UNITS[time_unit], forces) for p in paths]
        trajs = [_in_order(tr, trajs[0]) for tr in trajs]
    total = sum(tr.duration for tr in trajs)
    if total > MAX_TOTAL_DURATION:
        raise LogError(f"{len(trajs)} logs of {total:.6g} s in all; one analysis takes at most "
                       f"{MAX_TOTAL_DURATION:g} s of logs (give fewer or shorter logs)")
    pieces, sources, notes = [], [], []
    for p, tr in zip(paths, trajs, strict=True):
        notes += tr.meta.get("notes", [])
        cut, said = split_at_gaps(tr)
        pieces += cut
        sources += [str(p)] * len(cut)
        notes += said
    ds = Dataset(models, pieces, sources, notes, servo_period)
    ds.notes += _unshared_joints(ds) + (speed_unchecked(ds.compiled(ds.trajectories[0].model),
                                                         trajs) if angle_unit == "rad" else [])
    return ds


def _check_same_names(trajs: Sequence[Trajectory], compiled=None) -> None:
    """One analysis takes logs of one set of joints and actuators (logs in another column order
    were put in the first's by ``_in_order``); logs of other sets are refused naming a log of
    each set (a log's pieces carry '#k' after its name) and the fix. With ``compiled`` (key ->
    model), only logs commanding different actuators that all exist in the model are refused
    here, before the model checks (whose advice, 'a model of the logged joints only', would fit
    one set and break the other); every other difference is left to those checks."""
    sets: dict[tuple, str] = {}
    for tr in trajs:
        sets.setdefault((tr.joints, tr.actuators), tr.name.split("#")[0])
    if len(sets) < 2:
        return
    if compiled is not None:
        m = compiled(trajs[0].model)
        names = {m.actuator(i).name for i in range(m.nu)}
        if len({a for _, a in sets}) < 2 or not all(set(a) <= names for _, a in sets):
            return
    said = "; ".join(f"{log} logs {', '.join(j)}" if j == a else
                     f"{log} measures {', '.join(j)} and commands {', '.join(a)}"
                     for (j, a), log in sets.items())
    raise LogError(f"the logs are of different joints: {said}; one analysis takes logs of the "
                   "same joints and actuators: analyse each set on its own (with a model of its "
                   "joints), or log every joint in every log")


def _in_order(tr: Trajectory, first: Trajectory) -> Trajectory:
    """``tr`` with its joint and actuator columns in ``first``'s order when it logs the same
    ones in another order (a user's logger writing its columns in dict or file order), else
    ``tr`` unchanged (logs of different joints are refused by ``Dataset``)."""
    if ((tr.joints, tr.actuators) == (first.joints, first.actuators)
            or sorted(tr.joints) != sorted(first.joints)
            or sorted(tr.actuators) != sorted(first.actuators)):
        return tr
    jo = [tr.joints.index(j) for j in first.joints]
    ao = [tr.actuators.index(a) for a in first.actuators]
    return replace(tr, joints=first.joints, actuators=first.actuators, qpos=tr.qpos[:, jo],
                   qvel=None if tr.qvel is None else tr.qvel[:, jo], goal=tr.goal[:, ao],
                   channels={k: v[:, ao] for k, v in tr.channels.items()})


def _first_step(tr: Trajectory, m: mujoco.MjModel) -> np.ndarray:
    """(nj,) the log's first goal minus its first reading per joint [rad] where a fixed-gain
    position servo (``position``, or ``general`` with bias 0/-kp) drives the joint and that
    goal acts from the first row; NaN elsewhere (a piece cut from inside a log, a goal that
    arrives later, another actuator kind)."""
    step = np.full(len(tr.joints), np.nan)
    if tr.meta.get("mid_log") or (tr.goal_time is not None and tr.goal_time[0] > tr.time[0]):
        return step
    for col, name in enumerate(tr.actuators):
        a = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
        kp = float(m.actuator_gainprm[a, 0]) if a >= 0 else 0.0
        if not (kp > 0 and m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
                and m.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
                and m.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_AFFINE
                and m.actuator_biasprm[a, 0] == 0 and m.actuator_biasprm[a, 1] == -kp
                and m.actuator_dyntype[a] == mujoco.mjtDyn.mjDYN_NONE
                and m.actuator_gear[a, 0] != 0):
            continue
        joint = m.joint(int(m.actuator_trnid[a, 0])).name
        if joint in tr.joints:
            j = tr.joints.index(joint)
            step[j] = tr.goal[0, col] / m.actuator_gear[a, 0] - tr.qpos[0, j]
    return step


def _absolute_asset_dirs(spec: mujoco.MjSpec, model: Path) -> None:
    """Mesh and texture folders as absolute paths: the model is kept as XML text and compiled
    again from it, where a relative ``meshdir="assets"`` (a user's model with its meshes beside
    it) would be looked up from the working directory ("Error opening file")."""
    base = model.resolve().parent
    for attr in ("meshdir", "texturedir"):
        d = getattr(spec, attr)
        if not os.path.isabs(d):
            setattr(spec, attr, str(base / d))
    for hf in getattr(spec, "hfields", ()):
        if hf.file and not os.path.isabs(hf.file):
            hf.file = str(base / hf.file)


def _drive(m: mujoco.MjModel, jid: int) -> tuple[int, list[str]]:
    """How joint ``jid`` is driven: (actuators on the joint itself, actuated tendons over it)."""
    n = int(np.sum((m.actuator_trntype == mujoco.mjtTrn.mjTRN_JOINT) & (m.actuator_trnid[:, 0] == jid)))
    return n, [m.tendon(int(m.actuator_trnid[a, 0])).name for a in tendon_actuators(m, jid)]


def _unshared_joints(ds: Dataset) -> list[str]:
    """Notes on measured joints that no candidate effect is placed on (two actuators, several
    tendons) and on joints driven through one tendon's servo (its effects are the actuator's)."""
    m = ds.compiled(ds.trajectories[0].model)
    notes = []
    for j in ds.joints:
        n, via = _drive(m, m.joint(j).id)
        if n == 0 and len(via) == 1:
            notes.append(f"joint {j!r} is driven through tendon {via[0]}: the servo's effects act on that actuator's own coordinate, the joint's on the joint")
        elif n > 1 or via:
            how = " and ".join([f"{n} actuators"] * (n > 1) + [f"tendons {', '.join(via)}"] * bool(via))
            notes.append(f"joint {j!r} is driven by {how}: it replays as modelled, but no candidate "
                         "effect is placed on it (effects act on joints with one actuator)")
    return notes


# ------------------------------------------------------------------------------------------------
# windows


def quiet_start(tr: Trajectory, lo: int, hi: int, settle: float = 0.1) -> int:
    """The sample in [lo, hi) where a replay is best started: the joints slowest and no goal
    change within the preceding ``settle`` seconds (a clean measured initial state; a moving,
    saturated servo would carry any initial-state error through the whole move)."""
    lo, hi = max(lo, 0), min(hi, len(tr))
    if hi - lo <= 1:
        return lo
    v = np.abs(tr.qvel[lo:hi]).sum(axis=1) if tr.qvel is not None else np.zeros(hi - lo)
    changed = np.concatenate([[0], np.any(np.diff(tr.goal, axis=0) != 0, axis=1)]).astype(int)
    csum = np.cumsum(changed)
    back = np.searchsorted(tr.time, tr.time[lo:hi] - settle)
    recent = (csum[lo:hi] - csum[back]) > 0
    score = v + np.where(recent, 10.0 + v.max(), 0.0)
    return lo + int(np.argmin(score))


def _cuts(tr: Trajectory, start: int, stop: int, n: int) -> list[int]:
    """Cut [start, stop) into n pieces at quiet samples near the even boundaries."""
    t0, t1 = tr.time[start], tr.time[stop - 1]
    edges = [start]
    width = (t1 - t0) / n
    for k in range(1, n):
        lo = int(np.searchsorted(tr.time, t0 + (k - 0.25) * width))
        hi = int(np.searchsorted(tr.time, t0 + (k + 0.25) * width))
        edges.append(max(quiet_start(tr, lo, hi), edges[-1] + 2))
    edges.append(stop)
    return edges


def episodes(ds: Dataset, chunk: float | None = None) -> list[Window]:
    """Cut trajectories into episodes of about ``chunk`` seconds (None: auto).

    Auto: total duration / 16, within [2, 10] s; trajectories shorter than 1.5 chunks stay
    whole, so a set of short logs (e.g. BAM's 6 s) keeps one episode per log. Cuts fall on
    quiet samples (``quiet_start``) near the even boundaries.
    """
    if chunk is None:
        chunk = min(max(ds.duration() / 16.0, 2.0), 10.0)
    out = []
    for k, tr in enumerate(ds.trajectories):
        n = max(1, int(tr.duration // chunk)) if tr.duration >= 1.5 * chunk else 1
        edges = _cuts(tr, 0, len(tr), n)
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            if b - a >= 2:
                out.append(Window(k, int(a), int(b), int(a)))
    return out


def segments(ds: Dataset, eps: Sequence[Window], length: float, burn_in: float) -> list[Window]:
    """Multiple-shooting segments of about ``length`` s inside episodes, cut at quiet samples.

    Segments that start inside a trajectory (not at its first sample) are scored only after
    ``burn_in`` seconds, while the hidden state (velocity estimate, filters) settles.
    """
    out = []
    for ep in eps:
        tr = ds.trajectories[ep.traj]
        t0, t1 = tr.time[ep.start], tr.time[ep.stop - 1]
        n = max(1, int(round((t1 - t0) / length)))
        edges = _cuts(tr, ep.start, ep.stop, n)
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            if b - a < 2:
                continue
            score = a if a == 0 else int(np.searchsorted(tr.time, tr.time[a] + burn_in))
            score = min(score, b - 1)
            out.append(Window(ep.traj, int(a), int(b), score))
    return out


@dataclass(frozen=True)
class Split:
    """Episode indices per role: fit on ``train``, choose effects on ``select``, report ``test``."""

    train: tuple[int, ...]
    select: tuple[int, ...]
    test: tuple[int, ...]
    unscored: tuple[int, ...] = ()  # select episodes left out: chaotic replays (``gap.chaos``)


def _stratum(ds: Dataset, w: Window) -> tuple:
    """What an episode exercises: its log's trajectory name (BAM) and torque-off samples."""
    tr = ds.trajectories[w.traj]
    te = tr.channels.get("torque_enable")
    off = bool(te is not None and np.any(te[w.start:w.stop] < 0.5))
    return (str(tr.meta.get("trajectory", "")), off)


def _deal(groups: Sequence[Sequence[int]], shares: dict[str, float]) -> dict[str, list[int]]:
    """Deal each group's items to roles in proportion to ``shares``: within a group, each item
    goes to the role furthest below its share of that group, ties to the role furthest below
    its share overall (so small groups still spread across roles and the totals balance)."""
    out: dict[str, list[int]] = {r: [] for r in shares}
    total = 0
    for group in groups:
        local = dict.fromkeys(shares, 0)
        for j, item in enumerate(group):
            role = max(shares, key=lambda r: (shares[r] * (j + 1) - local[r],
                                              shares[r] * (total + 1) - len(out[r])))
            out[role].append(int(item))
            local[role] += 1
            total += 1
    return out


def _strata(ds: Dataset, eps: Sequence[Window], idx: Sequence[int],
            rng: np.random.Generator) -> list[list[int]]:
    """Episodes grouped by stratum, shuffled within groups, groups in a shuffled order."""
    groups: dict[tuple, list[int]] = {}
    for i in idx:
        groups.setdefault(_stratum(ds, eps[i]), []).append(int(i))
    lists = [[int(x) for x in rng.permutation(g)] for _, g in sorted(groups.items())]
    return [lists[k] for k in rng.permutation(len(lists))]


def _check_held_trajectories(ds: Dataset, held: set[int]) -> None:
    """LogError for held-out indices (``GapConfig.test_logs``, of ``ds.trajectories``) that are
    no trajectory, or hold out part of a log split at a time gap (its other pieces fitted while
    it is scored as unseen: a Python caller counting files met it silently)."""
    n = len(ds.trajectories)
    if bad := sorted(i for i in held if not 0 <= i < n):
        raise LogError(f"test_logs {tuple(bad)}: the data set has {n} trajectories (indices "
                       f"0..{n - 1}); test_logs index ds.trajectories")
    for source in dict.fromkeys(ds.sources if len(ds.sources) == n else ()):
        mine = [i for i, s in enumerate(ds.sources) if s == source]
        part = sorted(held.intersection(mine))
        if part and len(part) < len(mine):
            raise LogError(
                f"test_logs holds out trajectory {', '.join(map(str, part))} of {source} but "
                f"not {', '.join(str(i) for i in mine if i not in held)}: that log is "
                f"trajectories {', '.join(map(str, mine))} of ds.trajectories (split at a time "
                "gap, see Dataset.notes, or given twice), and test_logs index ds.trajectories, "
                "not the files. Hold out all of its trajectories or none (ds.sources names "
                "each trajectory's file)")


def split_episodes(ds: Dataset, eps: Sequence[Window], rng: np.random.Generator,
                   test_trajectories: Sequence[int] | None = None,
                   fractions: tuple[float, float] = (0.25, 0.25)) -> Split:
    """Split episodes into train / select / test, stratified by what they exercise.

    Episodes are grouped by stratum (the log's trajectory name when the log says it, as BAM logs
    do, and whether the torque is switched off), shuffled within groups and dealt to the roles
    so each role gets its share of every group (a group of two goes one to train, one to
    select): selection must see the kinds of motion it selects for.

    Args:
      ds: the data set.
      eps: episodes.
      rng: seeded generator for the random assignment.
      test_trajectories: trajectories held out for the test (e.g. a gain the fit never sees);
        the remaining episodes are split into train and select 1:1 (the final refit uses both).
      fractions: (select, test) fractions of the random split.
    Raises:
      LogError when there are too few episodes for three roles.
    """
    n = len(eps)
    idx = np.arange(n)
    if test_trajectories is not None:
        held = set(test_trajectories)
        _check_held_trajectories(ds, held)
        test = [i for i in idx if eps[i].traj in held]
        rest = [i for i in idx if eps[i].traj not in held]
        if not test or len(rest) < 2:
            raise LogError("the held-out logs must leave at least 2 episodes for fitting and "
                           "selection, and hold out at least one")
        roles = _deal(_strata(ds, eps, rest, rng), {"train": 0.5, "select": 0.5})
        return Split(tuple(sorted(roles["train"])), tuple(sorted(roles["select"])),
                     tuple(sorted(int(i) for i in test)))
    if n < 3:
        raise LogError(f"too little data: {n} episode(s) from "
                       f"{len(set(ds.sources)) or len(ds.trajectories)} log(s), "
                       f"{ds.duration():.3g} s in all; need at least 3 (longer or more logs) "
                       "to fit, select and test on different data")
    sel, tst = fractions
    roles = _deal(_strata(ds, eps, idx, rng),
                  {"train": 1 - sel - tst, "select": sel, "test": tst})
    return Split(tuple(sorted(roles["train"])), tuple(sorted(roles["select"])),
                 tuple(sorted(roles["test"])))


def subset(ds: Dataset, segs: Sequence[Window], seconds: float) -> list[Window]:
    """Evenly spread segments totalling about ``seconds`` (all when there are fewer)."""
    dur = [ds.trajectories[w.traj].time[w.stop - 1] - ds.trajectories[w.traj].time[w.start]
           for w in segs]
    total = float(sum(dur))
    if total <= seconds:
        return list(segs)
    k = max(1, int(round(len(segs) * seconds / total)))
    idx = np.unique(np.linspace(0, len(segs) - 1, k).round().astype(int))
    return [segs[i] for i in idx]


def traces(ds: Dataset, eps: Sequence[Window], base: Sequence[np.ndarray],
            ext: Sequence[np.ndarray], n: int = 2) -> list[dict]:
    """The first ``n`` episodes' logged and replayed traces (``base``, ``ext``: predictions
    over each window) for the report's plot."""
    out = []
    for w, b, e in list(zip(eps, base, ext, strict=True))[:n]:
        tr = ds.trajectories[w.traj]
        sl = slice(w.start, w.stop)
        out.append({"name": tr.name, "time": tr.time[sl] - tr.time[w.start],
                    "goal": tr.goal[sl], "measured": tr.qpos[sl], "baseline": b,
                    "extended": e, "joints": ds.joints, "actuators": ds.actuators})
    return out


def actuator_columns(ds: Dataset, targets: Targets, model: mujoco.MjModel) -> list[int]:
    """Column of each effect joint's actuator in the log's actuator list."""
    names = [model.actuator(int(a)).name for a in targets.actuators]
    return [list(ds.actuators).index(n) for n in names]
