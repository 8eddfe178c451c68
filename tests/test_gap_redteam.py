"""The gap analysis judged on a second, independently written truth simulator (issue 11, redteam).

``tests/gap_truth_sim2.py`` was written without reading the analyzer, its effect catalogue or the
first truth simulator: plain MuJoCo rigs (a pendulum with a ``position`` kp-only actuator and a
force range, a 2-link arm with ``general`` position servos, a vertical-axis turntable with kp+kv
and no force range), hidden effects implemented there from their physics at real-world sizes,
and logs as a user would bring them (50-200 Hz, jittery rows, a host stall, position-only logs).
Each case is analysed as the CLI does (``lowcostdex gap analyze --model ... --log ... --out ...
--seed 0 --threads 2``) and its report.json scored by ``gap_truth_sim2.score``: the named
causes must be exactly the hidden ones (catalogue names; nothing on a clean case), and every
parameter whose meaning the docs make plain must lie inside its reported 95 % interval.

The truth comes from outside the code under test: the rigs, effects and expected parameters are
this folder's own physics. Cases the analysis misses today are strict xfails whose reason says
what it named instead (``bench/gap_redteam.py`` run of 2026-11-26, bench/RESULTS.md); they flip
to a failure (XPASS) when fixed, and must then lose their mark. The default run holds the cases
that are cheap; each analysis takes 1-3 min of CPU, so the rest are ``slow``.
"""

from __future__ import annotations

import json
import pathlib
import sys

import pytest

from lowcostdex.cli import main

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import gap_truth_sim2 as sim  # noqa: E402

# in the default run (the rest are slow). clean_pendulum was a documented miss (the 2 ms replay
# step named as viscous_damping +0.0021); clean since GapConfig.refine_step (gap-fix,
# 2026-11-26: analysed at 0.25 ms, no cause, 1110 s through bench/gap_redteam.py at load 16-19)
FAST = ("latency_queue_pendulum", "clean_pendulum")
# inertia_pendulum_200hz was a miss (inertia 1.785 [1.774, 1.796] plus spurious coulomb and a
# backlash through 0); since gap-extras' significance checks (2026-11-26, /tmp/ge run through
# bench/gap_redteam.py, 363 s at load ~9): inertia_error 1.790 [1.781, 1.814] alone;
# torque_limit_turntable's interval excluded 1.5 N m ([1.488, 1.496]); now 1.492 [1.488, 1.503];
# latency_coulomb_pendulum (latency 26.0 ms [25.5, 26.5] plus inertia_error): latency 25.2 ms
# [24.3, 26.1] and coulomb 0.1055 [0.0909, 0.1138] N m alone; mass_arm2 (plus torque_limit
# 0.596 = the nominal forcerange, inertia_error, load friction): mass_error 1.593 [1.549, 1.623]
# / 1.602 [1.598, 1.609] alone; viscous_mj_pendulum_200hz (0.0985 [0.0976, 0.0994] plus gain
# and inertia errors): viscous_damping 0.1021 [0.0972, 0.1051] alone; gain_low_pendulum_posonly
# (plus viscous_damping +0.0019 that raised the held-out RMSE 1.56 -> 1.82 mrad): gain_error
# 0.5963 [0.5944, 0.6016] alone, held-out 1.46 mrad; latency_7ms_turntable_200hz (7.49 ms
# [7.24, 7.74] plus inertia_error): latency 7.35 ms [6.88, 7.51] alone. (Measured with the
# interval spanning the fitted and the Richardson value; the landed symmetric form, recomputed
# from each report's value, data interval and step shift, holds these truths too.)
# coulomb_mj_turntable was coulomb_friction 0.0802 plus load_dependent_friction mu 0.032 and
# gain_error 1.013, reading_offset_arm2 position_offset plus a spurious load_dependent_friction
# (mu 0.0043 / 0.0086); re-run on main 9b54389 (gap-fric2, session 9, bench/gap_redteam.py
# --threads 1): coulomb_friction 0.0809 [0.0790, 0.0828] alone, held-out 17.57 -> 0.95 mrad,
# 225 s; position_offset 0.05237 [0.05231, 0.05242] / -0.03489 [-0.03496, -0.03481] alone,
# held-out 44.66 -> 0.80 mrad, 1414 s wall at load 17.
# Re-run on main c3ff5c5 (gap-offset, 2026-11-26 session 8, bench/gap_redteam.py --threads 1,
# load ~1): clean_mounting_vertical (was a false load_dependent_friction) names nothing, 10 s
# (gap-select's explain_above); gain_high_arm2_50hz (was gain_error 1.846 [1.820, 1.872] plus
# backlash and coulomb_friction that raised the held-out RMSE) is exact, 1.805 [1.796, 1.815]
# / 1.797 [1.793, 1.801], 63 s. mounting_offset_pendulum (position_offset 0.0048 alone: at the
# model's 2 ms step the 4 deg mounting offset fits worse, train RMSE 3.38 vs 2.52 mrad; at 1 ms
# better, 1.78 vs 2.16) is exact since the first cause is chosen again at the refined step:
# mounting_offset 0.0729 [0.0671, 0.0786], held-out 4.79 -> 0.95 mrad, 34 s.

# backlash_body_pendulum was 'interval' (width 0.02710 [0.02649, 0.02771] for 0.02618, sensor
# 0.035: the truth's goals act from its next 0.25 ms physics step, a 0.125 ms mean lag the sensor
# and width soaked up); since gates.hold_sensor (gap-play4, session 11: the sensor held at 0,
# freeing it lowered the training cost 6.1 % as replayed, 0.1 % with goals half a step later):
# backlash width 0.02629 [0.02610, 0.02648] alone, held-out 12.21 -> 0.77 mrad, 253 s CPU.

# torque_coulomb_pendulum (was torque_limit 1.086 [1.042, 1.133] alone: the sticking Coulomb
# taken as a static-0 Stribeck, then dropped) is exact since gap-fric3 (session 10,
# gates.drop_weak: the Stribeck refitted as its nested Coulomb): torque_limit 1.205 [1.195,
# 1.215], coulomb_friction 0.1057 [0.0951, 0.1163]; held-out 305.8 -> 1.78 mrad, 89 s wall.

# gain_viscous_turntable (gap-fric3, session 10: named exactly since gates.swap_equivalent, but
# gain 0.6989 [0.6981, 0.6998] missed 0.7: the truth acts on a goal at its next 0.25 ms step, a
# lag the 1 ms replay cannot resolve) holds both since stepsize.goal_timing (gap-truth7, session
# 14, 130 s wall): gain 0.6989 [0.6981, 0.7316], viscous 0.0807 [0.0789, 0.0915].

# backlash_output_pendulum was 'extra' (width 0.0181 [0.0146, 0.0219] for 0.0436 plus
# inertia_error 0.909 and coulomb_friction 0.016) and backlash_output_damped_pendulum 'interval'
# (width 0.0224 [0.0178, 0.0252]): the catalogue's play kept the joint's damping on the rotor's
# rate while this servo's D reads the output, outside its force range; replayed at the true width
# the play was worse than the nominal (12.6-15.4 vs 6.4-7.7 mrad per episode at 2 ms). With the
# nominal joint damping read across the play with ``sensor`` (gap-bl9, session 15: 1.7-2.1 mrad
# at 2 ms, 0.8-1.0 at 0.25 ms): both exact, width 0.04541 [0.0421, 0.04564], held-out 5.73 ->
# 0.90 mrad (floor 0.71); damped: width 0.04409 [0.03466, 0.04631], viscous 0.2500 [0.2431,
# 0.2508], held-out 155.4 -> 1.55 mrad (floor 0.70); the two cases 562 s CPU, 36 min wall at
# load 8-13.

# queue_mass_arm2_posonly (a 30 ms goal queue + every link x1.5, position-only logs) was torque_limit +
# latency + backlash (held-out 173.4 -> 30.3 mrad): round 1 took the torque limit for the heavier arm and
# a play stood in for its sag; the mass, ranked 10th at the nominal model, never won a round. Exact
# since gap.exchange (gap-mass9, session 15, 634 s CPU): mass_error 1.488 [1.281, 1.727] / 1.5005
# [1.448, 1.555], latency 33.4 [27.2, 37.7] / 30.3 [26.3, 32.2] ms, held-out 173.4 -> 7.75 mrad.

# backlash_offset_pendulum_stall was 'interval' from 4fc78c0 (session 15) to session 25 (found by
# the lead's bisect, 8a454c1): width 0.03872 [0.03510, 0.04485] for 0.03491, the sensor free at
# 0.105. Since 4fc78c0 the sensor also puts the joint's damping on the play's rate, and freeing it
# lowered the training cost 8.4 % as replayed and still 6.1 % with goals half a 2 ms step late
# (15.4 % and -0.04 % with that damping term off): the late test no longer held it. At a 4x finer
# step (0.5 ms: the play contact as stiff as the truth's) the held sensor fits better (-1.4 %).
# Since gap-hold21 (session 26, gates.hold_sensor's second try at a 0.25x step, goals half of it
# late: 0.1 %): held, exact, width 0.0346 [0.03227, 0.03559], offset -0.05235 [-0.05271,
# -0.05198] for -0.05236, 114 s CPU (nice'd, load 5).

# what the analysis named instead, per case it misses (bench/gap_redteam.py, 2026-11-26)
MISSES: dict[str, str] = {
    # queue_mass_arm2_posonly passed on main 3783eb4 (lead, session 16, 795 s CPU; gap-mass11's
    # prune_refitted): mass 1.491 / 1.500, latency 33.4 / 30.3 ms, inside; held-out 173.4 -> 7.63 mrad
}


def _params():
    for case in sim.CASES:
        marks = []
        if case.name not in FAST:
            marks.append(pytest.mark.slow)
        if case.name in MISSES:
            marks.append(pytest.mark.xfail(strict=True, reason=MISSES[case.name]))
        yield pytest.param(case.name, marks=marks, id=case.name)


def analyze_case(name: str, root: pathlib.Path) -> dict:
    """Write the case's model and logs, run ``gap analyze`` on them as a user would, score."""
    files = sim.write_case(sim.CASE_BY_NAME[name], root / "data")
    out = root / "report"
    code = main(["gap", "analyze", "--model", files["model"], "--log", *files["logs"],
                 "--out", str(out), "--seed", "0", "--threads", "2"])
    assert code == 0, f"gap analyze exited {code} on {name}"
    return sim.score(json.loads((out / "report.json").read_text()), files["truth"])


@pytest.mark.parametrize("name", list(_params()))
def test_names_exactly_the_hidden_causes_with_intervals_holding_the_truth(name, tmp_path):
    s = analyze_case(name, tmp_path)
    assert s["result"] in ("exact", "clean"), (
        f"hidden {s['hidden'] or 'nothing'}, named {s['named'] or 'nothing'}")
    outside = [p for p in s["params"] if not p["inside"]]
    assert not outside, f"true values outside their 95 % intervals: {outside}"


def test_scoring_tells_exact_family_miss_and_false_apart():
    """The scorer itself, on hand-written reports (so a wrong scorer cannot pass the cases)."""
    truth = {"causes": ["latency"], "expected_params": [
        dict(effect="latency", param="delay", joint="j", value=0.02, abs=False)]}

    def rep(*causes):
        return {"causes": [{"effect": c, "joints": ["j"], "params": {
            "delay": {"value": [0.021], "interval": [[0.019, 0.022]]}}} for c in causes]}

    s = sim.score(rep("latency"), truth)
    assert s["result"] == "exact" and s["params"][0]["inside"]
    assert sim.score(rep("latency", "backlash"), truth)["result"] == "extra"
    assert sim.score(rep("backlash"), truth)["result"] == "miss"
    assert sim.score(rep(), truth)["result"] == "miss"
    fam = {"causes": ["coulomb_friction"], "expected_params": []}
    assert sim.score(rep("stribeck_friction"), fam)["result"] == "family"
    assert sim.score(rep("stribeck_friction", "latency"), fam)["result"] == "miss"
    clean = {"causes": [], "expected_params": []}
    assert sim.score(rep(), clean)["result"] == "clean"
    assert sim.score(rep("viscous_damping"), clean)["result"] == "false"
    # a hidden effect the logs cannot show (a mounting offset on a vertical axis) is scored
    # as a clean case: its truth lists no cause, naming one is a false discovery
    case = sim.CASE_BY_NAME["clean_mounting_vertical"]
    assert not case.observable and case.effects and case.causes == set()
    assert all(c.observable for c in sim.CASES if c.name != "clean_mounting_vertical")
    # an offset's sign convention is not documented: magnitudes are compared
    off = {"causes": ["position_offset"], "expected_params": [
        dict(effect="position_offset", param="offset", joint="j", value=0.05, abs=True)]}
    r = {"causes": [{"effect": "position_offset", "joints": ["j"], "params": {
        "offset": {"value": [-0.049], "interval": [[-0.052, -0.046]]}}}]}
    assert sim.score(r, off)["params"][0]["inside"]
    r["causes"][0]["params"]["offset"]["interval"] = [[-0.049, -0.048]]
    assert not sim.score(r, off)["params"][0]["inside"]


def test_truth_simulator_effects_are_physical():
    """The hidden effects act as written: a reading offset shifts every read by its size, a
    mounting offset on a vertical axis changes nothing observable, a latency queue delays the
    response by whole control periods (checked on the simulator alone, no analysis)."""
    import numpy as np

    rng = np.random.default_rng(0)
    t = sim.row_times(3.0, 100.0, 0.0, 0.0, rng)
    g = sim.goals("steps", t, np.array([-1.0]), np.array([1.0]), rng)
    base = sim.Case("b", "turntable")

    def run(case):
        return sim.simulate(case, t, g, np.random.default_rng(1))[0][:, 0]

    q0 = run(base)
    off = run(sim.Case("o", "turntable", (sim.Effect("reading_offset", 0.05),)))
    assert np.median(off - q0) == pytest.approx(0.05, abs=sim.TICK)
    mount = run(sim.Case("m", "turntable", (sim.Effect("mounting_offset", 0.05),)))
    assert np.abs(mount - q0).max() <= 2 * sim.TICK
    late = run(sim.Case("l", "turntable", (sim.Effect("latency_queue", 3),)))
    # the delayed response matches the undelayed one 3 rows (30 ms) later, not before
    err = [np.sqrt(np.mean((late[k:] - q0[:len(q0) - k]) ** 2)) for k in range(6)]
    assert int(np.argmin(err)) == 3


def test_output_loop_damps_once():
    """``backlash_output``'s own servo loop puts the joint's damping on the output velocity once,
    outside the force range, as the nominal rig's joint damping acts: with a play of 0.1 mrad the
    truth is MuJoCo's own ``position`` actuator on the damped hinge (the nominal rig, no loop of
    this module) to within a tick, and with ``viscous_mj`` 0.25 beside it, the nominal hinge
    with 0.25 N m s/rad more damping. Until session 14 the motor joint kept its damping too and
    the loop's D sat inside the clip: 53 mrad RMS from the nominal on these steps."""
    import numpy as np

    rng = np.random.default_rng(0)
    t = sim.row_times(4.0, 100.0, 0.0, 0.0, rng)
    g = sim.goals("steps", t, np.array([-1.0]), np.array([1.0]), rng)

    def run(*effects):
        return sim.simulate(sim.Case("c", "pendulum", effects), t, g,
                            np.random.default_rng(1))[0][:, 0]

    def rms(a, b):
        return float(np.sqrt(np.mean((a - b) ** 2)))

    play = sim.Effect("backlash_output", 1e-4)
    nominal, damped = run(), run(sim.Effect("viscous_mj", 0.25))
    assert rms(run(play), nominal) < sim.TICK
    assert rms(run(play, sim.Effect("viscous_mj", 0.25)), damped) < sim.TICK
    assert rms(damped, nominal) > 30 * sim.TICK  # the extra damping is plain in these logs
