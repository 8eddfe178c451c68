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

FAST: frozenset[str] = frozenset()

# what the analysis named instead, per case it misses (``gap analyze --seed 0 --threads 1``, as
# the test runs it). Measured on main 441707b (session 21, gap-profile16), goal_profile not yet
# a default candidate; profile_v1_5_bench (a slower rectangle) was not analysed there.
# With goal_profile a default cause (branch gap-profile16-causes, not landed: +12.9 % CPU on
# tests/test_gap_independent_bench.py) all six cases were exact or clean, every documented value
# inside its interval (bench/RESULTS.md gap-profile16): the misses below are goal_profile not
# being offered by default, not a wrong model of the profile.
MISSES: dict[str, str] = {
    "profile_v2_5_bench": "main 441707b, 44 CPU-s: velocity_limit (speed 2.41 rad/s, interval "
    "[2.27, 2.57]) for the 2.5 rad/s profile, held-out 60.4 -> 11.9 mrad (family)",
    "profile_v3_a12_bench": "main 441707b, 102 CPU-s: velocity_limit (speed 2.33) + latency "
    "(91 ms) for the 3 rad/s, 12 rad/s^2 trapezoid, held-out 102.5 -> 28.7 mrad (family)",
    "profile_v2_load_bench": "main 441707b, 75 CPU-s: velocity_limit (speed 1.91) for the 2 rad/s "
    "profile on the loaded arm, held-out 251.5 -> 81.3 mrad (family)",
    "profile_v1_5_bench": "not analysed on main 441707b (CPU budget); goal_profile is not a "
    "default candidate there, so it cannot be named (v2_5 and v2_load: velocity_limit)",
}


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
