"""Select episodes whose open-loop replay is chaotic: they cannot judge a model.

A torque-driven joint (a ``motor`` actuator fed the torques a host PD wrote) replayed open loop
has no feedback to pull it back: in a pose where gravity tips it over (a finger curled up), a
difference far below what a log resolves grows exponentially, and after a second or two the
replay's error is chaos, not model error. Seen on an Allegro-class finger with a 9 ms read delay
(tests/gap_truth_sim6.py, session 19): the true 9 ms latency lowered two select episodes' RMSE
29 -> 3 and 32 -> 6 mrad, but the third started curled (error e-folding ~0.45 s) and went
185 -> 280 mrad; its squared error outweighed the rest and the right effect was refused.

The test (``chaotic``): replay each select episode with the nominal model twice, the second with
every goal ``SHIFT`` physics steps later (0.1 ms at a 2 ms step: far below any log's timestamp
resolution). A regular replay ends within a noise floor or two of itself; a chaotic one ends many
floors away. Measured on sim6's logs (floor 0.44 mrad): regular episodes 0.04-0.76 mrad over the
last quarter (up to 1.7 floors), the two chaotic ones 8.8 and 31.8 mrad (20 and 72 floors). Over
every episode of the sim2-sim6 truth cases (session 19) the largest regular value was 9.4 floors (a
Coulomb stick-slip on a motor, sim4), and only read_delay_9ms_torque's chaotic select episode (72)
crossed ``FLOORS``. Episodes above it are left out of the select split's score, as long as one
episode is left; the report says how many.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from lowcostdex.gap.dataset import Dataset, Split, Window

__all__ = ["FLOORS", "SHIFT", "chaotic", "divergence", "scored_select"]

SHIFT = 0.05  # physics steps: the goal shift of the probe replay
FLOORS = 20.0  # an episode whose probe replay ends this many noise floors away is chaotic

Run = Callable[..., tuple[list[list[np.ndarray]], np.ndarray | None]]  # ``Replayer.run``


def divergence(a: np.ndarray, b: np.ndarray) -> float:
    """RMS [rad] over the last quarter of two replays (n, nj) of one window (at least 1 sample)
    of the largest per-joint difference at each sample."""
    d = np.max(np.abs(np.asarray(a) - np.asarray(b)), axis=1)
    tail = d[-max(1, len(d) // 4):]
    return float(np.sqrt(np.mean(tail ** 2)))


def chaotic(run: Run, ds: Dataset, eps: Sequence[Window], pred: Sequence[np.ndarray],
            floor_rms: float) -> list[bool]:
    """Per episode of ``eps``: is its open-loop replay chaotic (``divergence`` of ``pred``, the
    nominal model's replay, from a replay with the goals ``SHIFT`` steps late, above ``FLOORS``
    x ``floor_rms`` [rad])? ``run`` is ``Replayer.run``."""
    if not eps:
        return []
    shifted = run(eps, [[]], goal_shift=SHIFT * ds.timestep)[0][0]
    limit = FLOORS * max(floor_rms, 1e-9)
    return [divergence(p, s) > limit for p, s in zip(pred, shifted, strict=True)]


def scored_select(run: Run, ds: Dataset, eps: Sequence[Window], split: Split,
                  pred: Sequence[np.ndarray], floor_mse: float
                  ) -> tuple[Split, list[Window]]:
    """``split`` with its chaotic select episodes moved to ``unscored`` (when at least one
    regular select episode is left), and the select windows that stay. ``pred``: the nominal
    replay of every episode of ``eps``; ``floor_mse`` [rad^2]: the reading noise floor."""
    sel = [eps[i] for i in split.select]
    bad = chaotic(run, ds, sel, [pred[i] for i in split.select], float(np.sqrt(floor_mse)))
    if not any(bad) or all(bad):
        return split, sel
    keep = tuple(i for i, b in zip(split.select, bad, strict=True) if not b)
    out = replace(split, select=keep,
                  unscored=tuple(i for i, b in zip(split.select, bad, strict=True) if b))
    return out, [eps[i] for i in keep]
