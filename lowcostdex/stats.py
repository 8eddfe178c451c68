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


def median_interval(values: list[float] | tuple[float, ...], level: float = 0.95
                    ) -> tuple[float, float, float, float]:
    """The median and its distribution-free interval from order statistics.

    The interval is ``[x_(k), x_(n+1-k)]`` of the sorted values with the largest rank ``k``
    whose coverage ``1 - 2 P(Binomial(n, 1/2) <= k - 1)`` is still at least ``level`` (no
    assumption on the distribution; the values must be independent draws). Below 6 values no
    rank reaches 95 %: the interval is then the range ``[x_(1), x_(n)]`` and the coverage
    returned says what it is (75 % for 3 values, 0 for one).

    Args:
      values: n >= 1 finite numbers (e.g. final errors [rad]).
      level: the coverage wanted, in (0, 1).

    Returns:
      (median, low, high, coverage): coverage is the interval's exact coverage (>= level
      when n is large enough, else that of the range).
    """
    xs = sorted(float(v) for v in values)
    n = len(xs)
    if n == 0:
        raise ValueError("median_interval: need at least one value")
    if not all(math.isfinite(v) for v in xs):
        raise ValueError("median_interval: the values must be finite")
    if not 0.0 < level < 1.0:
        raise ValueError(f"level={level!r} must be in (0, 1)")
    median = xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2])
    tail = 0.5 ** n  # P(B <= k - 1) for the current rank k, B ~ Binomial(n, 1/2)
    k = 1
    while k < (n + 1) // 2:
        nxt = tail + math.comb(n, k) / 2.0 ** n  # P(B <= k) for rank k + 1
        if 1.0 - 2.0 * nxt < level:
            break
        tail, k = nxt, k + 1
    coverage = 1.0 - 2.0 * tail
    return median, xs[k - 1], xs[n - k], coverage
