"""lowcostdex.transfer.tilt: a mounting tilt written into a plain MJCF in this test (a base body
holding a two-hinge finger under weak position servos, gravity pulling it) is recovered from a
noisy joint trace, and none is named on the untilted model. Truth: the tilt this test writes."""

import mujoco
import numpy as np

from lowcostdex.transfer.tilt import fit_tilt, tilt_body, tilt_quat

XML = """
<mujoco>
  <option timestep="0.002" gravity="0 0 -9.81"/>
  <worldbody>
    <body name="base" pos="0 0 0.5">
      <body name="link">
        <joint name="j_y" type="hinge" axis="0 1 0" damping="0.05"/>
        <joint name="j_x" type="hinge" axis="1 0 0" damping="0.05"/>
        <geom type="capsule" fromto="0 0 0 0.05 0 -0.1" size="0.01" mass="0.1"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position joint="j_y" kp="0.1"/>
    <position joint="j_x" kp="0.1"/>
  </actuator>
</mujoco>
"""

GOALS = np.array([[0.0, 0.0], [0.3, -0.2], [-0.2, 0.3], [0.1, 0.1]])


def simulate(angles, steps_per_goal=250):
    spec = mujoco.MjSpec.from_string(XML)
    tilt_body(spec, "base", angles)
    model = spec.compile()
    data = mujoco.MjData(model)
    trace = []
    for goal in GOALS:
        data.ctrl[:] = goal
        for i in range(steps_per_goal):
            mujoco.mj_step(model, data)
            if i % 10 == 9:
                trace.append(data.qpos.copy())
    return np.asarray(trace)


def test_tilt_quat_is_the_rotation_written_out():
    a = 0.04
    np.testing.assert_allclose(tilt_quat([a, 0.0]), [np.cos(a / 2), np.sin(a / 2), 0, 0])
    np.testing.assert_allclose(tilt_quat([0.0, 0.0]), [1, 0, 0, 0])


def test_fit_recovers_a_written_tilt_and_names_none_on_the_nominal():
    rng = np.random.default_rng(0)
    truth = np.array([0.05, -0.03])  # rad: ~3 and ~2 degrees
    noise = 1e-3
    tilted = simulate(truth) + rng.normal(0, noise, (len(simulate(truth)), 2))
    fit = fit_tilt(simulate, tilted)
    assert fit.named
    for k in range(2):
        lo, hi = fit.intervals[k]
        assert lo <= truth[k] <= hi, (k, fit)
    assert fit.rms_after < 2 * noise < fit.rms_before

    nominal = simulate(np.zeros(2)) + rng.normal(0, noise, tilted.shape)
    none = fit_tilt(simulate, nominal)
    assert not none.named, none


def test_an_angle_the_trace_does_not_see_is_never_named():
    """A trace blind to one angle (a finger off the spoke: no contact) gives that angle no
    interval, so no tilt is named from it (a zero Jacobian must not read as a sharp estimate)."""
    t = np.linspace(0, 1, 50)

    def blind(angles):
        return np.sin(t)  # moves with neither angle

    fit = fit_tilt(blind, np.sin(t) + 0.01)
    assert not fit.named
    assert np.all(np.isinf(fit.intervals[:, 1]))
