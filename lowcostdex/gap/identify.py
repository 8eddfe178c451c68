"""Servo identification: fit a chosen servo structure on whole logs, open loop, BAM's way.

Where ``analyze`` *selects* unmodelled effects one at a time on top of a trusted nominal model,
identification fits a fixed structure (the servo's own parameters: motor constants, rotor
inertia, friction, mounting offset, firmware gain) jointly, the way BAM (Rhoban/bam ``bam.fit``)
identifies an actuator model. On real servos the nominal (datasheet) model is rarely trustworthy
in all of these at once, and greedy one-at-a-time selection cannot move six wrong ones together.

The objective is BAM's: every training log is replayed whole, open loop from its first state
(``bam_measure``), each log weighted equally (residuals scaled by 1 / sqrt(samples)), and the
squared error is minimised by the project's bounded lockstep Levenberg-Marquardt
(``fit.lockstep_lm``, all starts in one batched pass per round). Held-out logs are scored with
BAM's per-log MAE; ``ablation`` reports what each effect buys on them.

By default the structure's families are fitted from several jittered starts on the training
logs but those at the smallest value of a header field (``inner_split``: the lowest gain, whose
logs moved the fits away from what the other gains need); per family the restart with the lowest
cost is kept and the families are compared on the fitted logs (``identify_select``); the held-back
logs are scored and reported (``IdentifyConfig.stage_choice``: they also choose whether the chosen
fit's first stage or its joint stage is the model; off by default, measured worse).

Why one module: the stages, families, restarts, inner split and the checks of what the
training logs cannot tell are one procedure over one residual and Replayer.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from lowcostdex.errors import ConfigError, check_bool, check_choice, check_number, keyword_hints
from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import setup_offsets
from lowcostdex.gap.bam_logs import check_one_motor
from lowcostdex.gap.bam_measure import per_log_mae, whole_logs
from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.identify_bounds import _at_bound, bound_notes  # noqa: F401
from lowcostdex.gap.identify_logs import (  # noqa: F401 (re-exported)
    BACKDRIVEN,
    BACKDRIVEN_MODES,
    INNER_FIELDS,
    SPEED_MARGIN,
    backdriven_plan,
    faster_than_training,
    inner_split,
    peak_speed,
    set_backdriven,
    torque_off_seen,
    type_folds,
)
from lowcostdex.gap.identify_select import FAMILY_MARGIN, choose, choose_stage
from lowcostdex.gap.identify_select import choose_family as _choose_family
from lowcostdex.gap.identify_starts import jittered as _jitter
from lowcostdex.gap.identify_starts import seeded, widened
from lowcostdex.gap.identify_starts import starts as own_starts
from lowcostdex.gap.identify_verdict import verdict
from lowcostdex.gap.replay import Replayer
from lowcostdex.gap.rest_friction import held_at_rest
from lowcostdex.gap.torque_off import armature_seed, no_swing_warning
from lowcostdex.sim.effects import EFFECTS, AppliedEffect, Targets
from lowcostdex.sim.servo import goal_slew_states

# The servo's own parameters, as BAM models a voltage-controlled servo on a pendulum bench:
# back-EMF constant and torque per volt (velocity_limit, motor_strength: kt and R), reflected
# rotor inertia (armature), Coulomb and viscous friction, gear friction carried by the load
# (sliding and breakaway; acts back-driven), the bench's mounting offset (q_offset), and (not
# BAM's) the drive's fall with the duty (supply_resistance; Rhoban XL330: gap-stall7). The
# firmware's duty per position error (``MotorSpec.error_gain``) is a measured constant (BAM's
# oscilloscope values) and is not fitted: add "gain_error" to fit it (BAM's error_gain_ratio).
SERVO_STRUCTURE: tuple[str, ...] = (
    "velocity_limit", "motor_strength", "inertia_error", "coulomb_friction", "viscous_damping",
    "gearbox_friction", "mounting_offset", "supply_resistance")
# Fitted in a second stage, from the first stage's optimum: the motor's constants and firmware
# gain, goal slew and supply resistance (they trade off against friction and inertia; alone
# first, the joint fit strays).
STAGE_TWO = frozenset({"velocity_limit", "motor_strength", "gain_error", "torque_limit",
                       "goal_slew", "supply_resistance"})
# A second start with a large breakaway share (stick-slip: the cost is flat at no breakaway).
BREAKAWAY_START = {("gearbox_friction", "static"): 0.3, ("gearbox_friction", "velocity"): 0.3}
# Parameters also fitted held at their null, as a second family: the gear friction's
# back-driven share (1: a gearbox whose friction grows with the load it carries in both
# directions, BAM M3/M4; free: directional, BAM M5). Freeing it moves the fit into other basins,
# so both families are fitted and the training logs decide (``IdentifyConfig.directional``
# False: the held family only). Free, the fits put it at its 0.05 floor on Rhoban XL330 and
# STS3032: held at 1, Rhoban's held-out error falls (BAM split 42.5 -> 41.5, trajectory folds
# mean 62.7 -> 55.8) but STS3032's rises (24.3 -> 34.9): bench/RESULTS.md gap-gear6.
HELD_FIRST = frozenset({("gearbox_friction", "backdrive")})
# A third family holds the motor's constants and firmware gain (the STAGE_TWO effects) at their
# catalogue values and the measured-voltage term off: a servo whose datasheet (or earlier fit)
# constants hold needs none of them, and freeing them can move the fit into a basin that fits
# the training gains as well and extrapolates worse (measured 2026-11-26 on STS3032, kp 32 ->
# kp 8: 29.5 mrad with them free, 22.6 held, the same training MAE 15.7).
MOTOR_EFFECTS = STAGE_TWO | {"voltage_sag"}
# Parameters held at their null in every fit unless ``IdentifyConfig.hold`` says otherwise: the
# Stribeck curvature (2, Gaussian).
HELD_ALWAYS = frozenset({("gearbox_friction", "alpha")})


def servo_structure(ds: Dataset) -> tuple[str, ...]:
    """``SERVO_STRUCTURE``, plus ``voltage_sag`` when every log measures the supply voltage,
    ``goal_slew`` when the logs' servos slew their goal (a Feetech STS: ``MotorSpec.goal_speed``)
    and the torque-off friction's own law (``backdriven_friction``) when a log has the torque off."""
    slewed = any(len(goal_slew_states(ds.compiled(k))[0]) for k in ds.models)
    off = torque_off_seen(ds, range(len(ds.trajectories)))
    return (SERVO_STRUCTURE + (("voltage_sag",) if "voltage" in ds.channels() else ())
            + (("goal_slew",) if slewed else ()) + ((BACKDRIVEN,) if off else ()))

Progress = Callable[[str, float], None]


@keyword_hints
@dataclass(frozen=True)
class IdentifyConfig:
    """Settings of one identification.

    Attributes:
      effects: the structure to fit (effect names, fitted jointly on every effect joint).
      starts: extra start points besides the catalogue's: {(effect, param): value}, the other
        parameters at their catalogue start.
      hold: (effect, param) pairs held at their null in every fit.
      loss: "mse" (least squares) or "mae": after the least-squares stages, a polish of the
        absolute error BAM scores, smoothed below ``delta`` (Charbonnier: sum of
        2 (sqrt(r^2 + delta^2) - delta)) so that the Levenberg-Marquardt model of it holds;
        from scratch that loss is too flat for LM, from the least-squares optimum it only
        moves where it lowers the absolute error.
      delta: [rad] the smoothing width of the "mae" loss.
      max_rounds: Levenberg-Marquardt rounds at most (the first stage; 30 before 2026-11-26
        13:00: 15 measured -27 % CPU on STS3032, 254 vs 340-364 s, held out 22.0 vs 21.6 mrad;
        STS3250 lift_and_drop held out 76.7 vs 209.5; bench/RESULTS.md).
      rtol: stop when an accepted step lowers the cost by less than this fraction.
      nthread: simulation threads (0: all CPUs).
      cold: the joint (second) stage also runs the catalogue starts from scratch, besides
        the first stage's optimum and its extra-start variants (off: measured never to win,
        ending 15-30x above the warm start on STS3032).
      joint_rounds: Levenberg-Marquardt steps of the joint (second) stage, from the first
        stage's optimum. Converged, the joint fit over-fits the training gains (held out,
        mrad: Rhoban XL330 54.0 vs 45.6 after 4 steps, STS3032 30.4 vs 29.5; Pham 11.1 vs
        12.4); 4 is what the joint stage ran before 2026-11-26, when pruning ended it there.
      jitter: relative spread of the first stage's starts (each value times 1 + jitter N(0, 1),
        clipped to its search bounds; 0: the catalogue's starts exactly). Measures how much the
        identified model and its held-out error depend on where the least-squares path starts
        (``bench/gap_real.py --seeds``).
      seed: seed of the jitter's random generator.
      select: how the family (and, with ``restarts`` > 1, the fit) is chosen: "train" (the
        training logs' MAE, ``_choose_family``) or "inner" (fitted on the training logs but the
        held-back ones of ``inner_split``, the restart and the family chosen on the fitted
        logs by ``identify_select``, the held-back logs scored; that fit is the model). "inner" falls back to "train" when the headers cannot split
        the training logs. "types": each trajectory type left out in turn (``type_folds``),
        every family fitted (one start) on the others and scored on it; the family chosen on
        the mean is fitted on all training logs ("inner" when fewer than two types).
      restarts: with select="inner", fits per family from differently jittered starts.
      restart_jitter: relative spread of the restarts after the first (at least ``jitter``).
      directional: also fit the gear friction's back-driven share (``HELD_FIRST``) as a
        family of its own (BAM M5's directional gearbox); False: held at 1 in every family
        (BAM M3/M4's gearbox, friction load-dependent both ways).
      prior: [rad] a pull of every free parameter toward its catalogue null (0: none): the
        least-squares cost gains prior^2 x (fitted logs) x sum over free parameters of
        ((u - u_null) / (u_hi - u_lo))^2 (u: the optimizer's coordinate, log for scales), i.e.
        moving one parameter across its whole range costs as much as an RMS error of ``prior``
        on every fitted log.
      stage_choice: with select="inner", the chosen fit's first stage (its motor constants at
        their catalogue values) is the model instead of its joint fit unless the joint is 2 %
        lower on the held-back logs (``identify_select.choose_stage``). Off: measured
        2026-11-28 on every real-log set, it kept the first stage on Rhoban's up_and_down fold
        (held back 40.5 vs 41.8 mrad; held out 57.7 vs the joint's 46.0) and Pham's BAM split
        (16.0 vs 16.2; 8.4 vs 7.6), and changed nothing else (bench/RESULTS.md gap-real12).
      swing_seed: when training logs swing with the torque off and their swings put the
        armature 1.5x or more from the catalogue's (``torque_off.armature_seed``), the first
        stage starts the armature's scale there (else at 1). Off: measured 2026-11-28 it lost
        on Rhoban's BAM split (held out 31.1 -> 32.6 mrad, armature 0.002 from the swings)
        and STS3250's sin_time_square fold (57.0 -> 81.4), won on STS3250's up_and_down
        (2.4 -> 1.6), equal on sin_sin (13.3) (bench/RESULTS.md gap-real13).
      backdriven: the torque-off friction's own law, "fit" or "null" (absent):
        ``identify_logs.backdriven_plan`` (bench/RESULTS.md gap-real15).
      setup_offsets: a mounting offset per bench set-up from its own torque-off logs
        (``gap.setup_offsets``; bench/RESULTS.md lead24).
    """

    effects: tuple[str, ...] = SERVO_STRUCTURE
    starts: tuple[dict, ...] = (BREAKAWAY_START,)
    loss: str = "mse"
    hold: frozenset = HELD_ALWAYS
    delta: float = 0.005
    max_rounds: int = 15
    rtol: float = 1e-4
    nthread: int = 0
    cold: bool = False
    joint_rounds: int = 4
    jitter: float = 0.0
    seed: int = 0
    select: str = "inner"
    restarts: int = 3
    restart_jitter: float = 1e-3
    prior: float = 0.0
    directional: bool = True
    stage_choice: bool = False
    swing_seed: bool = False
    backdriven: str = "fit"
    setup_offsets: bool = True

    def __post_init__(self) -> None:
        _check_types(self)
        check_choice("backdriven", self.backdriven, BACKDRIVEN_MODES)
        if not self.effects:
            raise ConfigError("identification needs at least one effect to fit")
        for name in self.effects:
            if name not in EFFECTS:
                raise ConfigError(f"unknown effect {name!r}; valid: {sorted(EFFECTS)}")
        for name, param in self.hold:
            if name not in EFFECTS:
                raise ConfigError(f"hold: unknown effect {name!r}; valid: {sorted(EFFECTS)}")
            EFFECTS[name].param(param)  # raises with the valid parameter names
        if self.loss not in ("mse", "mae"):
            raise ConfigError(f"unknown loss {self.loss!r}; valid: mse, mae")
        if not self.delta > 0:
            raise ConfigError("delta must be > 0 rad")
        if self.max_rounds < 1 or self.joint_rounds < 1:
            raise ConfigError("max_rounds and joint_rounds must be >= 1")
        if not (0.0 <= self.jitter < 1.0 and 0.0 <= self.restart_jitter < 1.0):
            raise ConfigError("jitter and restart_jitter must be in [0, 1) (relative spreads)")
        if self.select not in ("train", "inner", "types"):
            raise ConfigError(f"unknown select {self.select!r}; valid: train, inner, types")
        if self.restarts < 1:
            raise ConfigError("restarts must be >= 1")
        if not self.prior >= 0:
            raise ConfigError("prior must be >= 0 rad")


def _check_types(c: IdentifyConfig) -> None:
    """Types and finiteness of IdentifyConfig's fields (a string from a JSON file, NaN, 1.5
    rounds, one effect name given as a string), before the range checks."""
    for name, low in (("max_rounds", 1), ("joint_rounds", 1), ("restarts", 1), ("nthread", 0),
                      ("seed", 0)):
        check_number(name, getattr(c, name), low, integer=True)
    for name in ("delta", "rtol", "jitter", "restart_jitter", "prior"):
        check_number(name, getattr(c, name))
    check_number("rtol", c.rtol, 0)
    for name in ("cold", "directional", "stage_choice", "swing_seed", "setup_offsets"):
        check_bool(name, getattr(c, name))
    if isinstance(c.effects, str) or not isinstance(c.effects, (tuple, list)):
        raise ConfigError(f"effects={c.effects!r} must be a tuple of effect names, e.g. "
                          "servo_structure(ds)")
    pairs = isinstance(c.hold, (set, frozenset, tuple, list)) and all(
        isinstance(h, tuple) and len(h) == 2 for h in c.hold)
    if not pairs:
        raise ConfigError(f"hold={c.hold!r:.80} must be a set of (effect, parameter) pairs")
    if isinstance(c.starts, (str, dict)) or not isinstance(c.starts, (tuple, list)) or not all(
            isinstance(d, dict) for d in c.starts):
        raise ConfigError(f"starts={c.starts!r:.80} must be a tuple of dicts "
                          "{(effect, parameter): value}")
    for d in c.starts:
        for key, value in d.items():
            if not (isinstance(key, tuple) and len(key) == 2 and key[0] in EFFECTS):
                raise ConfigError(f"starts: key {key!r} must be an (effect, parameter) pair; "
                                  f"effects: {sorted(EFFECTS)}")
            EFFECTS[key[0]].param(key[1])  # raises with the valid parameter names
            check_number(f"starts[{key!r}]", value)


@dataclass
class Identified:
    """An identified servo model and its errors (BAM's per-log MAE [rad]).

    Attributes:
      effects: the fitted effects (apply them to the nominal models).
      train, test: log indices fitted on / held out.
      nominal_mae, identified_mae: {log index: MAE} of the nominal and identified models.
      ablation: effect name -> mean held-out MAE with that effect removed (others kept).
      fit_seconds: wall time of the fit; rounds: LM rounds run (all stages); cost: final
        training cost.
      at_bound: "effect.param" of fitted values at a search bound (not at the null): the range
        is too narrow or the parameter stands in for something the structure lacks.
      family: the family kept ("free", "held": HELD_FIRST at their null, "nominal_motor": the
        MOTOR_EFFECTS at their null); family_train_mae: each family's training-log mean per-log
        MAE [rad] (empty when only one family was fitted); with select="inner" the inner fit
        logs' MAE of each family's lowest-cost restart (what it was chosen by).
      selection: with select="inner": the header field split on, the inner fit and validation
        logs, every (family.restart)'s least-squares cost ("cost") and MAE on the fitted and
        on the validation logs [rad] ("fit_mae", "val_mae"), and the one chosen.
      notes: what the identification decided from the logs themselves (e.g. no training log
        has the torque off, so the back-driven share of the gear friction was held at 1).
      verdict: the identified model against the nominal one on the held-out logs
        (``identify_verdict.verdict``: "no reliable gain" or the gain).
      setup_offsets: {bench set-up: its mounting offset's change from the common one [rad]}
        (``gap.setup_offsets``), used for every log of that set-up.
    """

    effects: list[AppliedEffect]
    train: tuple[int, ...]
    test: tuple[int, ...]
    nominal_mae: dict[int, float]
    identified_mae: dict[int, float]
    ablation: dict[str, float] = field(default_factory=dict)
    fit_seconds: float = 0.0
    rounds: int = 0
    cost: float = math.nan
    at_bound: list[str] = field(default_factory=list)
    family: str = "free"
    family_train_mae: dict[str, float] = field(default_factory=dict)
    selection: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    verdict: dict = field(default_factory=dict)
    setup_offsets: dict[str, float] = field(default_factory=dict)

    def mean(self, logs: Sequence[int], identified: bool = True) -> float:
        """Mean per-log MAE over ``logs`` (BAM's set-level number) [rad]."""
        src = self.identified_mae if identified else self.nominal_mae
        return float(np.mean([src[i] for i in logs])) if logs else math.nan

    def params(self) -> dict[str, dict[str, list[float]]]:
        """{effect: {param: values per joint}} of the fitted effects; a parameter that does not
        apply to the servo (every value non-finite, e.g. velocity_limit.speed, null inf, which
        only acts on force-limited actuators) is left out, so the values are plain JSON."""
        return {e.name: {p: v.tolist() for p, v in e.values.items()
                         if np.any(np.isfinite(v))} for e in self.effects}


def identify(ds: Dataset, train: Sequence[int], test: Sequence[int] = (),
             config: IdentifyConfig = IdentifyConfig(), progress: Progress | None = None
             ) -> Identified:
    """Fit ``config.effects`` on the ``train`` logs, score ``train`` and ``test`` logs.

    Args:
      ds: the data set (BAM logs resampled by ``bam_measure.grid_dataset`` give BAM's measure).
      train: indices of the logs to fit on.
      test: indices of held-out logs (scored, never fitted).
      config: structure and fit settings.
      progress: optional callback (stage, fraction done).
    Raises:
      ConfigError for an empty or overlapping split.
    """
    train, test = tuple(int(i) for i in train), tuple(int(i) for i in test)
    if not train:
        raise ConfigError("identification needs at least one training log")
    if set(train) & set(test):
        raise ConfigError("training and held-out logs overlap")
    check_one_motor([ds.trajectories[i] for i in (*train, *test)])
    prog = progress or (lambda s, f: None)
    rep = Replayer(ds, config.effects, nthread=config.nthread)
    joints = ds.effect_joints
    key = ds.trajectories[train[0]].model
    m0 = rep.models[key]
    targets = Targets.resolve(m0, joints)
    w_train = whole_logs(ds, train)
    ctx = fitmod.Context(dt=ds.timestep, peak_force=_peak_force(rep, w_train, targets, m0),
                         **fitmod.servo_facts(m0, targets.actuators),
                         damping=m0.dof_damping[targets.dofs].copy())
    weights = [1.0 / math.sqrt(ds.trajectories[w.traj].qpos.size) for w in w_train]

    def make_residual(windows, wts):
        def residual(points, absolute=False):
            pred, _ = rep.run(windows, [s.to_effects(x) for s, x in points])
            out = []
            for col in pred:
                parts = []
                for w, p, k in zip(windows, col, wts, strict=True):
                    r = (ds.trajectories[w.traj].qpos - p).ravel()
                    if absolute:
                        # sum of r'^2 = sum of 2 (sqrt(r^2 + d^2) - d): |r| beyond d, smooth at 0
                        d = config.delta
                        r = np.sign(r) * np.sqrt(2.0 * (np.sqrt(r * r + d * d) - d))
                    parts.append(r * k)
                if config.prior > 0:
                    parts.append(_prior_residual(points[len(out)][0], points[len(out)][1],
                                                 config.prior * math.sqrt(len(windows))))
                out.append(np.concatenate(parts))
            return out
        return residual

    residual = make_residual(w_train, weights)
    t0 = time.perf_counter()
    full = fitmod.Structure.build(config.effects, joints, ctx)
    off_null, off_after = backdriven_plan(ds, train, config.effects, config.backdriven)
    hold = frozenset(config.hold) | off_null
    full = _hold(full, hold) or full
    families = {"free": hold}
    notes: list[str] = []
    if _hold(full, HELD_FIRST) is not None:
        families["held"] = HELD_FIRST | hold
        if not config.directional:
            del families["free"]  # the share held at 1: HELD_FIRST's comment
        elif not torque_off_seen(ds, train):
            # nothing in the training logs back-drives the servo with the torque off: the
            # back-driven share is held at 1 in every family (a symmetric gearbox, BAM M3/M4;
            # the XL330's 0.05, what its torque-off logs fit, measured worse: Rhoban
            # lift_and_drop fold 64.0 -> 176.1 mrad, bench/RESULTS.md gap-real13)
            del families["free"]
            notes.append("no training log has the torque off: the gear friction's back-driven "
                         "share is held at 1 (measured on STS3250 with lift_and_drop held "
                         "out: 262 mrad with it free, 210 held)")
    motor = frozenset((f.effect, f.param) for f in full.free if f.effect in MOTOR_EFFECTS)
    if motor and len(motor) < len(full.free):
        families["nominal_motor"] = motor | hold | (
            HELD_FIRST if "free" not in families else frozenset())
    seed: dict[tuple[str, str], float] = {}
    sf = armature_seed(ds, train) if config.swing_seed and "inertia_error" in config.effects \
        and torque_off_seen(ds, train) else None
    if sf is not None:
        seed[("inertia_error", "scale")] = sf.armature / sf.catalogue_armature
        notes.append(f"the training logs' torque-off swings say armature {sf.armature:.3g} kg m^2 "
                     f"(catalogue {sf.catalogue_armature:.3g}): its fit starts there "
                     "(gap.torque_off)")
    fast = faster_than_training(ds, train, test)
    if fast:
        notes.append(f"{len(fast)} held-out log(s) move faster than any training log (peak "
                     f"{max(fast.values()):.1f} rad/s against {peak_speed(ds, train):.1f}): "
                     "the fitted friction's speed dependence is extrapolated there")
    stall = float(np.max(ctx.stall))

    def rest(logs):  # gap.rest_friction: the torque never off in ``logs``
        return not torque_off_seen(ds, logs) and "stribeck_friction" not in config.effects
    folds = type_folds(ds, train) if config.select == "types" else None
    inner = inner_split(ds, train) if config.select == "inner" or (
        config.select == "types" and folds is None) else None
    fam_mae: dict[str, float] = {}
    selection: dict = {}
    if folds is not None:
        # a family that only helps the types it was fitted on loses on the type left out
        per_fold: dict[str, list[float]] = {f: [] for f in families}
        rounds = 0
        for k, (kind, fit_logs, val_logs) in enumerate(folds):
            prog(f"type fold {k + 1}/{len(folds)}: {kind} left out", 0.7 * k / len(folds))
            w_fit = whole_logs(ds, fit_logs)
            wts = [1.0 / math.sqrt(ds.trajectories[w.traj].qpos.size) for w in w_fit]
            cands, r = _fit_families(make_residual(w_fit, wts), joints, ctx, config, families,
                                     1, lambda s, f: None, seed=seed)
            rounds += r
            keys = list(cands)
            frep, cols = rep, [cands[c].effects() for c in keys]
            if rest(fit_logs):  # the fold's fit as the final one would be
                frep, cols, _ = held_at_rest(ds, config.effects, config.nthread, fit_logs, cols,
                                             stall, FAMILY_MARGIN)
            vm = per_log_mae(frep, whole_logs(ds, val_logs), cols)
            for i, (f, _) in enumerate(keys):
                per_fold[f].append(float(np.mean(vm[i])))
        fam_mae = {f: float(np.mean(v)) for f, v in per_fold.items()}
        n_free = {f: len((_hold(full, h) or full).free) for f, h in families.items()}
        chosen = _choose_family(fam_mae, n_free)
        selection = {"field": "trajectory", "folds": [k for k, _, _ in folds], "chosen": chosen,
                     "val_mae": {f"{f}.{k}": v for f, vs in per_fold.items()
                                 for (k, _, _), v in zip(folds, vs, strict=True)}}
        cands, r = _fit_families(residual, joints, ctx, config, {chosen: families[chosen]}, 1,
                                 prog, seed=seed)  # on all training logs
        rounds += r
        best = cands[(chosen, 0)]
    elif inner is not None:
        # every family from ``restarts`` jittered starts, fitted on the inner fit logs; the
        # restart and the family chosen on those logs (gap.identify_select), the held-back
        # logs scored (selection["val_mae"]); that fit is the identified model
        field_, fit_logs, val_logs = inner
        w_fit = whole_logs(ds, fit_logs)
        wts = [1.0 / math.sqrt(ds.trajectories[w.traj].qpos.size) for w in w_fit]
        residual = make_residual(w_fit, wts)
        stages: dict = {}
        cands, rounds = _fit_families(residual, joints, ctx, config, families,
                                      config.restarts, prog, stages, seed=seed)
        keys = list(cands)
        prog("choosing the family and the fit (gap.identify_select)", 0.8)
        fm = {k: float(np.mean(_train_mae(cands[k], w_fit, wts, ds, rep))) for k in keys}
        vm = per_log_mae(rep, whole_logs(ds, val_logs), [cands[k].effects() for k in keys])
        chosen, per_fam = choose({k: cands[k].cost for k in keys}, fm,
                                 {k: len(cands[k].structure.free) for k in keys},
                                 at_bound={k: _at_bound(cands[k]) for k in keys}
                                 if torque_off_seen(ds, fit_logs) else None, held=families,
                                 val_mae={k: float(np.mean(vm[i])) for i, k in enumerate(keys)})
        fam_mae = {f: fm[k] for f, k in per_fam.items()}
        selection = {"field": field_, "fit_logs": list(fit_logs), "val_logs": list(val_logs),
                     "cost": {f"{f}.{j}": float(cands[(f, j)].cost) for f, j in keys},
                     "fit_mae": {f"{f}.{j}": v for (f, j), v in fm.items()},
                     "val_mae": {f"{f}.{j}": float(np.mean(vm[i]))
                                 for i, (f, j) in enumerate(keys)},
                     "chosen": f"{chosen}.{per_fam[chosen][1]}"}
        # the chosen fit itself (LM steps from it on all training logs: worse held out); with
        # stage_choice, its stage kept on the held-back logs
        k_best = per_fam[chosen]
        tracks = stages[k_best] if config.stage_choice else [cands[k_best]]
        vals = [float(np.mean(vm[keys.index(k_best)]))] if len(tracks) > 1 else []
        if vals:
            vals = [float(np.mean(v)) for v in per_log_mae(
                rep, whole_logs(ds, val_logs), [t.effects() for t in tracks[:-1]])] + vals
        n_free = [len(t.structure.free) for t in tracks]
        kept = choose_stage(vals, n_free)
        best = tracks[-1] if kept == len(tracks) - 1 else widened(tracks[kept],
                                                                    tracks[-1].structure)
        if vals:
            selection["stage"] = {"val_mae": vals, "n_free": n_free, "chosen": kept + 1}
    else:
        cands, rounds = _fit_families(residual, joints, ctx, config, families, 1, prog,
                                      seed=seed)
        bests = {f: t for (f, _), t in cands.items()}
        if len(bests) > 1:
            prog("choosing the family on the training logs", 0.88)
            fam_mae = {f: float(np.mean(_train_mae(t, w_train, weights, ds, rep)))
                       for f, t in bests.items()}
        chosen = _choose_family(fam_mae, {f: len(t.structure.free) for f, t in bests.items()}
                                ) if fam_mae else next(iter(bests))
        best = bests[chosen]
    if config.loss == "mae":  # on the logs the least-squares stages fitted
        prog("absolute-error polish", 0.9)
        polished = fitmod.Track(best.structure, best.u.copy(), label="mae")
        fitmod.lockstep_lm([polished], lambda pts: residual(pts, absolute=True),
                           config.max_rounds, rtol=config.rtol, jacobian_at_end=False)
        best = polished
        rounds += polished.rounds
    effects = set_backdriven(best.effects(), off_after, notes)
    if rest(train):
        rep, (effects,), (level,) = held_at_rest(ds, config.effects, config.nthread, train,
                                                 [effects], stall, FAMILY_MARGIN)
        notes.append(f"no training log has the torque off: a breakaway at rest of {level:.3g} N m"
                     " beyond the gear friction's own (the largest costing the training logs"
                     " <= 2 %; gap.rest_friction)")
    offsets = setup_offsets.fit(ds, train, rep, effects) if config.setup_offsets else {}
    if offsets:
        notes.append(f"{len(offsets)} set-up(s) hang off the common mounting offset in their "
                     "own torque-off logs: each gets its own (gap.setup_offsets)")
    fit_s = time.perf_counter() - t0
    prog("scoring", 0.95)
    logs = train + test
    mae = setup_offsets.scored(ds, logs, rep, [[], effects], offsets)
    warn = no_swing_warning(torque_off_seen(ds, train))
    out = Identified(effects, train, test,
                     nominal_mae=dict(zip(logs, mae[0].tolist(), strict=True)),
                     identified_mae=dict(zip(logs, mae[1].tolist(), strict=True)),
                     fit_seconds=fit_s, rounds=rounds, cost=best.cost,
                     at_bound=_at_bound(best), family=chosen, family_train_mae=fam_mae,
                     selection=selection, notes=[warn] * bool(warn) + notes + bound_notes(best),
                     setup_offsets=offsets)
    out.verdict = verdict(out.nominal_mae, out.identified_mae, test)
    if test:  # the ablation is reported on the held-out logs only: replay only those
        abl = setup_offsets.scored(ds, test, rep, [[e for e in effects if e.name != n]
                                                    for n in config.effects], offsets)
        out.ablation = {n: float(np.mean(abl[i])) for i, n in enumerate(config.effects)}
    prog("done", 1.0)
    return out


def _fit_families(residual, joints, ctx: fitmod.Context, config: IdentifyConfig,
                  families: dict[str, frozenset], copies: int, prog: Progress,
                  stages_out: dict | None = None, seed: dict | None = None) -> tuple[dict[tuple[str, int], fitmod.Track], int]:
    """Both least-squares stages for every family, ``copies`` times from differently jittered
    first-stage starts, in the same batched passes but pruned apart (each (family, copy) its
    own group). Returns {(family, copy): its best stage-2 track} and the LM rounds run;
    ``stages_out`` (given) gets {(family, copy): [its best track of each stage]}.

    Stage 1: the motor constants held at their nominal values; stage 2: everything, for
    ``joint_rounds`` steps from the stage-1 optimum (and it with each extra start's overrides;
    the joint fit has local minima that the nested one avoids, and from its optimum the joint
    fit can only do better on the fitted logs). Copy 0 is jittered by ``config.jitter`` (0:
    the catalogue's starts exactly), copy j >= 1 by ``max(jitter, restart_jitter)`` from its
    own generator (seeded by ``config.seed`` and j). ``seed``: {(effect, param): value} where
    the first stage's starts put those scalars (before the jitter)."""
    later = [n for n in config.effects if n in STAGE_TWO]
    stages = [tuple(n for n in config.effects if n not in STAGE_TWO)] if later else []
    stages = [st for st in stages if st] + [tuple(config.effects)]
    rngs = [np.random.default_rng(config.seed if j == 0 else (config.seed, j))
            for j in range(copies)]
    spread = [config.jitter if j == 0 else max(config.jitter, config.restart_jitter)
              for j in range(copies)]
    best: dict[tuple[str, int], fitmod.Track] = {}
    rounds = 0
    for k, names in enumerate(stages):
        groups: dict[tuple[str, int], list[fitmod.Track]] = {}
        for fam, hold in families.items():
            for j in range(copies):
                st = fitmod.Structure.build(names, joints, ctx)
                st = _hold(st, hold) or st
                starts = own_starts(st, config.starts)
                if seed and not best:
                    starts = [seeded(st, x, seed) for x in starts]
                if spread[j] > 0 and not best:
                    starts = [_jitter(st, x, spread[j], rngs[j]) for x in starts]
                if (fam, j) in best:
                    # the previous optimum, and it with each extra start's overrides applied
                    base = st.values_from(best[(fam, j)].effects())
                    starts = own_starts(st, config.starts, base=base) + (starts if config.cold
                                                                       else [])
                groups[(fam, j)] = [fitmod.Track(st, st.u(x0),
                                                 label=f"{fam}.{j}.stage{k + 1}.start{i}")
                                    for i, x0 in enumerate(starts)]
        frac = (k, len(stages))

        def prune(rnd, _tracks, groups=groups):
            for g in groups.values():
                _prune_trailing(rnd, g)

        # the joint stage after a first one: a few steps from its optimum (``joint_rounds``)
        n_rounds = min(config.max_rounds, config.joint_rounds) if k else config.max_rounds
        fitmod.lockstep_lm([t for g in groups.values() for t in g], residual, n_rounds,
                           rtol=config.rtol, jacobian_at_end=False,
                           on_round=lambda r, live, frac=frac, n=n_rounds: prog(
                               f"stage {frac[0] + 1}/{frac[1]}: LM round {r + 1} ({live} live)",
                               0.8 * (frac[0] + min(1.0, (r + 1) / n)) / frac[1]),
                           prune=prune)
        best = {key: min(g, key=lambda t: t.cost) for key, g in groups.items()}
        if stages_out is not None:
            for key, t in best.items():
                stages_out.setdefault(key, []).append(t)
        rounds += max(t.rounds for g in groups.values() for t in g)
    return best, rounds


def _prior_residual(st: fitmod.Structure, x: np.ndarray, weight: float) -> np.ndarray:
    """weight x (u - u_null) / (u_hi - u_lo) per free parameter (``IdentifyConfig.prior``)."""
    out = np.empty(len(st.free))
    for i, (f, v) in enumerate(zip(st.free, x, strict=True)):
        lo, hi = f.u_bounds
        null = float(np.clip(EFFECTS[f.effect].param(f.param).null, f.lo, f.hi))
        out[i] = (f.to_u(v) - f.to_u(null)) / (hi - lo)
    return weight * out


def _prune_trailing(rnd: int, tracks: Sequence[fitmod.Track], after: int = 4,
                    margin: float = 0.02) -> None:
    """From round ``after`` on, end the starts of one family that trail its best by ``margin``.

    (Not ``fit.prune_tracks``: its "cost fell by less than a tenth of the largest fall" rule cut
    STS3032's best warm stage-2 track at 4 rounds, its cost still falling.)"""
    if rnd + 1 < after or not tracks:
        return
    best = min(t.cost for t in tracks)
    for t in tracks:
        if not t.done and t.cost > (1.0 + margin) * best:
            t.done = True


def _train_mae(t: fitmod.Track, windows, weights, ds: Dataset, rep: Replayer) -> np.ndarray:
    """Per-log MAE [rad] of a least-squares track on its training windows, read off its last
    residual (log by log: measured - predicted, times the log's weight); replayed when the
    track holds none."""
    if t.r is None or len(t.r) != sum(ds.trajectories[w.traj].qpos.size for w in windows):
        return per_log_mae(rep, windows, [t.effects()])[0]
    out, k = [], 0
    for w, wt in zip(windows, weights, strict=True):
        n = ds.trajectories[w.traj].qpos.size
        out.append(float(np.mean(np.abs(t.r[k:k + n]))) / wt)
        k += n
    return np.asarray(out)


def _hold(st: fitmod.Structure, params: frozenset) -> fitmod.Structure | None:
    """``st`` with ``params`` ((effect, param) pairs) held at their null (None: none in it);
    the scalars ``st`` already holds at a value (``Structure.held``: a ``Context.widened``
    range of one value) keep it."""
    free = [f for f in st.free if (f.effect, f.param) not in params]
    if len(free) == len(st.free):
        return None
    return replace(st, free=free)


def _peak_force(rep: Replayer, windows, targets: Targets, model) -> np.ndarray:
    """Peak |actuator force| of the nominal model on ``windows`` per effect joint [N m]."""
    _, peaks = rep.run(windows, [[]], force_peak=True)
    names = [model.actuator(int(a)).name for a in targets.actuators]
    cols = [list(rep.ds.actuators).index(n) for n in names]
    return np.asarray(peaks[0])[cols]


def breakdown(ds: Dataset, mae: dict[int, float], logs: Sequence[int], key: str) -> dict:
    """Mean per-log MAE grouped by a log header field (e.g. "trajectory", "kp") [rad]."""
    groups: dict = {}
    for i in logs:
        groups.setdefault(ds.trajectories[i].meta.get(key), []).append(mae[i])
    return {k: float(np.mean(v)) for k, v in sorted(groups.items(), key=lambda kv: str(kv[0]))}
