"""Measuring the gain honestly: held-out error before and after, bootstrap interval, floors.

The unit of resampling is the held-out episode (whole logs or chunks of long logs), never the
sample: residuals within an episode are strongly autocorrelated (04-sysid.md section 4.4).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Gain:
    """Held-out error before/after and the gain with its bootstrap interval.

    Attributes:
      baseline_rmse / extended_rmse: pooled RMSE over test episodes [rad].
      baseline_mae / extended_mae: pooled MAE [rad].
      absolute: baseline_rmse - extended_rmse [rad].
      relative: absolute / baseline_rmse.
      ci95: 95 % percentile-bootstrap interval of ``absolute`` over test episodes [rad]
        (degenerate with one test episode: resampling one episode gives it back; ``to_dict``
        writes null and the report says why).
      relative_ci95: the same for ``relative``.
      noise_floor: RMS of read noise and quantization [rad].
      reducible_explained: (MSE_b - MSE_e) / (MSE_b - floor^2), None when nothing is reducible.
      episodes: number of test episodes.
    """

    baseline_rmse: float
    extended_rmse: float
    baseline_mae: float
    extended_mae: float
    absolute: float
    relative: float
    ci95: tuple[float, float]
    relative_ci95: tuple[float, float]
    noise_floor: float
    reducible_explained: float | None
    episodes: int

    def to_dict(self) -> dict:
        return {
            "baseline_rmse": self.baseline_rmse, "extended_rmse": self.extended_rmse,
            "baseline_mae": self.baseline_mae, "extended_mae": self.extended_mae,
            "absolute": self.absolute, "relative": self.relative,
            "ci95": list(self.ci95) if self.episodes > 1 else None,
            "relative_ci95": list(self.relative_ci95) if self.episodes > 1 else None,
            "noise_floor": self.noise_floor,
            "reducible_explained": self.reducible_explained, "episodes": self.episodes,
        }


def bootstrap_ci(stat, k: int, rng: np.random.Generator, n_boot: int = 2000,
                 level: float = 0.95) -> tuple[float, float]:
    """Percentile interval of ``stat(idx)`` over resamples of ``k`` units with replacement.

    Args:
      stat: function of an (n_boot, k) index array returning (n_boot,) statistics.
      k: number of units (episodes).
      rng: seeded generator.
      n_boot: resamples.
      level: coverage.
    """
    idx = rng.integers(0, k, size=(n_boot, k))
    vals = np.asarray(stat(idx), float)
    a = 100 * (1 - level) / 2
    return float(np.percentile(vals, a)), float(np.percentile(vals, 100 - a))


def gain_with_ci(sse_b: np.ndarray, sse_e: np.ndarray, n: np.ndarray, sae_b: np.ndarray,
                 sae_e: np.ndarray, floor_mse: float, rng: np.random.Generator,
                 n_boot: int = 2000) -> Gain:
    """Paired gain over episodes (per-episode sums of squared / absolute errors and counts)."""
    sse_b, sse_e, n = (np.asarray(x, float) for x in (sse_b, sse_e, n))
    rb = math.sqrt(sse_b.sum() / n.sum())
    re_ = math.sqrt(sse_e.sum() / n.sum())

    def absolute(idx):
        nn = n[idx].sum(1)
        return np.sqrt(sse_b[idx].sum(1) / nn) - np.sqrt(sse_e[idx].sum(1) / nn)

    def relative(idx):
        return 1.0 - np.sqrt(sse_e[idx].sum(1) / sse_b[idx].sum(1))

    k = len(n)
    ci = bootstrap_ci(absolute, k, rng, n_boot)
    rci = bootstrap_ci(relative, k, rng, n_boot)
    mse_b, mse_e = rb * rb, re_ * re_
    reducible = mse_b - floor_mse
    frac = (mse_b - mse_e) / reducible if reducible > 0.05 * mse_b else None
    return Gain(rb, re_, float(np.sum(sae_b) / n.sum()), float(np.sum(sae_e) / n.sum()),
                rb - re_, (rb - re_) / rb if rb > 0 else 0.0, ci, rci, math.sqrt(floor_mse),
                frac, k)


def episode_errors(ds, eps: Sequence, pred: Sequence[np.ndarray], joints: Sequence[str]) -> dict:
    """Held-out RMSE/MAE pooled, per joint and per episode [rad]."""
    rs = [ds.trajectories[w.traj].qpos[w.start:w.stop] - p for w, p in zip(eps, pred,
                                                                             strict=True)]
    allr = np.concatenate(rs)
    return {
        "heldout_rmse": float(np.sqrt(np.mean(allr ** 2))),
        "heldout_mae": float(np.mean(np.abs(allr))),
        "per_joint_rmse": dict(zip(joints, np.sqrt(np.mean(allr ** 2, 0)).tolist(),
                                   strict=True)),
        "per_joint_mae": dict(zip(joints, np.mean(np.abs(allr), 0).tolist(), strict=True)),
        "per_episode_rmse": [float(np.sqrt(np.mean(r ** 2))) for r in rs],
        "per_episode_mae": [float(np.mean(np.abs(r))) for r in rs],
    }
