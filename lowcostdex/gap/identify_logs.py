"""What identification reads off the training logs themselves, before any fit: which header
field splits them for the inner validation (``inner_split``), the trajectory-type folds
(``type_folds``), whether the torque is ever off (``torque_off_seen``) and how fast they move
(``peak_speed``, ``faster_than_training``). Used by ``gap.identify`` (which re-exports them)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lowcostdex.gap.dataset import Dataset
from lowcostdex.sim.effects import AppliedEffect

# Header fields that tell the training logs' setups apart, in the order the inner validation
# tries them (``inner_split``): the firmware gain first (what a user changes, and the P law must
# carry from one gain to another), then the bench geometry and the supply.
INNER_FIELDS: tuple[str, ...] = ("kp", "length", "mass", "arm_mass", "vin")
# A held-out log whose peak speed exceeds the fastest training log's by this factor is flagged
# (``faster_than_training``: the friction's speed law extrapolated). Rhoban XL330, sin_time_square
# held out (4.8-14.9 rad/s vs <= 7.4 trained), 2026-11-26: 88.1 mrad vs the datasheet's 73.0.
SPEED_MARGIN = 1.2


def torque_off_seen(ds: Dataset, logs: Sequence[int]) -> bool:
    """Whether any of ``logs`` has samples with the torque off (``torque_enable`` < 0.5)."""
    return any("torque_enable" in ds.trajectories[i].channels
               and bool(np.any(ds.trajectories[i].channels["torque_enable"] < 0.5))
               for i in logs)


# The torque-off (back-driven) friction's own law (``backdriven_friction``): what it is in each
# identification (``backdriven_plan``). Measured 2026-11-28 (bench/RESULTS.md gap-real15).
BACKDRIVEN = "backdriven_friction"
BACKDRIVEN_PARAMS = frozenset({(BACKDRIVEN, "coulomb"), (BACKDRIVEN, "viscous"),
                               (BACKDRIVEN, "gear"), (BACKDRIVEN, "joint")})
BACKDRIVEN_MODES = ("fit", "null")


def catalogue_backdriven(ds: Dataset, logs: Sequence[int]) -> tuple[float, float] | None:
    """The servo catalogue's torque-off law (``MotorSpec.backdriven``) of the BAM logs' motor
    among ``logs``; None when they name none or it has none."""
    from lowcostdex.gap.bam_logs import BAM_MOTORS, bam_motor
    from lowcostdex.sim import servo

    for i in logs:
        meta = ds.trajectories[i].meta
        name = meta.get("motor") if meta.get("source") == "bam" else None
        bam = bam_motor(name) if isinstance(name, str) else None
        if bam is not None:
            return servo.motor_spec(BAM_MOTORS[bam]).backdriven
    return None


def backdriven_plan(ds: Dataset, train: Sequence[int], effects: Sequence[str], mode: str
                    ) -> tuple[frozenset, dict[str, float] | None]:
    """How identification treats the torque-off law: (its parameters held at their null in the
    fit, the values it is set to after the fit or None).

    Training logs with the torque off, mode "fit": its Coulomb and viscous are fitted on top of
    the gear friction's own back-driven level (share ``gear`` held at 1: that level is the gear
    friction's fitted back-driven share, free in identify's "free" family). No training log with
    the torque off (nothing to fit it on): held at its null in the fit (it changes no torque-on
    log) and, when the servo catalogue knows the law, set to it after the fit as the back-driven
    joint's whole friction: the gear friction's back-driven level not kept (``gear`` 0: the
    torque-on fit holds that share at 1 and brakes the swing with its whole load friction;
    Rhoban lift_and_drop fold 64.0 mrad; the XL330 catalogue's law 40.9; the torque-on fit's own
    Coulomb + viscous as the law 168.8), nor the joint's own Coulomb and damping fitted with the
    torque on (``joint`` 0: there a firmware D term or the drive can stand in for them; STS3032's
    lift_and_drop fold fits 0.010 N m s/rad, its real swings want 0.0017: 188.8 -> 46.9 mrad;
    Rhoban's fold 40.9 -> 42.3, its joint damping 0.0019; bench/RESULTS.md gap-real17).
    "null": held at its null everywhere (the law absent, as before it existed). Nor set where
    the training logs' largest gravity torque is below the law's Coulomb level (the load cannot
    back-drive the gears: nothing swings, and the law only stops the arm's coasting at the
    release sooner than the real one: Pham's 4 g arm, 0.004 N m, lift_and_drop fold 3.4 -> 8.3
    mrad with it; Rhoban's 0.45 N m). The rest breakaway ``gap.rest_friction`` scans on the
    torque-on logs is not reduced by the law's Coulomb level (it acts with the torque on too)."""
    if BACKDRIVEN not in effects:
        return frozenset(), None
    if mode == "null":
        return BACKDRIVEN_PARAMS, None
    if torque_off_seen(ds, train):
        return frozenset({(BACKDRIVEN, "gear"), (BACKDRIVEN, "joint")}), None
    law = catalogue_backdriven(ds, train)
    if law is None:
        return BACKDRIVEN_PARAMS, None
    from lowcostdex.gap.rest_friction import gravity_torque

    if not np.max(gravity_torque(ds, train)) > law[0]:
        return BACKDRIVEN_PARAMS, None  # a load too light to back-drive the gears: no swing
    return BACKDRIVEN_PARAMS, {"coulomb": law[0], "viscous": law[1], "gear": 0.0, "joint": 0.0}


def set_backdriven(effects: list[AppliedEffect], values: dict[str, float] | None,
                   notes: list[str]) -> list[AppliedEffect]:
    """``effects`` with the torque-off law set to ``values`` (``backdriven_plan``'s after the
    fit; None: unchanged), saying so in ``notes``."""
    if not values:
        return effects
    notes.append("no training log has the torque off: the back-driven gears' friction is the "
                 f"servo catalogue's Coulomb {values['coulomb']:.3g} N m + viscous "
                 f"{values['viscous']:.3g} N m s/rad (MotorSpec.backdriven), the gear friction's "
                 "load-dependent level and the joint's own torque-on Coulomb and damping not kept "
                 "with the torque off")
    return [AppliedEffect(e.name, e.joints, {**e.values, **{
        k: np.full(len(e.joints), v) for k, v in values.items()}}) if e.name == BACKDRIVEN else e
        for e in effects]


def peak_speed(ds: Dataset, logs: Sequence[int]) -> float:
    """Largest |joint speed| [rad/s] over ``logs``, differentiated from the measured positions
    (central differences on each log's own sample times; 0 for no logs)."""
    out = 0.0
    for i in logs:
        tr = ds.trajectories[i]
        if len(tr.time) >= 2:
            out = max(out, float(np.max(np.abs(np.gradient(tr.qpos, tr.time, axis=0)))))
    return out


def faster_than_training(ds: Dataset, train: Sequence[int], test: Sequence[int],
                         margin: float = SPEED_MARGIN) -> dict[int, float]:
    """{held-out log: its peak speed [rad/s]} for the ``test`` logs whose peak speed exceeds
    ``margin`` times the fastest ``train`` log's (``SPEED_MARGIN``)."""
    top = peak_speed(ds, train)
    speeds = {int(i): peak_speed(ds, [i]) for i in test}
    return {i: v for i, v in speeds.items() if v > margin * top}


def type_folds(ds: Dataset, train: Sequence[int]
               ) -> list[tuple[str, tuple[int, ...], tuple[int, ...]]] | None:
    """Leave-one-trajectory-type-out folds of the training logs by their ``trajectory`` header:
    [(type left out, logs fitted, logs validated)], or None when a log lacks the header or
    fewer than two types are present."""
    kinds = [ds.trajectories[i].meta.get("trajectory") for i in train]
    if any(k is None for k in kinds) or len(set(kinds)) < 2:
        return None
    return [(str(k), tuple(i for i, x in zip(train, kinds, strict=True) if x != k),
             tuple(i for i, x in zip(train, kinds, strict=True) if x == k))
            for k in sorted(set(kinds), key=str)]


def inner_split(ds: Dataset, train: Sequence[int]
                ) -> tuple[str, tuple[int, ...], tuple[int, ...]] | None:
    """Split the training logs for an inner validation by their headers alone.

    The first of ``INNER_FIELDS`` that every training log's header gives and that takes two
    or more values among them; the logs at its smallest value are validated on, the others
    fitted (the larger gains and loads excite saturation and stick-slip most, so they are the
    ones to fit). Measured both ways on Rhoban XL330 (fit kp 100 and validate on kp 400, or the
    reverse): the fits on kp 100 alone extrapolated worst (held out 72-110 mrad against 42-55
    fitted on kp 400), so the direction was chosen after seeing held-out numbers, 2026-11-26.
    Returns (field, fit logs, validation logs), or None when no field splits.
    """
    for key in INNER_FIELDS:
        vals = [ds.trajectories[i].meta.get(key) for i in train]
        if any(v is None for v in vals) or len(set(vals)) < 2:
            continue
        low = min(vals)
        return (key, tuple(i for i, v in zip(train, vals, strict=True) if v != low),
                tuple(i for i, v in zip(train, vals, strict=True) if v == low))
    return None
