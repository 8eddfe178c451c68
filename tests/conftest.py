"""Shared fixtures: small inline models so tests need no files."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from lowcostdex.sim import servo

HINGE_XML = """
<mujoco>
  <option timestep="0.0025" integrator="implicitfast" noslip_iterations="1"/>
  <worldbody>
    <body name="arm">
      <joint name="j" type="hinge" axis="0 1 0" damping="0.0"/>
      <geom type="capsule" fromto="0 0 0 0.1 0 0" size="0.01" mass="0.1"/>
    </body>
  </worldbody>
</mujoco>
"""


def hinge_spec(gravity: bool = False) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_string(HINGE_XML)
    if not gravity:
        spec.option.gravity = [0, 0, 0]
    return spec


def hinge_servo_model(motor: str = "XM430-W350", gains: servo.ServoGains | None = None,
                      gravity: bool = False, thermal: bool = True) -> mujoco.MjModel:
    spec = hinge_spec(gravity)
    m = servo.motor_spec(motor)
    servo.add_servo(spec, "j", m, gains or servo.ServoGains(position_p=m.default_p),
                    thermal=thermal)
    return spec.compile()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


@pytest.fixture
def one_torch_thread():
    """Small networks: one thread is fastest and immune to a busy machine (the caller's thread
    count is restored). Files use it with ``pytestmark = pytest.mark.usefixtures(...)``."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def pytest_addoption(parser):
    group = parser.getgroup("lowcostdex hardware")
    group.addoption("--dxl-port", default=None,
                    help="serial port of a real D'Claw for the `hardware` acceptance tests")
    group.addoption("--can-channel", default=None,
                    help="CAN channel of a real Allegro hand for the `hardware` acceptance tests")
