"""``gain_error`` means one physical thing on every actuator kind: the position loop's
proportional gain (torque per rad of error) scaled, what damps and what integrates kept
(issue 11 item 1).

The truth of each case is a plain MuJoCo model written out here with the gain changed in its
XML (a user's actuator with kp x s: ``position`` kv kept, ``general`` gain and -kp bias,
MuJoCo's own ``dcmotor`` controller kp, ki and kd kept; a ``velocity`` actuator's kv, its only
gain; a ``motor``'s torque per command), stepped with ``mujoco.mj_step``; the project's plant
runs the nominal model with ``gain_error`` at s. They must move alike to round-off. Before
session 16 a dcmotor's gain_error scaled its P, I and D together (sim4 gain05_dcmotor: a
user's kp x0.5 fitted as 0.708 plus a mass error 1.41).

Also: a user's dcmotor written without a drive limit (``controller`` Vmax 0, MuJoCo's default:
unclamped) has no stall torque, so dry friction is still a candidate there (it was held at 0,
never named).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lowcostdex.errors import ConfigError
from lowcostdex.gap import fit as fitmod
from lowcostdex.sim import servo
from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.plant import Plant

# a pendulum under gravity (a tip mass 0.1 m below a horizontal hinge), 1 ms implicitfast
_RIG = """
<mujoco><option timestep="0.001" integrator="implicitfast"/>
  <worldbody><body pos="0 0 0.3"><joint name="j" axis="0 1 0" damping="0.02" armature="0.003"/>
    <geom type="sphere" pos="0 0 -0.1" size="0.02" mass="0.2"/></body></worldbody>
  <actuator>{act}</actuator>
</mujoco>"""

# per kind: the actuator as written with its proportional gain times s (s = 1: the nominal)
_KINDS = {
    "position": lambda s: f'<position joint="j" kp="{5 * s:.12g}" kv="0.1" forcelimited="true" '
                          'forcerange="-2 2"/>',
    "general": lambda s: f'<general joint="j" gaintype="fixed" biastype="affine" '
                         f'gainprm="{4 * s:.12g}" biasprm="0 {-4 * s:.12g} -0.08"/>',
    # 12 V, 1.5 N m stall, 6 rad/s no-load; kp, ki, kd, slewmax, Imax, Vmax 12 V
    "dcmotor": lambda s: f'<dcmotor joint="j" input="pos" nominal="12 1.5 6" '
                         f'controller="{4 * s:.12g} 0.5 0.1 0 0 12"/>',
    "dcmotor_unclamped": lambda s: f'<dcmotor joint="j" input="pos" nominal="12 1.5 6" '
                                   f'controller="{4 * s:.12g} 0 0.1 0 0 0"/>',
    "velocity": lambda s: f'<velocity joint="j" kv="{0.6 * s:.12g}" forcelimited="true" '
                          'forcerange="-1.5 1.5"/>',
    "motor": lambda s: f'<motor joint="j" gear="{s:.12g}" ctrllimited="true" ctrlrange="-1 1"/>',
}


def _commands(kind: str, n: int) -> np.ndarray:
    """Steps and a sine: angles [rad] for position kinds, rad/s for velocity, N m for motor."""
    t = np.arange(n) * 0.001
    u = np.where((t % 0.8) < 0.4, 0.6, -0.4) + 0.3 * np.sin(2 * np.pi * 1.3 * t)
    return {"velocity": 2.0 * u, "motor": 0.8 * u}.get(kind, u)


def _truth(kind: str, s: float, u: np.ndarray) -> np.ndarray:
    """The joint angle after each 1 ms step of the model written with gain x s (plain mujoco)."""
    m = mujoco.MjModel.from_xml_string(_RIG.format(act=_KINDS[kind](s)))
    d = mujoco.MjData(m)
    out = np.empty(len(u))
    for k, c in enumerate(u):
        d.ctrl[0] = c
        mujoco.mj_step(m, d)
        out[k] = d.qpos[0]
    return out


def _plant(kind: str, s: float, u: np.ndarray) -> np.ndarray:
    """The same through the project's plant: the nominal model with gain_error at s."""
    m = mujoco.MjModel.from_xml_string(_RIG.format(act=_KINDS[kind](1.0)))
    p = Plant(m, [AppliedEffect("gain_error", ("j",), {"scale": np.array([s])})])
    p.reset(qpos=np.zeros(1), ctrl=np.zeros(1))
    out = np.empty(len(u))
    for k, c in enumerate(u):
        p.step(np.array([c]), 1)
        out[k] = float(np.asarray(p.qpos).ravel()[0])
    return out


@pytest.mark.parametrize("kind", list(_KINDS))
@pytest.mark.parametrize("s", [0.5, 2.5])
def test_gain_error_is_the_actuator_written_with_its_proportional_gain_scaled(kind, s):
    u = _commands(kind, 3000)
    truth, nominal = _truth(kind, s, u), _truth(kind, 1.0, u)
    # the gain matters here: the written change moves the pendulum by tens of mrad or more
    assert np.abs(truth - nominal).max() > 0.02
    np.testing.assert_allclose(_plant(kind, s, u), truth, atol=1e-9)


def test_on_a_dcmotor_only_the_controller_kp_changes():
    """What stays: the dcmotor's ki and kd (damping and integral are not the P gain), its motor
    constants and its drive limit; a softer P under the same D (the truth of sim4
    gain05_dcmotor) is no longer the P, I and D scaled together."""
    m = mujoco.MjModel.from_xml_string(_RIG.format(act=_KINDS["dcmotor"](1.0)))
    p = Plant(m, [AppliedEffect("gain_error", ("j",), {"scale": np.array([0.5])})])
    g, g0 = p.model.actuator_gainprm[0], m.actuator_gainprm[0]
    assert g[servo.GAIN_KP] == pytest.approx(0.5 * g0[servo.GAIN_KP])
    keep = [i for i in range(len(g0)) if i != servo.GAIN_KP]
    np.testing.assert_array_equal(g[keep], g0[keep])
    np.testing.assert_array_equal(p.model.actuator_biasprm[0], m.actuator_biasprm[0])


def test_an_actuator_without_a_proportional_gain_is_refused_clearly():
    """A gain that depends on the actuator's length (``general`` with an affine gain) has no
    proportional gain to scale: a non-null gain_error on it says so, the null changes nothing."""
    act = '<general joint="j" gaintype="affine" gainprm="1 0.5 0" biastype="none"/>'
    m = mujoco.MjModel.from_xml_string(_RIG.format(act=act))
    with pytest.raises(ConfigError, match="gain type affine, with no proportional gain"):
        Plant(m, [AppliedEffect("gain_error", ("j",), {"scale": np.array([0.5])})])
    p = Plant(m, [AppliedEffect("gain_error", ("j",), {"scale": np.array([1.0])})])
    np.testing.assert_array_equal(p.model.actuator_gainprm, m.actuator_gainprm)


def test_a_dcmotor_without_a_drive_limit_has_no_stall_torque_and_dry_friction_is_fitted():
    """MuJoCo's dcmotor with Vmax 0 does not clamp its voltage: 3 rad off its goal it pushes
    kp x 3 = 12 N m from a 1.5 N m motor (checked here in plain mujoco). Its stall torque is
    then unbounded (the top of its force range when it has one), not K Vmax / R = 0, and
    coulomb_friction is a free parameter on it with a range above 0."""
    acts = np.array([0])
    for vmax, cap, stall in ((12.0, None, 1.5), (0.0, None, math.inf), (0.0, 0.9, 0.9)):
        act = (f'<dcmotor joint="j" input="pos" nominal="12 1.5 6" '
               f'controller="4 0 0.1 0 0 {vmax}"/>')
        m = mujoco.MjModel.from_xml_string(_RIG.format(act=act))
        if cap:  # a force range (the dcmotor element takes none in XML; the compiled model does)
            m.actuator_forcelimited[0] = 1
            m.actuator_forcerange[0] = [-cap, cap]
        d = mujoco.MjData(m)
        d.ctrl[0] = 3.0
        mujoco.mj_forward(m, d)
        assert abs(d.actuator_force[0]) == pytest.approx(min(12.0, stall), rel=1e-9)
        st = servo.stall_torque(m, acts)
        assert st[0] == pytest.approx(stall, rel=1e-9)
        assert servo.dcmotor_mask(m, acts).tolist() == [True]
        ctx = fitmod.Context(dt=0.002, peak_force=np.array([1.0]), stall=st,
                             damping=np.array([0.02]), dcmotor=servo.dcmotor_mask(m, acts))
        free = fitmod.Structure.build(("coulomb_friction",), ("j",), ctx).free
        assert [f.param for f in free] == ["frictionloss"]
        assert free[0].hi == pytest.approx(min(1.0, stall))
        # a dcmotor-only parameter still acts on it (the velocity limit's no-load speed scale)
        vl = fitmod.Structure.build(("velocity_limit",), ("j",), ctx).free
        assert [f.param for f in vl] == ["scale"]


def test_the_generator_draws_a_torque_limit_from_the_one_stall_torque():
    """``gap generate`` hides a torque limit at a share (0.2 at level 0, +-5 %) of the servo's
    stall torque: the XM430-W350's datasheet 4.1 N m at 12 V on the bench. It read a second copy
    of the formula, K Vmax / R of any actuator's gains: 0 on a position actuator (a torque limit
    of 0 N m); now a joint with no stall torque is refused."""
    from lowcostdex.gap.generate import bench_config, draw_hidden
    from lowcostdex.sim.models.bench import BENCH_JOINT, build_bench

    model = build_bench(bench_config("XM430-W350")).compile()
    stall = servo.motor_spec("XM430-W350").stall_torque
    assert stall == pytest.approx(4.1)
    e = draw_hidden("torque_limit", (BENCH_JOINT,), np.random.default_rng(0), model, level=0.0)
    assert 0.95 * 0.2 * stall <= e.values["torque"][0] <= 1.05 * 0.2 * stall
    pos = mujoco.MjModel.from_xml_string(_RIG.format(act=_KINDS["position"](1.0)))
    with pytest.raises(ConfigError, match=r"stall torque; the actuators of \['j'\] have none"):
        draw_hidden("torque_limit", ("j",), np.random.default_rng(0), pos, level=0.0)
