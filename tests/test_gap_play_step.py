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
