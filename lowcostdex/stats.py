"""Small statistics for reporting rates measured from a finite number of episodes, and paired tests
of two policies on the same episodes (McNemar on success, Wilcoxon on final errors)."""

from __future__ import annotations

import math
from typing import Any


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


def paired_test(before: dict[str, Any], after: dict[str, Any]) -> tuple[int, int, float] | None:
    """Exact one-sided McNemar test on two policies' per-episode successes (``"solved"``) on
    the same held-out episodes: (episodes only ``after`` solved, only ``before`` solved, p that
    ``after`` solves more), a binomial test at 1/2 on the discordant episodes (p = 1 when there
    are none); None when either has no per-episode record or the records differ in length."""
    from scipy.stats import binomtest

    a, b = before.get("solved"), after.get("solved")
    if not a or not b or len(a) != len(b):
        return None
    only_after = sum(1 for x, y in zip(a, b, strict=True) if y and not x)
    only_before = sum(1 for x, y in zip(a, b, strict=True) if x and not y)
    n = only_after + only_before
    pvalue = binomtest(only_after, n, 0.5, alternative="greater").pvalue if n else 1.0
    return only_after, only_before, float(pvalue)


def paired_errors(before: dict[str, Any], after: dict[str, Any]
                  ) -> tuple[float, float, float] | None:
    """Two policies' final |goal error| (``"final_goal_errors"``) on the same held-out episodes:
    (median before, median after, p of the one-sided Wilcoxon signed-rank test that ``after``'s
    errors are smaller; zero differences dropped, p = 1 when all are zero); None when either
    has no per-episode record or the records differ in length."""
    import numpy as np
    from scipy.stats import wilcoxon

    a, b = before.get("final_goal_errors"), after.get("final_goal_errors")
    if not a or not b or len(a) != len(b):
        return None
    a, b = np.abs(np.asarray(a, float)), np.abs(np.asarray(b, float))
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return None
    if np.all(a == b):
        pvalue = 1.0
    else:
        pvalue = float(wilcoxon(b, a, alternative="less", zero_method="wilcox").pvalue)
    return float(np.median(a)), float(np.median(b)), pvalue
