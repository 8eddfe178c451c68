"""A replay depends only on its inputs: the windows, the column's effects and their values.

Not on what the process replayed before (plants are reused between calls: a plant keyed by its
effect names and size is re-armed with new values), not on the other columns replayed beside it
in one batch, and a fresh process gives the same numbers to the bit.

The log comes from plain MuJoCo written out here (a gravity-loaded pendulum on a position servo
with a native 6 ms actuator delay, Coulomb friction and a 1 deg play, stepped at 0.25 ms); its
truth does not matter, only that the replays see a loaded play, friction and a delay.

Two defects this found (session 18, gap-cpu13): (1) a ``mass_error`` column in a batch made the
plant recompute MuJoCo's model constants (``mj_setConst``: invweight0, acc0) for EVERY simulation
from its own armature, so an ``inertia_error`` column replayed beside a ``mass_error`` one moved
by 2.8e-5 rad on the main job's finger logs (and the replay memo then kept whichever it saw
first); a plain ``Plant`` also kept an earlier mass_error's constants after its effects changed;
(2) a replay with ``goal_shift`` zeroed the native actuator delay of the reused plant, and every
later replay on that plant ran without it. (The session-17 "0.0186 in a whole run vs 0.0177 in a
fresh process" was neither: the fresh run started at the point printed to 7 digits; at the
whole run's exact point a fresh process gives the whole run's 0.0186150748279538 to the bit, and
a 1e-9 rad change of the play's width there moves the cost by -4 .. +11 %: the cost is chaotic.)
"""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap

import mujoco
import numpy as np
import pytest

from lowcostdex.gap.dataset import Window, load_dataset
from lowcostdex.gap.logs import write_log
from lowcostdex.gap.replay import Replayer
from lowcostdex.gap.trajectory import Trajectory
from lowcostdex.sim.effects import AppliedEffect
from lowcostdex.sim.plant import Plant

W = 0.0175  # play [rad]
TICK = 2 * math.pi / 4096
_BODY = ('<geom type="capsule" fromto="0 0 0 0 0 -0.12" size="0.008" mass="0.05"/>'
         '<geom type="sphere" pos="0 0 -0.12" size="0.015" mass="0.15"/>')
_ACT = ('<actuator><position name="j" joint="{j}" kp="6" kv="0.12" forcelimited="true" '
        'forcerange="-2 2" nsample="40" interp="linear" delay="{d}"/></actuator>')
USER = ('<mujoco><compiler angle="radian"/><option timestep="0.001" integrator="implicitfast"/>'
        '<default><geom contype="0" conaffinity="0"/></default><worldbody>'
        '<body pos="0 0 0.3"><joint name="j" axis="0 1 0" damping="0.02" armature="0.003" '
        'frictionloss="0.01"/>' + _BODY + '</body></worldbody>' + _ACT.format(j="j", d=0.006)
        + '</mujoco>')
TRUTH = ('<mujoco><compiler angle="radian"/><option timestep="0.00025" integrator="implicitfast"/>'
         '<default><geom contype="0" conaffinity="0"/></default><worldbody>'
         '<body pos="0 0 0.3"><joint name="m" axis="0 1 0" damping="0.02" armature="0.003" '
         'frictionloss="0.03"/><geom type="sphere" size="0.004" mass="0.002"/>'
         '<body><joint name="p" axis="0 1 0" limited="true" '
         f'range="{-W / 2} {W / 2}" solreflimit="0.0005 1" armature="1e-6"/>' + _BODY
         + '</body></body></worldbody>' + _ACT.format(j="m", d=0.006) + '</mujoco>')


@pytest.fixture(scope="module")
def ds(tmp_path_factory):
    """A 4 s log at 200 Hz of the truth (goal steps and a sine), readings on 4096 ticks."""
    tmp = tmp_path_factory.mktemp("det")
    m = mujoco.MjModel.from_xml_string(TRUTH)
    d = mujoco.MjData(m)
    rate, n = 200.0, 800
    t = np.arange(n) / rate
    goal = (0.4 * np.sin(2 * math.pi * 0.7 * t) + 0.3 * (t > 1.3) - 0.5 * (t > 2.6))[:, None]
    d.qpos[:] = [goal[0, 0], 0.0]
    d.ctrl[:] = goal[0]
    mujoco.mj_forward(m, d)
    mujoco.mj_initCtrlHistory(m, d, 0, None, np.full((40, 1), goal[0, 0]))  # held before
    q, v = np.empty((n, 1)), np.empty((n, 1))
    for i, ti in enumerate(t):
        while d.time < ti - 1e-9:
            mujoco.mj_step(m, d)
        q[i] = np.round((d.qpos[0] + d.qpos[1]) / TICK) * TICK
        v[i] = d.qvel[0] + d.qvel[1]
        d.ctrl[:] = goal[i]
    (tmp / "model.xml").write_text(USER)
    write_log(tmp / "log0.csv", Trajectory(name="log0", time=t, goal=goal, qpos=q, qvel=v,
                                           joints=("j",), actuators=("j",)))
    return load_dataset([tmp / "log0.csv"], model=tmp / "model.xml")


# windows inside the log (a play state carried from the second before each) and at its start
WINDOWS = [Window(0, 300, 500, 310), Window(0, 500, 780, 510), Window(0, 0, 300, 0)]
NAMES = ["backlash", "coulomb_friction", "inertia_error", "mass_error", "latency"]


def _e(name, **values):
    return AppliedEffect(name, ("j",), {k: np.array([v], float) for k, v in values.items()})


PLAY = _e("backlash", width=W, sensor=0.0, read=1.0)
A = [PLAY, _e("coulomb_friction", frictionloss=0.02), _e("inertia_error", scale=2.0)]
B = [_e("backlash", width=0.03, sensor=1.0, read=1.0), _e("coulomb_friction", frictionloss=0.05),
     _e("inertia_error", scale=0.7)]
A_FLAT = [_e("coulomb_friction", frictionloss=0.02), _e("inertia_error", scale=2.0)]
MASS = [_e("mass_error", scale=1.3), _e("inertia_error", scale=0.7)]


def _replay(rep, cols, **kw):
    """Predictions of every column (no memory of replayed columns: ``force_peak`` replays)."""
    return rep.run(WINDOWS, cols, force_peak=True, **kw)[0]


def _same(p, q):
    for a, b in zip(p, q, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("col", [A, A_FLAT], ids=["with play", "no play"])
def test_a_column_replays_the_same_whatever_is_batched_beside_it(ds, col):
    alone = _replay(Replayer(ds, NAMES, nthread=1), [col])[0]
    beside = _replay(Replayer(ds, NAMES, nthread=1), [B, col, MASS, [_e("mass_error", scale=1.3)]])
    _same(beside[1], alone)
    assert not np.array_equal(beside[0][0], alone[0])  # (B is another model)


def test_a_replay_does_not_depend_on_the_replays_before_it(ds):
    rep = Replayer(ds, NAMES, nthread=1)
    first = _replay(rep, [A])[0]
    _replay(rep, [B])  # the same plants (effect names, sizes), other values
    _replay(rep, [MASS])  # constants recomputed in a plant of another key
    _replay(rep, [A], goal_shift=0.002)  # goals shifted: the native delay zeroed for it
    _replay(rep, [[]], goal_shift=0.002)
    _same(_replay(rep, [A])[0], first)
    _same(_replay(rep, [[]])[0], _replay(Replayer(ds, NAMES, nthread=1), [[]])[0])
    # ... and the memory of replayed columns answers what a replay gives
    _same(rep.run(WINDOWS, [A])[0][0], first)


def test_a_plant_forgets_an_earlier_mass_error():
    m = mujoco.MjModel.from_xml_string(USER)
    fresh = Plant(m, [_e("inertia_error", scale=2.0)])
    used = Plant(m, [_e("mass_error", scale=1.5), _e("inertia_error", scale=0.5)])
    used.set_effects([_e("inertia_error", scale=2.0)])
    np.testing.assert_array_equal(used.model.dof_invweight0, fresh.model.dof_invweight0)
    np.testing.assert_array_equal(used.model.body_subtreemass, m.body_subtreemass)
    moved = Plant(m, [_e("mass_error", scale=1.5)])  # a moved mass still moves its constants
    assert moved.model.body_subtreemass[1] == pytest.approx(1.5 * m.body_subtreemass[1])


def test_a_fresh_process_gives_the_same_replay_to_the_bit(ds, tmp_path):
    rep = Replayer(ds, NAMES, nthread=1)
    _replay(rep, [B, MASS])
    here = np.concatenate([p.ravel() for p in _replay(rep, [A])[0]])
    src = ds.sources[0] if ds.sources else None
    assert src is not None
    code = textwrap.dedent(f"""
        import numpy as np, sys
        sys.path.insert(0, {str(__import__('pathlib').Path(__file__).parent)!r})
        import test_replay_determinism as t
        from lowcostdex.gap.dataset import load_dataset
        from lowcostdex.gap.replay import Replayer
        import pathlib
        log = pathlib.Path({str(src)!r})
        ds = load_dataset([log], model=log.parent / "model.xml")
        p = t._replay(Replayer(ds, t.NAMES, nthread=1), [t.A])[0]
        np.save({str(tmp_path / 'p.npy')!r}, np.concatenate([x.ravel() for x in p]))
    """)
    subprocess.run([sys.executable, "-c", code], check=True, timeout=300)
    np.testing.assert_array_equal(np.load(tmp_path / "p.npy"), here)
