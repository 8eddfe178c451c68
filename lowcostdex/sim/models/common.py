"""Shared pieces of the MJCF builders: physics options, orientation helpers, materials."""

from __future__ import annotations

import math

import mujoco
import numpy as np

TIMESTEP = 0.0025  # [s] ROBEL's D'Claw timestep

# Collision classes: geoms in group 3 collide; group 1 is visual only.
GROUP_VISUAL, GROUP_COLLISION = 1, 3


def new_spec(name: str, timestep: float = TIMESTEP) -> mujoco.MjSpec:
    """An empty spec with lowcostdex's solver settings.

    Every scene builder (D'Claw, Allegro, servo bench) starts here. implicitfast integrates the servos' back-EMF damping stably at 2.5 ms; Newton with an
    elliptic cone keeps fingertip contacts from creeping.
    """
    spec = mujoco.MjSpec()
    spec.modelname = name
    spec.option.timestep = timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.solver = mujoco.mjtSolver.mjSOL_NEWTON
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.iterations = 50
    spec.option.ls_iterations = 20
    # One no-slip pass makes dry friction (joint frictionloss, contacts) hold instead of creeping:
    # without it a servo resting against Coulomb friction drifts to its goal within seconds.
    spec.option.noslip_iterations = 1
    spec.compiler.degree = False
    spec.visual.global_.offwidth = 640
    spec.visual.global_.offheight = 480
    spec.worldbody.add_light(pos=[0, 0, 1.5], dir=[0, 0, -1], diffuse=[0.8, 0.8, 0.8])
    return spec


def quat_euler(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> list[float]:
    """Quaternion (w, x, y, z) of intrinsic XYZ Euler angles [rad]."""
    q = np.zeros(4)
    mujoco.mju_euler2Quat(q, np.array([x, y, z], dtype=float), "XYZ")
    return q.tolist()


def quat_axis_angle(axis: tuple[float, float, float], angle: float) -> list[float]:
    """Quaternion (w, x, y, z) rotating by ``angle`` [rad] about ``axis``."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    return [math.cos(angle / 2), *(math.sin(angle / 2) * a)]


def add_floor(spec: mujoco.MjSpec, size: float = 0.5) -> None:
    spec.worldbody.add_geom(
        name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[size, size, 0.01],
        rgba=[0.85, 0.85, 0.8, 1], group=GROUP_COLLISION,
    )


def visual_only(geom: mujoco.MjsGeom) -> mujoco.MjsGeom:
    """Make a geom visual only (no contacts, no mass)."""
    geom.contype = 0
    geom.conaffinity = 0
    geom.group = GROUP_VISUAL
    geom.density = 0
    return geom
