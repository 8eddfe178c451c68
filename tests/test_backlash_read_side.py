"""A backlash read on the motor side (issue 11, gap-rotor12): ``backlash.read``.

The truth here is plain MuJoCo written in this file, not project code: a two-link arm whose
distal servo drives a rotor body (its armature, the servo's ``position`` actuator, its encoder)
and, through a hinge limited to the play, the link (the third truth simulator's finger is built
the same way, ``tests/gap_truth_sim3.py``). Its encoder reads the rotor: the motor side.
The catalogue's backlash (a play hinge added to the user's nominal two-link model) with ``read``
0 must read what that encoder reads, with ``read`` 1 (its null) the link; and a play locked at
width 0 on the other joint must leave that joint the nominal one (the lock was an armature of
1e12 kg m^2 until this session: past double precision beside a 1e-4 kg m^2 link, it moved the
other joints' readings by millirads).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from lowcostdex.sim.effects import AppliedEffect, Backlash
from lowcostdex.sim.plant import Plant, prepare_spec

DT = 0.00025       # s, physics step of both models
W = 0.06           # rad, the distal play
ARM = 0.0008       # kg m^2, rotor armature of each joint
KP, KV, TMAX = 3.0, 0.08, 1.5


def _link(mass: float, length: float) -> str:
    i = mass * length ** 2 / 12
    return (f'<inertial pos="0 0 {-length / 2}" mass="{mass}" diaginertia="{i} {i} 1e-6"/>'
            f'<geom type="capsule" fromto="0 0 0 0 0 {-length}" size="0.01" contype="0" '
            'conaffinity="0" mass="0"/>')


def _actuators() -> str:
    return "".join(f'<position name="s_{j}" joint="{j}" kp="{KP}" kv="{KV}" '
                   f'forcerange="{-TMAX} {TMAX}"/>' for j in ("a", "b"))


def _xml(play: float | None) -> str:
    """The arm; ``play`` None: the user's nominal model; else the truth with a rotor body and a
    play hinge of that full width between the distal servo and its link."""
    joint = f'type="hinge" axis="0 1 0" armature="{ARM}" damping="0.01"'
    if play is None:
        distal = f'<body name="lower" pos="0 0 -0.07"><joint name="b" {joint}/>{_link(0.05, 0.065)}</body>'
    else:
        distal = (f'<body name="rotor" pos="0 0 -0.07"><joint name="b" {joint}/>'
                  '<inertial pos="0 0 0" mass="1e-4" diaginertia="1e-9 1e-9 1e-9"/>'
                  f'<body name="lower"><joint name="b_play" type="hinge" axis="0 1 0" limited="true" '
                  f'range="{-play / 2} {play / 2}" solreflimit="{2 * DT} 1" '
                  'solimplimit="0.99 0.999 0.0001"/>' + _link(0.05, 0.065) + '</body></body>')
    return (f'<mujoco><compiler angle="radian"/><option timestep="{DT}" integrator="implicitfast"/><worldbody>'
            f'<body name="upper" pos="0 0 0.4"><joint name="a" {joint}/>{_link(0.085, 0.07)}'
            f'{distal}</body></worldbody><actuator>{_actuators()}</actuator></mujoco>')


def _goals(n: int) -> np.ndarray:
    t = np.arange(n) * DT
    a = 0.5 + 0.3 * np.sin(2 * np.pi * 0.7 * t)
    b = 0.6 + 0.4 * np.sign(np.sin(2 * np.pi * 0.9 * t)) * (t % 1.0 < 0.8)
    return np.stack([a, b], 1)


SETTLE, RUN = 4000, 12000   # steps: 1 s at the first goal, then 3 s


def _truth() -> dict:
    """Plain MuJoCo: the truth's rotor (encoder) and link angles of both joints per step."""
    m = mujoco.MjModel.from_xml_string(_xml(W))
    d = mujoco.MjData(m)
    g = _goals(RUN)
    d.qpos[[m.joint("a").qposadr[0], m.joint("b").qposadr[0]]] = g[0]
    qa, qb, qp = (m.joint(n).qposadr[0] for n in ("a", "b", "b_play"))
    rotor, link = np.empty((RUN, 2)), np.empty((RUN, 2))
    for k in range(SETTLE + RUN):
        d.ctrl[:] = g[max(k - SETTLE, 0)]
        mujoco.mj_step(m, d)
        if k >= SETTLE:
            rotor[k - SETTLE] = d.qpos[[qa, qb]]
            link[k - SETTLE] = d.qpos[qa], d.qpos[qb] + d.qpos[qp]
    return {"rotor": rotor, "link": link}


def _catalogue(read: float, widths=(0.0, W)) -> np.ndarray:
    """The user's nominal model with the catalogue's backlash (play hinges on both joints,
    ``widths``), read on side ``read``: its readings (measured_qpos) per step."""
    eff = [AppliedEffect("backlash", ("a", "b"), {"width": np.asarray(widths, float),
                                                 "read": np.full(2, read)})]
    spec = prepare_spec(mujoco.MjSpec.from_string(_xml(None)), eff, hidden_dofs=True)
    p = Plant(spec.compile(), eff)
    jq = [p.model.joint(n).qposadr[0] for n in ("a", "b")]
    g = _goals(RUN)
    q0 = np.zeros(p.model.nq)
    q0[jq] = g[0]
    p.reset(qpos=q0, ctrl=g[0])
    out = np.empty((RUN, 2))
    for k in range(SETTLE + RUN):
        p.step(g[max(k - SETTLE, 0)], 1)
        if k >= SETTLE:
            out[k - SETTLE] = p.measured_qpos()[jq]
    return out


@pytest.fixture(scope="module")
def truth():
    return _truth()


def _rms(x):
    return np.sqrt(np.mean(x ** 2, axis=0))


def test_read_on_the_motor_side_reads_the_rotor_and_on_the_link_the_link(truth):
    """Read 0 follows the truth's rotor encoder, read 1 its link, each to a small share of the
    play (the two contacts differ in softness); the other side is off by about half the play."""
    motor, link = _catalogue(0.0), _catalogue(1.0)
    assert truth["link"][:, 1].max() - truth["rotor"][:, 1].max() != 0.0
    gap = _rms(truth["link"] - truth["rotor"])[1]
    assert gap > 0.3 * W, gap                         # the play shows between the two sides
    e_motor = _rms(motor - truth["rotor"])
    e_link = _rms(link - truth["link"])
    assert e_motor[1] < 0.003 * W and e_link[1] < 0.008 * W, (e_motor, e_link)  # 0.03, 0.24 mrad
    assert _rms(motor - truth["link"])[1] > 10 * e_motor[1]   # the wrong side is far off
    assert _rms(link - truth["rotor"])[1] > 10 * e_link[1]


def test_a_locked_play_leaves_its_joint_the_nominal_one(truth):
    """The proximal joint has no play in the truth; the catalogue locks its play hinge (width 0)
    beside the distal play: its reading follows the truth's to a small share of the play's
    effect, as it does with no hinge there at all (the distal play alone)."""
    both = _catalogue(0.0)
    e = _rms(both - truth["rotor"])[0]
    assert e < 2e-4, e   # measured 0.07 mrad (1.7 with the old lock)


def test_the_reading_side_is_a_parameter_with_the_link_as_its_null():
    p = Backlash.param("read")
    assert (p.null, p.low, p.high) == (1.0, 0.0, 1.0)
    # domain randomization draws no reading side: the same seed gives the same robots
    a = Backlash.sample(np.random.default_rng(3), (4,))
    b = np.random.default_rng(3)
    assert np.array_equal(a["width"], b.uniform(*Backlash.param("width").dr, size=(4,)))
    assert np.all(a["read"] == 1.0)
