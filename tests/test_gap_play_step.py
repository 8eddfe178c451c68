"""A backlash fit started on one joint at a time, and the step a structural play is tried at
(issue 11; gap-arm20, session 25).

The truth is outside the code: the arm and its logs come from ``tests/gap_truth_sim9.py``
(mujoco + numpy only), and the speed a joint crosses a play at is computed here from the logged
readings by finite differences (the 99th percentile of |dq/dt| over rows), not from the
data set's velocity estimate; a play takes a step or more of that motion to cross when width >=
speed x step.
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import load_dataset, play_side, stepsize
from lowcostdex.sim.effects import AppliedEffect

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import gap_truth_sim9 as sim  # noqa: E402


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    """sim9's limit_play_offset arm (3 x 8 s, 100 Hz) as the analysis loads it, and each
    joint's fast speed from the logged readings (99th percentile of |finite difference|)."""
    case = sim.CASE_BY_NAME["limit_play_offset_arm4"]
    files = sim.write_case(case, tmp_path_factory.mktemp("arm"))
    ds = load_dataset(files["logs"], model=files["model"], angle_unit="deg", time_unit="ms")
    speeds = []
    for path in sorted(pathlib.Path(files["logs"][0]).glob("*.csv")):
        head = path.read_text().splitlines()[0].split(",")
        a = np.genfromtxt(path, delimiter=",", skip_header=1)
        t = a[:, head.index("time")] * 1e-3
        q = np.radians(np.column_stack([a[:, head.index(f"qpos:{j}")] for j in ds.joints]))
        ok = np.diff(t) > 0
        speeds.append(np.abs(np.diff(q, axis=0)[ok] / np.diff(t)[ok, None]))
    return ds, np.percentile(np.concatenate(speeds), 99, axis=0)


def _play(ds, widths) -> AppliedEffect:
    n = len(ds.joints)
    return AppliedEffect("backlash", ds.joints, {"width": np.asarray(widths, float),
                                                 "sensor": np.ones(n), "read": np.ones(n)})


def test_a_play_crossed_within_a_step_is_tried_where_it_takes_a_step(arm):
    """The elbow's fast motion (measured here ~11 rad/s: 22 mrad per 2 ms step) crosses its 10
    mrad play within a step: it takes a step or more at 0.5 ms (5.6 mrad per step), not at 1 ms;
    a 4 mrad play goes to the finest step (0.25 ms); a play wider than a 2 ms step's motion is
    not structural, nor one narrower than the readings resolve (1 mrad: ~2 noise floors)."""
    ds, fast = arm
    e = ds.joints.index("elbow")
    dt = ds.timestep
    assert dt == pytest.approx(0.002)
    assert 0.005 < fast[e] * dt / 4 < 0.010 < fast[e] * dt / 2  # 10 mrad: 0.5 ms, not 1 ms
    w = np.zeros(len(ds.joints))
    for width, factor in ((0.010, 0.25), (0.004, 0.125), (1.2 * fast[e] * dt, None),
                          (0.001, None)):
        w[e] = width
        assert stepsize.play_factor(ds, _play(ds, w), 2.5e-4) == factor, width
    w[e] = 0.010
    assert stepsize.play_factor(ds, _play(ds, w), 1e-3) == 0.5  # no finer than min_step
    assert stepsize.play_factor(ds, _play(ds, np.zeros(len(w))), 2.5e-4) is None
    assert stepsize.play_factor(ds, None, 2.5e-4) is None


def test_each_joint_gets_a_start_with_a_play_there_alone(arm):
    """The link-read backlash structure of a 4-joint arm is started as the catalogue says (a
    play on every joint) and once per joint with a 10 mrad play read across on that joint
    only; the motor-side structure (sensor held) gets no one-joint starts."""
    ds, _ = arm
    n = len(ds.joints)
    ctx = fitmod.Context(dt=ds.timestep, peak_force=np.ones(n), stall=np.full(n, np.inf),
                         damping=np.zeros(n))
    tracks = play_side.tracks("backlash", ds.joints, ctx, one_joint=True)
    assert len(play_side.tracks("backlash", ds.joints, ctx)) == len(tracks) - n  # off: none
    link = [t for t in tracks if "motor" not in t.label]
    motor = [t for t in tracks if "motor" in t.label]
    st = link[0].structure
    base = len(st.starts())
    assert len(link) == base + n and len(motor) == len(motor[0].structure.starts())
    for j, t in enumerate(link[base:]):
        vals = t.effects()[-1].values
        want = np.zeros(n)
        want[j] = 0.01
        np.testing.assert_allclose(vals["width"], want)
        assert vals["sensor"][j] == 1.0


def test_a_one_joint_rig_gets_no_one_joint_start():
    """On a one-joint rig the catalogue's starts already put their play on its only joint: no
    one-joint start is added (a one-joint bench's backlash round costs what it did)."""
    ctx = fitmod.Context(dt=0.002, peak_force=np.ones(1), stall=np.full(1, np.inf),
                         damping=np.zeros(1))
    assert len(play_side.tracks("backlash", ["j"], ctx, one_joint=True)) == len(
        play_side.tracks("backlash", ["j"], ctx))


def test_a_sensor_the_data_cannot_tell_goes_back_to_its_start():
    """A fitted play whose training residual does not depend on a joint's sensor (written out
    here: the residual reads the widths only) does not keep the 1.0 a start put there: it goes
    back to the catalogue's start (the motor side); a sensor the residual does depend on stays."""
    n = 3
    ctx = fitmod.Context(dt=0.002, peak_force=np.ones(n), stall=np.full(n, np.inf),
                         damping=np.zeros(n))
    st = play_side.structures("backlash", ["a", "b", "c"], ctx)[0]
    sensors = [i for i, f in enumerate(st.free) if f.param == "sensor"]
    widths = [i for i, f in enumerate(st.free) if f.param == "width"]

    def fn(points, told=()):  # the widths' misfit from 0.02 rad, plus the told sensors' from 1
        out = []
        for _, x in points:
            out.append(np.concatenate([x[widths] - 0.02, [x[sensors[j]] - 1.0 for j in told]]))
        return out

    for told in ((), (1,)):
        x = np.array([0.02 if f.param == "width" else (1.0 if f.joint == 1 else f.start)
                      for f in st.free])
        t = fitmod.Track(st, st.u(x))
        t.r = fn([(st, x)], told)[0]
        t.cost = 0.5 * float(t.r @ t.r)
        moved = play_side.settle_sensor(t, lambda p, told=told: fn(p, told))
        s1 = t.x[sensors[1]]
        assert (moved, s1) == ((True, st.free[sensors[1]].start) if not told else (False, 1.0))
        np.testing.assert_allclose(t.x[widths], 0.02)
