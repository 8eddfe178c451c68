"""Goal signals a user drives their own rig with, for the user-rig truth cases
(tests/gap_user_leap.py, tests/gap_user_arm.py). Plain numpy: nothing from lowcostdex."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np


def goal_signal(style: str, n: int, rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray,
                rate: float, hold: tuple[float, float], f_max: float, amp: float,
                phase_mult: np.ndarray) -> np.ndarray:
    """(n, joints) goals [rad] at rows sent at ``rate`` [Hz] within [lo, hi] per joint:
    'steps' (random levels held ``hold`` s), 'chirp' (0.2 to ``f_max`` Hz sweeps of ``amp`` of
    each joint's half-range around mid-range, each joint's phase times ``phase_mult``) or
    'ramps' (slow triangles of 2-4 s periods over the middle 80 % of the range)."""
    k_joints = len(lo)
    if style == "steps":
        g = np.zeros((n, k_joints))
        k = 0
        while k < n:
            m = int(rng.uniform(*hold) * rate)
            g[k:k + m] = rng.uniform(lo, hi)
            k += m
        return g
    s = np.arange(n) / rate
    mid, half = (lo + hi) / 2, (hi - lo) / 2
    if style == "chirp":
        f = 0.2 + (f_max - 0.2) * s / s[-1]
        phase = 2 * np.pi * np.cumsum(f) / rate
        return mid + amp * half * np.sin(phase[:, None] * phase_mult
                                         + rng.uniform(0, 2 * np.pi, k_joints))
    if style != "ramps":
        raise ValueError(f"unknown goal style {style!r}; valid: 'steps', 'chirp', 'ramps'")
    period = rng.uniform(2.0, 4.0, k_joints)
    tri = 2 * np.abs((s[:, None] / period + rng.uniform(0, 1, k_joints)) % 1.0 - 0.5)
    return lo + (hi - lo) * (0.1 + 0.8 * tri)


def project_imports(path: str | Path) -> set[str]:
    """The lowcostdex modules the file at ``path`` imports, followed through the test-side
    modules beside it that it imports (a user rig's truth must come from outside the project)."""
    path = Path(path)
    tree = ast.parse(path.read_text())
    names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {str(n.module) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    found = {m for m in names if m.startswith("lowcostdex")}
    for m in names:
        beside = path.parent / f"{m}.py"
        if beside.is_file() and beside != path:
            found |= project_imports(beside)
    return found
