"""Command safety: reject non-finite goals, clip to joint limits and to a per-step motion bound.

Pure functions on arrays; the Robot applies them to every goal before it reaches the bus, so a
policy, a reset procedure and a demo teacher all pass through the same gate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lowcostdex.hardware.bus import CommandError


class UnsafeCommand(CommandError):
    """A command was rejected (NaN/inf entries, wrong shape, no valid present position);
    nothing was sent."""


@dataclass(frozen=True)
class ClipReport:
    """What ``clip_goal`` changed.

    Attributes:
      goal: the goal actually allowed (n,) [rad].
      limit_clipped: entries moved by the joint limits (n,) bool.
      motion_clipped: entries moved by the motion bound (n,) bool.
    """

    goal: np.ndarray
    limit_clipped: np.ndarray
    motion_clipped: np.ndarray


def check_finite(goal: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    """The goal as a float array (n,); raises UnsafeCommand naming the non-finite joints."""
    try:
        if np.asarray(goal).dtype.kind == "b":  # a joint mask, not goals (sent as 0/1 rad)
            raise TypeError
        g = np.asarray(goal, dtype=float)
    except (TypeError, ValueError):
        raise UnsafeCommand(f"goal {goal!r:.60} is not {len(names)} numbers [rad] for joints "
                            f"{', '.join(names)}; nothing sent") from None
    if g.shape != (len(names),):
        raise UnsafeCommand(f"goal has shape {g.shape}, expected ({len(names)},) for joints "
                            f"{', '.join(names)}; nothing sent")
    bad = ~np.isfinite(g)
    if np.any(bad):
        listed = ", ".join(f"{n}={v}" for n, v, b in zip(names, g, bad, strict=True) if b)
        raise UnsafeCommand(f"non-finite goal for {listed}; nothing sent")
    return g


UNIT_MARGIN = 2 * math.pi
"""[rad] A goal more than a full turn outside its joint's range is not a goal in rad (degrees,
ticks): refused, not clipped. Within it, a goal beyond a limit is clipped to it (a policy, a
test's wild goals of +-4-5 rad, or a person asking for the limit). On the D'Claw this refuses
a degree value above about 7-8 (e.g. 30 deg); smaller degree values cannot be told from rad."""


def check_units(goal: np.ndarray, low: np.ndarray, high: np.ndarray,
                names: tuple[str, ...]) -> None:
    """Raise UnsafeCommand when a goal lies more than ``UNIT_MARGIN`` outside its joint's
    limits [rad]: 90 for a 90 deg goal would otherwise be clipped silently to the limit."""
    far = (goal < low - UNIT_MARGIN) | (goal > high + UNIT_MARGIN)
    if np.any(far):
        listed = ", ".join(f"{n}={v:g} (limits {lo:.3g}..{hi:.3g})" for n, v, lo, hi, f
                           in zip(names, goal, low, high, far, strict=True) if f)
        raise UnsafeCommand(f"goal far outside the joint limits: {listed}; goals are in rad "
                            "(degrees or ticks?); nothing sent")


def clip_goal(goal: np.ndarray, low: np.ndarray, high: np.ndarray, reference: np.ndarray,
              max_step: np.ndarray, present: np.ndarray | None = None,
              max_lead: np.ndarray | None = None) -> ClipReport:
    """Clip goals (n,) [rad] to ``reference +- max_step``, then (if given) to
    ``present +- max_lead``, then to ``[low, high]``.

    ``reference`` is the present position (stiff position servos, as ROBEL and LeRobot do) or
    the previous goal (a rate limit for soft, torque-driven joints whose position lags; the
    lead bound then keeps the goal from winding up against an obstacle).

    The limits win over the motion bound: no goal outside ``[low, high]`` ever leaves this
    function, even for a joint found outside its limits (its goal is the nearest limit).
    """
    stepped = np.clip(goal, reference - max_step, reference + max_step)
    if present is not None and max_lead is not None:
        stepped = np.clip(stepped, present - max_lead, present + max_lead)
    out = np.clip(stepped, low, high)
    return ClipReport(out, limit_clipped=out != stepped, motion_clipped=stepped != goal)
