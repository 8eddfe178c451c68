"""The gap analysis judged on an eighth independently written truth simulator: a Dynamixel's
motion profile on the goal (Profile Velocity / Profile Acceleration) on a servo bench with a
``position`` actuator (issue 11; gap-profile16, session 21; bench/RESULTS.md "gap-profile16").

``tests/gap_truth_sim8.py`` (mujoco + numpy only) writes the cases; each is analysed as the CLI
does and scored by ``redteam_check.grade``: the hidden effect named exactly (nothing on the clean
case), every documented parameter inside its 95 % interval. Misses are strict xfails whose reason
is the measured result; they fail (XPASS) when fixed and must then lose their mark.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import sys

import numpy as np
import pytest

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import gap_truth_sim8 as sim  # noqa: E402
import redteam_check  # noqa: E402

# profile_v2_5_bench runs in the default test run (26 CPU-s, gap-profile17): the data gate
# (lowcostdex.gap.ramps, one of gap.offer.GATES) offers goal_profile on its logs and the
# analysis names it.
FAST: frozenset[str] = frozenset({"profile_v2_5_bench"})

# what the analysis named instead, per case it misses (``gap analyze --seed 0 --threads 1``, as
# the test runs it). On main 441707b (session 21, gap-profile16), goal_profile not yet a default
# candidate, the profiles were named velocity_limit (v2_5: speed 2.41 rad/s, held-out 60.4 ->
# 11.9 mrad; v3_a12: velocity_limit + latency 91 ms, 102.5 -> 28.7; v2_load: velocity_limit,
# 251.5 -> 81.3). Since gap-profile17 goal_profile is a default cause offered where the logs show
# a profile's ramps (gap.ramps): on its branch (75590b7) the four profiles exact, every documented
# value inside its interval (bench/RESULTS.md "gap-profile17"): v2_5 velocity 2.4991 [2.4707,
# 2.5272] for 2.5, held-out 60.4 -> 0.65 mrad, 26 CPU-s; v1_5 1.5008 [1.4963, 1.5052], 248.1 ->
# 0.65, 49 s; v2_load 2.0018 [1.9900, 2.0132], 251.0 -> 0.91, 65 s; v3_a12 acceleration 11.84
# [11.47, 12.57] for 12 and velocity 3.05 for 3 with the whole search range [0.5, 50] as its
# interval (no move in its logs is long enough to cruise: the velocity never binds), 102.5 ->
# 0.86, 116 s. clean_bench and torque_limit_bench: the gate does not offer goal_profile there
# (slope 0.85; torque limit: slope 0.48 but speeds 2x apart by direction).
# Since gap-sig19 (session 24, gap.ramps.uncapped_velocity) a velocity no move reaches is reported
# as a lower bound: with v3_a12's recorded fit (3.05; 11.84 [11.47, 12.57]) the interval reads
# [2.90, 500] (the profile's fastest in its logs at 11.47 rad/s^2; 500 the search's limit) with
# the flag 'not identifiable above' and lower_bound_only set (the analysis not re-run).
MISSES: dict[str, str] = {}


@pytest.mark.parametrize("name", redteam_check.case_params(sim, FAST, MISSES))
def test_names_exactly_the_hidden_causes_with_intervals_holding_the_truth(name, tmp_path):
    redteam_check.assert_named_exactly(sim, name, tmp_path)


def test_truth_simulator_imports_nothing_from_the_project():
    names = redteam_check.imported_top_modules(HERE / "gap_truth_sim8.py")
    assert names <= {"__future__", "dataclasses", "json", "math", "pathlib", "mujoco",
                     "numpy"}, names


def test_the_truth_profile_is_the_e_manual_trapezoid():
    """The truth's own profile against hand numbers: a 1 rad step at 2 rad/s and 10 rad/s^2
    reaches the goal at v / a + d / v = 0.2 + 0.5 = 0.7 s (0.2 rad accelerating, 0.6 cruising,
    0.2 braking); with acceleration 0, at d / v = 0.5 s; with velocity 0, at once."""
    for vel, acc, arrive in ((2.0, 10.0, 0.7), (2.0, 0.0, 0.5), (0.0, 10.0, 0.0)):
        p, w, t = 0.0, 0.0, 0.0
        trace = {}
        while p < 1.0:
            p, w = sim.profile(p, w, 1.0, vel, acc, sim.TRUTH_DT)
            t += sim.TRUTH_DT
            trace[round(t, 6)] = p
        assert t <= max(arrive, sim.TRUTH_DT) + 1.5 * sim.TRUTH_DT, (vel, acc, t)
        if vel and acc:  # braking at 10 rad/s^2 into 0.7 s: 1 mrad short at 0.7 - sqrt(2e-3 / 10)
            near = min(k for k, x in trace.items() if x >= 1.0 - 1e-3)
            assert near == pytest.approx(0.7 - math.sqrt(2e-3 / 10.0), abs=0.002)
        else:
            assert t == pytest.approx(max(arrive, sim.TRUTH_DT), abs=0.002), (vel, acc, t)
        if vel and acc:
            assert trace[0.1] == pytest.approx(0.05, abs=1e-3)    # a t^2 / 2
            assert trace[0.35] == pytest.approx(0.5, abs=1e-3)    # cruising at 2 rad/s
            assert trace[0.6] == pytest.approx(0.95, abs=1e-3)    # braking


def _logs(case: sim.Case, seconds: float, tmp_path) -> list[dict[str, np.ndarray]]:
    files = sim.write_case(dataclasses.replace(case, durations=(seconds,) * 3), tmp_path)
    out = []
    for path in files["logs"]:
        head = pathlib.Path(path).read_text().splitlines()[0].split(",")
        a = np.genfromtxt(path, delimiter=",", skip_header=1)
        out.append({h: a[:, k] for k, h in enumerate(head)})
    return out


def test_the_logs_carry_what_a_user_logs_and_the_profile_shows(tmp_path):
    """Project CSV columns only, rows at 100 Hz within one 0.25 ms step of jitter, readings and
    goals on the 4096-tick grid; the logged goal is the raw goal (steps), while the joint of a
    profiled case moves at the profile velocity (median of its moving rows within 10 %) and
    the clean case's far faster (the servo's step response: several rad/s)."""
    peak = {}
    for name in ("clean_bench", "profile_v1_5_bench"):
        logs = _logs(sim.CASE_BY_NAME[name], 4.0, tmp_path / name)
        log = logs[0]
        dt = np.diff(log["time"])
        assert np.all(np.abs(dt - 0.01) <= sim.TRUTH_DT + 1e-9)
        for col in ("qpos:arm", "goal:m_arm"):
            np.testing.assert_allclose(log[col] / sim.TICK, np.round(log[col] / sim.TICK),
                                       atol=1e-4)
        assert sorted(log) == ["goal:m_arm", "qpos:arm", "time"]
        assert np.abs(np.diff(log["goal:m_arm"])).max() > 0.15  # the goal steps
        v = np.abs(np.concatenate([np.diff(x["qpos:arm"]) / np.diff(x["time"])
                                   for x in logs[:2]]))
        peak[name] = (float(v.max()), float(np.median(v[v > 0.75])))
    # the rectangle's jump in speed overshoots the servo (zeta 0.33) to at most 1.4x; moving,
    # it runs at the profile velocity
    assert peak["profile_v1_5_bench"][0] < 1.5 * 1.4, peak
    assert peak["profile_v1_5_bench"][1] == pytest.approx(1.5, rel=0.1), peak
    assert peak["clean_bench"][0] > 3.0 * 1.5, peak


def _mid_speed(t: np.ndarray, q: np.ndarray) -> float:
    """Mean speed [rad/s] over the middle half of a move (25 % to 75 % of the way)."""
    f = (q - q[0]) / (q[-1] - q[0])
    i25, i75 = np.argmax(f >= 0.25), np.argmax(f >= 0.75)
    return float(0.5 * (q[-1] - q[0]) / (t[i75] - t[i25]))


def test_the_profile_ramps_the_same_with_the_load_and_against_it():
    """04-sysid's signature ("ramped response independent of load"): on the loaded arm a 1 rad
    step with gravity and one against it move at the profile velocity both ways (mid-move speeds
    within 5 % of 2 rad/s; measured 2.07 / 1.99), while the torque-limited arm's speeds differ by
    direction (measured 9.9 / 3.8 rad/s)."""
    t = np.arange(0, 3.0, 0.01)
    tgt = np.where(t < 0.005, -0.5, np.where(t < 1.5, 0.5, -0.5))
    speeds = {}
    for name in ("profile_v2_load_bench", "torque_limit_bench"):
        q = sim.simulate(sim.CASE_BY_NAME[name], t, tgt, np.random.default_rng(0))["qpos:arm"]
        speeds[name] = (_mid_speed(t[:150], q[:150]), -_mid_speed(t[150:], q[150:]))
    for s in speeds["profile_v2_load_bench"]:
        assert s == pytest.approx(2.0, rel=0.05), speeds
    up, down = speeds["torque_limit_bench"]
    assert not math.isclose(up, down, rel_tol=0.3), speeds
