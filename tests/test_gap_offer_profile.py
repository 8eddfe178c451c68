"""The data gate that offers ``goal_profile`` by default only where the logs show a profile's ramps
(``lowcostdex.gap.ramps``, ``gap.ramps.GATES``), on hand-written signals: the readings are written out here, never
simulated with project code.

A one-hinge rig without gravity (armature 0.01 kg m^2, a 10 g link of 1e-5 kg m^2) driven by a
``position`` servo clipped at 1 N m: its force gives the joint at most 1 / 0.01001 = 99.9 rad/s^2.
Each log holds goals for 1.5 s each (100 Hz rows, readings on the 4096-tick grid) and the joint
moves from one goal to the next as written by each case:

- a Dynamixel-style trapezoid, 2 rad/s and 10 rad/s^2, the same both ways: a move of d >= v^2 / a
  = 0.4 rad runs at 2 rad/s from 25 % to 75 % of the way once d >= 4 v^2 / (2 a) = 0.8 rad
  (accelerating over v^2 / 2a = 0.2 rad), so its mid-move speed does not grow with d;
- a servo answering after 30 ms as a first-order lag of 50 ms: from 25 % to 75 % of the way in
  tau ln 3 = 54.9 ms whatever d, so the speed d / 2 / 54.9 ms doubles with d;
- a torque-limited servo on a loaded arm: trapezoids at 4 rad/s moving positive (with the load)
  and 1.5 rad/s negative (against it): the plateau depends on the direction;
- a servo saturating at its own force: rest-to-rest triangles at 99.9 rad/s^2 (the nominal
  model's force over inertia), a triangle law as an acceleration-limited profile's, but at the
  acceleration the user's model already has.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.gap import ramps
from lowcostdex.gap.analyze import available_candidates
from lowcostdex.gap.dataset import Dataset
from lowcostdex.gap.trajectory import Trajectory

_RIG = """
<mujoco><option timestep="0.002" gravity="0 0 0"/>
  <worldbody><body><joint name="j" type="hinge" axis="0 1 0" armature="0.01"/>
    <inertial pos="0 0 0" mass="0.01" diaginertia="1e-5 1e-5 1e-5"/></body></worldbody>
  <actuator><position name="a" joint="j" kp="5" forcelimited="true" forcerange="-1 1"/></actuator>
</mujoco>"""
ACCEL = 1.0 / 0.01001           # rad/s^2: the nominal servo's force over the joint's inertia
TICK = 2 * math.pi / 4096
RATE, HOLD = 100.0, 1.5         # rows per s, s per goal
GOALS = (0.0, 0.3, -0.5, 0.7, -0.4, 0.6, -0.6, 0.9, -0.3, 0.2, -0.8, 0.4)


def _ramp(t: np.ndarray, d: float, v: float, a: float) -> np.ndarray:
    """Distance covered [rad] at times ``t`` [s] (from the step) by a rest-to-rest move of
    ``|d|`` at most ``v`` rad/s and ``a`` rad/s^2: a trapezoid, or a triangle when |d| < v^2 / a
    (peak sqrt(a |d|)). Written out: accelerate, cruise, brake."""
    d = abs(d)
    peak = min(v, math.sqrt(a * d))
    ta = peak / a                                  # accelerating (and braking) [s]
    tc = (d - peak * ta) / peak                    # cruising [s]
    t = np.clip(t, 0.0, 2 * ta + tc)
    brake = np.clip(t - ta - tc, 0.0, ta)
    return (0.5 * a * np.minimum(t, ta) ** 2 + peak * np.clip(t - ta, 0.0, tc)
            + peak * brake - 0.5 * a * brake ** 2)


def _trapezoid(v_up: float, v_down: float, a: float):
    def move(t, d):
        return math.copysign(1.0, d) * _ramp(t, d, v_up if d > 0 else v_down, a)
    return move


def _lag(t, d, delay=0.03, tau=0.05):
    return d * (1.0 - np.exp(-np.clip(t - delay, 0.0, None) / tau))


def _dataset(move, goals=GOALS) -> Dataset:
    """One log: the goals held ``HOLD`` s each (the first for the first hold), the joint moving
    from each goal to the next by ``move(t since the step, d)``."""
    n = int(round(HOLD * RATE))
    t = np.arange(len(goals) * n) / RATE
    goal = np.repeat(goals, n)
    q = np.full(len(t), goals[0])
    for k in range(1, len(goals)):
        rows = slice(k * n, (k + 1) * n)
        q[rows] = goals[k - 1] + move(t[rows] - t[k * n], goals[k] - goals[k - 1])
    q = np.round(q / TICK) * TICK
    tr = Trajectory("log", t, goal[:, None], q[:, None], ("a",), ("j",))
    return Dataset({"model": _RIG}, [tr])


def _law(ds: Dataset) -> tuple[float, float]:
    tr = ds.trajectories[0]
    return ramps.ramp_law(ramps.profile_moves(tr, 0, 0))


def test_a_trapezoid_moves_at_its_velocity_whatever_the_step_and_is_offered():
    ds = _dataset(_trapezoid(2.0, 2.0, 10.0))
    moves = ramps.profile_moves(ds.trajectories[0], 0, 0)
    assert len(moves) == len(GOALS) - 1   # every step: 0.5-1.5 rad, from rest, held 1.5 s
    long = np.abs(moves[:, 0]) >= 0.8     # cruising from 25 % to 75 % of the way: 2 rad/s
    np.testing.assert_allclose(moves[long, 1], 2.0, rtol=0.03)
    beta, gamma = _law(ds)
    assert -0.1 < beta < 0.2 and abs(gamma) < 0.05, (beta, gamma)
    assert ramps.shows_profile(ds)
    assert "goal_profile" in available_candidates(ds, None)


def test_a_delayed_lag_moves_in_proportion_to_the_step_and_is_not_offered():
    ds = _dataset(_lag)
    moves = ramps.profile_moves(ds.trajectories[0], 0, 0)
    # from 25 % to 75 % of the way in tau ln 3 = 54.9 ms: d / 2 / 0.0549 s (rows 10 ms apart,
    # crossing times interpolated between them)
    np.testing.assert_allclose(moves[:, 1], np.abs(moves[:, 0]) / 2 / (0.05 * math.log(3)),
                               rtol=0.12)
    beta, _ = _law(ds)
    assert beta > 0.9
    assert not ramps.shows_profile(ds)
    got = available_candidates(ds, None)
    assert "goal_profile" not in got and "velocity_limit" in got
    # asked for by name it is fitted whatever the logs show
    assert available_candidates(ds, ["goal_profile", "latency"]) == ["goal_profile", "latency"]


def test_a_load_dependent_plateau_is_not_a_profile():
    """4 rad/s with the load, 1.5 against it: gamma = ln(4 / 1.5) = 0.98 > GAMMA_MAX."""
    ds = _dataset(_trapezoid(4.0, 1.5, 40.0))
    beta, gamma = _law(ds)
    assert beta < ramps.BETA_MAX and gamma == pytest.approx(math.log(4.0 / 1.5), abs=0.15)
    assert not ramps.shows_profile(ds)


def test_a_servo_saturating_at_its_own_force_is_not_a_profile():
    """Triangles at the nominal force over inertia: speed ~ sqrt(size) (beta 0.5, within
    BETA_MAX, no direction) but the acceleration is the user's model's own, not a firmware's."""
    ds = _dataset(_trapezoid(1e3, 1e3, ACCEL))
    beta, gamma = _law(ds)
    assert beta == pytest.approx(0.5, abs=0.1) and abs(gamma) < 0.05
    accel, speed = ramps.nominal_limits(ds, 0, 0, 1.0)
    assert accel == pytest.approx(ACCEL, rel=1e-6) and speed == math.inf
    assert not ramps.shows_profile(ds)
    # the same triangles at a tenth of it: a slow acceleration profile, offered
    assert ramps.shows_profile(_dataset(_trapezoid(1e3, 1e3, ACCEL / 10)))


def test_too_few_moves_or_one_direction_cannot_tell():
    up = np.array([[0.2, 2.0], [0.4, 2.0], [0.8, 2.0], [1.6, 2.0]])
    assert ramps.ramp_law(up) is None                       # one direction only
    both = up * [[1, 1], [-1, 1], [1, 1], [-1, 1]]   # sizes both ways, speeds 2 rad/s
    assert ramps.ramp_law(both[:3]) is None             # 3 moves < MIN_MOVES
    assert ramps.ramp_law(both) == pytest.approx((0.0, 0.0))
    # only steps under MIN_MOVE: nothing timed
    assert not ramps.shows_profile(_dataset(_trapezoid(2.0, 2.0, 10.0),
                                            goals=(0.0, 0.05, -0.02, 0.06, 0.0)))


@pytest.mark.parametrize("velocity, lower_only", [(5.0, True), (3.0, False)])
def test_a_profile_velocity_no_move_reaches_is_reported_as_a_lower_bound(velocity, lower_only):
    """goal_profile's velocity where every move is a triangle (sim8's 3 rad/s with 12 rad/s^2:
    its interval spanned the whole search range): the largest goal step here is 0.9 - (-0.6) =
    1.5 rad, whose rest-to-rest triangle at 12 rad/s^2 peaks at sqrt(12 x 1.5) = 4.243 rad/s.
    A fitted 5 rad/s caps no move: the data say only 'at least' the peak at the acceleration's
    lower 95 % end, sqrt(11 x 1.5) = 4.062 (interval [4.06, the search's limit], flagged); a
    fitted 3 rad/s caps the large moves: left as fitted."""
    ds = _dataset(_trapezoid(velocity, velocity, 12.0))
    params = {"velocity": {"value": [velocity], "interval": [[0.5, 50.0]], "unit": "rad/s"},
              "acceleration": {"value": [12.0], "interval": [[11.0, 13.0]], "unit": "rad/s^2"}}
    flags = ramps.uncapped_velocity(ds, ("j",), params)
    vel = params["velocity"]
    assert vel["lower_bound_only"] == [lower_only]
    assert bool(flags) == lower_only
    if lower_only:
        assert vel["interval"][0][0] == pytest.approx(math.sqrt(11.0 * 1.5), rel=0.01)
        assert vel["interval"][0][1] >= 500.0 and "not identifiable above" in flags[0]
    else:
        assert vel["interval"] == [[0.5, 50.0]]
