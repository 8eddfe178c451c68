"""A finger base's mounting tilt fitted from a recorded trace (issue 14: robot C's thumb-base tilt,
invisible in a finger's servo log, seen by a valve-turning log). The edit itself (a small rotation
multiplied into the body's ``quat``) is ``sim.models.dclaw_edit.tilt_body``, re-exported here.

``fit_tilt`` is the least-squares fit of the small angles (rotations about the base frame's x and
y axes) that make the simulated trace match the recorded one, by Gauss-Newton with forward
differences, with 95 % intervals from the residual's scatter and the Jacobian. A tilt is named only
when an interval excludes 0. The caller supplies ``simulate(angles) -> trace`` (e.g. the logged
valve goals replayed in the edited model); the fit never reads a robot's definition.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lowcostdex.sim.models.dclaw_edit import tilt_body, tilt_quat

__all__ = ["TiltFit", "fit_tilt", "tilt_body", "tilt_quat"]


@dataclass(frozen=True)
class TiltFit:
    angles: np.ndarray          # [rad], about the base frame's x and y
    intervals: np.ndarray       # (2, 2) 95 % intervals [rad]
    rms_before: float           # RMS residual at zero tilt
    rms_after: float            # RMS residual at the fit

    @property
    def named(self) -> bool:
        """A tilt is named when some angle's interval excludes 0."""
        return bool(np.any((self.intervals[:, 0] > 0) | (self.intervals[:, 1] < 0)))


def fit_tilt(simulate: Callable[[np.ndarray], np.ndarray], observed: np.ndarray,
             iterations: int = 8, step: float = 1e-3, limit: float = 0.2,
             max_step: float = 0.03) -> TiltFit:
    """Gauss-Newton fit of the two small tilt angles (|angle| <= limit, each step at most
    ``max_step`` [rad]: contact makes the trace only piecewise smooth in the tilt) minimizing the
    simulated trace's squared difference from ``observed``. An angle the trace does not move
    (no contact, a zero Jacobian column) gets an unbounded interval: it is never named."""
    observed = np.asarray(observed, float).ravel()

    def residual(a: np.ndarray) -> np.ndarray:
        return np.asarray(simulate(a), float).ravel() - observed

    a = np.zeros(2)
    r = residual(a)
    rms_before = float(np.sqrt(np.mean(r ** 2)))
    jac = np.zeros((r.size, 2))
    for _ in range(iterations):
        for k in range(2):
            d = np.zeros(2)
            d[k] = step
            jac[:, k] = (residual(a + d) - r) / step
        delta, *_ = np.linalg.lstsq(jac, -r, rcond=None)
        if np.max(np.abs(delta)) > max_step:
            delta = delta * (max_step / np.max(np.abs(delta)))
        trial = np.clip(a + delta, -limit, limit)
        r_trial = residual(trial)
        if np.sum(r_trial ** 2) >= np.sum(r ** 2):
            trial = np.clip(a + 0.5 * delta, -limit, limit)
            r_trial = residual(trial)
            if np.sum(r_trial ** 2) >= np.sum(r ** 2):
                break
        a, r = trial, r_trial
        if np.max(np.abs(delta)) < 1e-6:
            break
    for k in range(2):  # the Jacobian at the fit
        d = np.zeros(2)
        d[k] = step
        jac[:, k] = (residual(a + d) - r) / step
    dof = max(r.size - 2, 1)
    sigma2 = float(np.sum(r ** 2)) / dof
    info = jac.T @ jac
    if np.linalg.cond(info) > 1e12:
        half = np.full(2, np.inf)
    else:
        half = 1.96 * np.sqrt(np.maximum(np.diag(sigma2 * np.linalg.inv(info)), 0.0))
    intervals = np.stack([a - half, a + half], axis=1)
    return TiltFit(a, intervals, rms_before, float(np.sqrt(np.mean(r ** 2))))
