"""Discounted returns and generalised advantage estimation (GAE) for one trajectory.

Pure numpy functions on float64 arrays. Termination and time-limit truncation stay separate:
the caller passes ``last_value = 0`` for a terminated trajectory and ``V(s_T)`` for a truncated
one (the bootstrap that a single ``done`` flag would lose).
"""

from __future__ import annotations

import numpy as np


def discount_cumsum(x: np.ndarray, discount: float) -> np.ndarray:
    """``y[t] = sum_k discount**k * x[t + k]`` along a (T,) array."""
    x = np.asarray(x, dtype=np.float64)
    y = np.empty_like(x)
    running = 0.0
    for t in range(x.shape[0] - 1, -1, -1):
        running = x[t] + discount * running
        y[t] = running
    return y


def discounted_returns(rewards: np.ndarray, gamma: float, last_value: float = 0.0) -> np.ndarray:
    """Reward-to-go ``R_t = sum_{k<T-t} gamma^k r_{t+k} + gamma^(T-t) * last_value``.

    Args:
      rewards: (T,) rewards r_0..r_{T-1}.
      gamma: discount factor in [0, 1].
      last_value: value of the state after the last step: 0 if the episode terminated, the
        baseline's V(s_T) if it was truncated by the time limit.

    Returns:
      (T,) returns.
    """
    r = np.asarray(rewards, dtype=np.float64).copy()
    if r.size:
        r[-1] += gamma * last_value
    return discount_cumsum(r, gamma)


def gae(
    rewards: np.ndarray, values: np.ndarray, last_value: float, gamma: float, lam: float
) -> np.ndarray:
    """Generalised advantage estimates (Schulman et al. 2016).

    ``delta_t = r_t + gamma * V_{t+1} - V_t`` with ``V_T = last_value``, and
    ``A_t = sum_k (gamma * lam)^k delta_{t+k}``. ``lam = 1`` gives returns minus values;
    ``lam = 0`` gives one-step TD errors.

    Args:
      rewards: (T,) rewards.
      values: (T,) baseline values V(s_t).
      last_value: V(s_T): 0 if terminated, the baseline's value if truncated.
      gamma: discount in [0, 1].
      lam: GAE lambda in [0, 1].

    Returns:
      (T,) advantages.
    """
    r = np.asarray(rewards, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64)
    if r.shape != v.shape:
        raise ValueError(f"rewards {r.shape} and values {v.shape} must have the same shape")
    v_next = np.append(v[1:], last_value)
    deltas = r + gamma * v_next - v
    return discount_cumsum(deltas, gamma * lam)


def whiten(x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """``(x - mean) / (std + eps)`` over the whole array (mjrl's advantage normalisation)."""
    x = np.asarray(x, dtype=np.float64)
    return (x - x.mean()) / (x.std() + eps)
