"""Select episodes whose open-loop replay is chaotic are left out of the select score.

Truth written here in plain MuJoCo: a 0.12 m pendulum (0.15 kg) on a ``motor`` actuator, a host
PD at 333 Hz logging the torques it wrote (as an Allegro hand is driven), once hanging (gravity
restores it: an open-loop replay of its torques stays on the log) and once held upright (gravity
tips it over: e-folding time sqrt(l / g) ~ 0.11 s, so a replay 0.1 ms late falls another way).
The first is a regular episode, the second a chaotic one (session 19: a curled Allegro finger's
select episode outweighed the rest and a right 9 ms latency was refused).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from lowcostdex.gap import chaos
from lowcostdex.gap.dataset import Split, Window, load_dataset
from lowcostdex.gap.diagnostics import noise_floor
from lowcostdex.gap.logs import write_log
from lowcostdex.gap.replay import Replayer
from lowcostdex.gap.trajectory import Trajectory

TICK = 2 * math.pi / 4096
MODEL = ('<mujoco><compiler angle="radian"/><option timestep="{dt}" integrator="implicitfast"/>'
         '<default><geom contype="0" conaffinity="0"/></default><worldbody>'
         '<body pos="0 0 0.3"><joint name="j" axis="0 1 0" damping="0.005" armature="0.0005"/>'
         '<geom type="sphere" pos="0 0 -0.12" size="0.01" mass="0.15"/></body></worldbody>'
         '<actuator><motor name="j" joint="j" ctrlrange="-2 2" ctrllimited="true"/></actuator>'
         '</mujoco>')


def _truth_log(centre: float, seconds: float = 2.5, rate: float = 333.0):
    """Host PD (kp 3 N m/rad, kd 0.1 N m s/rad on the differenced reading) tracking a 0.5 Hz
    sine of 0.3 rad about ``centre`` (0: hanging, pi: upright); torques held between rows."""
    m = mujoco.MjModel.from_xml_string(MODEL.format(dt=0.00025))
    d = mujoco.MjData(m)
    rng = np.random.default_rng(3)
    n = int(seconds * rate)
    t = np.arange(n) / rate
    d.qpos[0] = centre
    mujoco.mj_forward(m, d)
    q, goal, last = np.empty(n), np.empty(n), None
    for i, ti in enumerate(t):
        while d.time < ti - 1e-9:
            mujoco.mj_step(m, d)
        read = np.round((d.qpos[0] + rng.normal(0, 2e-4)) / TICK) * TICK
        dq = 0.0 if last is None else (read - last) * rate
        last = read
        tgt = centre + 0.3 * math.sin(2 * math.pi * 0.5 * ti)
        d.ctrl[0] = np.clip(3.0 * (tgt - read) - 0.1 * dq, -2, 2)
        q[i], goal[i] = read, d.ctrl[0]
    return Trajectory(name=f"c{centre:.1f}", time=t, goal=goal[:, None], qpos=q[:, None],
                      qvel=None, joints=("j",), actuators=("j",))


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("chaos")
    (tmp / "model.xml").write_text(MODEL.format(dt=0.002))
    paths = []
    for k, centre in enumerate((0.0, math.pi)):
        paths.append(write_log(tmp / f"log{k}.csv", _truth_log(centre)))
    return load_dataset(paths, model=tmp / "model.xml")


def _eps(ds):
    return [Window(k, 0, len(tr.time), 0) for k, tr in enumerate(ds.trajectories)]


def test_divergence_is_the_tail_rms_of_the_largest_joint_difference():
    a = np.zeros((8, 2))
    b = np.zeros((8, 2))
    b[6:, 1] = [3.0, 4.0]  # last quarter: samples 6, 7
    b[0, 0] = 100.0  # early differences do not count
    assert chaos.divergence(a, b) == pytest.approx(math.sqrt((9 + 16) / 2))
    assert chaos.divergence(a[:1], b[:1]) == pytest.approx(100.0)


def test_the_upright_pendulum_is_chaotic_and_the_hanging_one_is_not(ds):
    rep = Replayer(ds, [], nthread=1)
    eps = _eps(ds)
    pred = rep.run(eps, [[]])[0][0]
    floor = float(np.sqrt(np.mean(noise_floor(ds.trajectories) ** 2)))
    assert chaos.chaotic(rep.run, ds, eps, pred, floor) == [False, True]
    shifted = rep.run(eps, [[]], goal_shift=chaos.SHIFT * ds.timestep)[0][0]
    hanging, upright = (chaos.divergence(p, s) / floor for p, s in zip(pred, shifted, strict=True))
    assert hanging < 2.0 < chaos.FLOORS < upright  # measured: regular episodes stay near 1 floor


def test_only_chaotic_select_episodes_leave_the_score_and_one_always_stays(ds):
    rep = Replayer(ds, [], nthread=1)
    eps = _eps(ds)
    pred = rep.run(eps, [[]])[0][0]
    fl = float(np.mean(noise_floor(ds.trajectories) ** 2))
    split, sel = chaos.scored_select(rep.run, ds, eps, Split((), (0, 1), ()), pred, fl)
    assert split == Split((), (0,), (), unscored=(1,)) and sel == [eps[0]]
    same, sel = chaos.scored_select(rep.run, ds, eps, Split((0,), (1,), ()), pred, fl)
    assert same == Split((0,), (1,), ()) and sel == [eps[1]]  # all chaotic: nothing better
