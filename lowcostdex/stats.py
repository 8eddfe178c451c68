"""Small statistics for reporting rates measured from a finite number of episodes."""

from __future__ import annotations

import math


def wilson_interval(successes: int, n: int, z: float = 1.959963984540054) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % by default).

    Unlike the normal approximation it stays inside [0, 1] and is not empty at 0/n or n/n,
    which is where a policy evaluated on 10 episodes often sits.

    Args:
      successes: successful episodes, 0 <= successes <= n.
      n: episodes (> 0).
      z: standard-normal quantile of the two-sided level.

    Returns:
      (low, high), the interval's ends as fractions.
    """
    if n <= 0:
        raise ValueError(f"n={n!r}: need at least one episode")
    if not 0 <= successes <= n:
        raise ValueError(f"successes={successes!r} is outside [0, n={n}]")
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == n else min(1.0, centre + half)
    return low, high


def rate_text(successes: int, n: int) -> str:
    """``"0.70 (7/10; 95 % CI 0.40-0.89)"``; ``"n/a (not evaluated)"`` when n == 0."""
    if n <= 0:
        return "n/a (not evaluated)"
    low, high = wilson_interval(successes, n)
    return f"{successes / n:.2f} ({successes}/{n}; 95 % CI {low:.2f}-{high:.2f})"
