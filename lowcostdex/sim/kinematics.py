"""Finger kinematics of the lowcostdex hands, read from a compiled model: each finger's frame, link
lengths, forward kinematics and analytic inverse kinematics (D'Claw: 3 joints; Allegro index,
middle and ring: 4 joints with the last two coupled). Used by the virtual teachers
(``lowcostdex.teachers``) and the auto-reset (``lowcostdex.hardware.robot.reset``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

# ------------------------------------------------------------------------------------------------
# D'Claw finger kinematics


def _finger_frame(model: mujoco.MjModel, finger: str, links: int
                  ) -> tuple[np.ndarray, np.ndarray, list[float], Any]:
    """A lowcostdex finger's base frame in the world at qpos0 (origin (3,), rotation (3, 3)),
    the lengths [m] of its first ``links`` links (link k+1's offset along z) and its tip geom."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    link0 = model.body(f"{finger}_link0")
    lengths = [float(model.body(f"{finger}_link{k + 1}").pos[2]) for k in range(links)]
    return (data.xpos[link0.id].copy(), data.xmat[link0.id].reshape(3, 3).copy(), lengths,
            model.geom(f"{finger}_tip_geom"))


@dataclass(frozen=True)
class FingerGeometry:
    """One D'Claw finger, read from a compiled model.

    The top joint turns about y of the ``link0`` frame; the middle and bottom joints turn about x,
    ``l0`` and ``l0 + l1`` further along z; the tip point (centre of the fingertip's end sphere) is
    ``l2`` beyond the bottom joint.

    Attributes:
      origin: world position of the top joint (3,) [m].
      rot: world orientation of the ``link0`` frame at zero joint angles (3, 3).
      l0, l1, l2: top->middle, middle->bottom, bottom->tip-sphere-centre lengths [m].
      tip_radius: fingertip sphere radius [m].
    """

    origin: np.ndarray
    rot: np.ndarray
    l0: float
    l1: float
    l2: float
    tip_radius: float

    @classmethod
    def from_model(cls, model: mujoco.MjModel, finger: str) -> FingerGeometry:
        origin, rot, links, tip = _finger_frame(model, finger, 2)
        return cls(origin=origin, rot=rot, l0=links[0], l1=links[1],
                   l2=float(tip.pos[2] + tip.size[1]), tip_radius=float(tip.size[0]))

    def forward(self, q: np.ndarray) -> np.ndarray:
        """Tip-sphere centre (..., 3) [m] in the world for joint angles q (..., 3) [rad]."""
        a, m, b = q[..., 0], q[..., 1], q[..., 2]
        y = -(self.l1 * np.sin(m) + self.l2 * np.sin(m + b))
        z = self.l0 + self.l1 * np.cos(m) + self.l2 * np.cos(m + b)
        local = np.stack([z * np.sin(a), y, z * np.cos(a)], axis=-1)
        return self.origin + local @ self.rot.T

    def inverse(self, p: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
        """Joint angles (3,) [rad] putting the tip-sphere centre at world point p (3,) [m].

        The elbow solution with the bottom joint >= 0 (as in the reset pose); unreachable
        points give the nearest stretched pose; results are clipped to [low, high].
        """
        px, py, pz = self.rot.T @ (np.asarray(p, float) - self.origin)
        a = math.atan2(px, pz)
        u, w = -py, math.hypot(px, pz) - self.l0
        c = (u * u + w * w - self.l1**2 - self.l2**2) / (2 * self.l1 * self.l2)
        b = math.acos(min(1.0, max(-1.0, c)))
        m = math.atan2(u, w) - math.atan2(self.l2 * math.sin(b), self.l1 + self.l2 * math.cos(b))
        return np.clip(np.array([a, m, b]), low, high)


@dataclass(frozen=True)
class AllegroFingerGeometry:
    """One Allegro finger (index, middle or ring), read from a compiled model.

    Joint 0 turns about z of the ``link0`` frame (along the finger); joints 1-3 flex about y,
    ``l0``, ``l0 + l1``, ``l0 + l1 + l2`` along the flexed chain; the tip point (centre of the
    fingertip's end sphere) is ``l3`` beyond joint 3.

    Attributes:
      origin: world position of joint 0 (3,) [m].
      rot: world orientation of the ``link0`` frame at zero joint angles (3, 3).
      l0, l1, l2, l3: joint 0 -> 1 -> 2 -> 3 -> tip-sphere-centre lengths [m].
    """

    origin: np.ndarray
    rot: np.ndarray
    l0: float
    l1: float
    l2: float
    l3: float

    @classmethod
    def from_model(cls, model: mujoco.MjModel, finger: str) -> AllegroFingerGeometry:
        origin, rot, links, tip = _finger_frame(model, finger, 3)
        return cls(origin=origin, rot=rot, l0=links[0], l1=links[1], l2=links[2],
                   l3=float(tip.pos[2] + tip.size[1]))

    def _chain(self, j2: float, j3: float) -> complex:
        """Joint 1 -> tip in the flexion plane (real: along the finger, imag: flexed)."""
        return self.l1 + self.l2 * np.exp(1j * j2) + self.l3 * np.exp(1j * (j2 + j3))

    def forward(self, q: np.ndarray) -> np.ndarray:
        """Tip-sphere centre (3,) [m] in the world for joint angles q (4,) [rad]."""
        j0, j1, j2, j3 = (float(v) for v in q)
        v = self.l0 + self._chain(j2, j3) * np.exp(1j * j1)
        local = np.array([v.imag * math.cos(j0), v.imag * math.sin(j0), v.real])
        return self.origin + self.rot @ local

    def inverse(self, p: np.ndarray, low: np.ndarray, high: np.ndarray,
                coupling: float = 1.0) -> np.ndarray:
        """Joint angles (4,) [rad] putting the tip-sphere centre at world point p [m].

        The redundant distal joint follows ``j3 = coupling * j2``; unreachable points give the
        nearest pose along the chain; results are clipped to [low, high].
        """
        x, y, z = self.rot.T @ (np.asarray(p, float) - self.origin)
        j0 = math.atan2(y, x) if math.hypot(x, y) > 1e-9 else 0.0
        w = complex(z - self.l0, math.hypot(x, y))
        lo, hi = float(low[2]), float(high[2])
        if coupling > 0:
            lo, hi = max(lo, float(low[3]) / coupling), min(hi, float(high[3]) / coupling)

        def excess(j2: float) -> float:  # the chain shortens as it curls
            return abs(self._chain(j2, coupling * j2)) - abs(w)

        if excess(lo) <= 0:
            j2 = lo
        elif excess(hi) >= 0:
            j2 = hi
        else:
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if excess(mid) > 0 else (lo, mid)
            j2 = 0.5 * (lo + hi)
        j1 = math.atan2(w.imag, w.real) - float(np.angle(self._chain(j2, coupling * j2)))
        return np.clip(np.array([j0, j1, j2, coupling * j2]), low, high)
