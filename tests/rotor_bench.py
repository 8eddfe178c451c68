"""A frictionless rotor written in plain MJCF (a motor actuator on one hinge, no gravity), the
truth side of the friction-effect tests: with a constant torque and one friction effect applied
by the project's Plant, its spin-downs and breakaways have closed-form answers (I w0 / F, ...)
that the tests write out themselves. Shared by test_coulomb_asymmetry and
test_gap_stribeck_fallback."""
from __future__ import annotations

import mujoco
import numpy as np

from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.plant import Plant

INERTIA = 0.01  # kg m^2 (armature)
DT = 0.001      # s

XML = f"""<mujoco model="rotor">
<compiler angle="radian"/>
<option timestep="{DT}" integrator="implicitfast" gravity="0 0 0"/>
<worldbody><body name="rotor">
<joint name="q" type="hinge" axis="0 0 1" armature="{INERTIA}"/>
<geom type="sphere" size="0.001" mass="1e-6" contype="0" conaffinity="0"/>
</body></worldbody>
<actuator><motor name="q" joint="q" ctrlrange="-1 1" ctrllimited="true"/></actuator>
</mujoco>
"""


def run(eff: AppliedEffect, torque: float, w0: float, seconds: float) -> np.ndarray:
    """Angle [rad] and speed [rad/s] every step (shape (seconds / DT, 2)) from rest at 0 (or
    spinning at w0) under a constant torque [N m]."""
    plant = Plant(mujoco.MjModel.from_xml_string(XML), [eff])
    plant.reset(qpos=np.zeros(1), qvel=np.array([w0]), ctrl=np.array([torque]))
    out = []
    for _ in range(int(round(seconds / DT))):
        plant.step(np.array([torque]), 1)
        out.append((plant.qpos[0], plant.qvel[0]))
    return np.array(out)
