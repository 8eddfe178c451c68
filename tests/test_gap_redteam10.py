"""The gap analysis judged on a tenth independently written truth simulator: a user's 3-joint
D'Claw-like finger with hidden effects OUTSIDE the catalogue (issue 11; gap-sim11, session 24;
bench/RESULTS.md "gap-sim11").

``tests/gap_truth_sim10.py`` (mujoco + numpy only) writes the cases; each is analysed as the CLI
does (the user's MJCF, the log folder, the spelling's options) and graded by its ``score``:

- the clean case passes when nothing is named;
- the catalogue case (40 ms latency) when exactly ``latency`` is named with every joint's 95 %
  interval holding 40 ms;
- a case hiding an effect outside the catalogue passes when the report names no CONFIDENT WRONG
  cause, which is, exactly: nothing named; or only catalogue effects the case lists as the
  nearest stand-in for its effect (``gap_truth_sim10.NEAREST``, decided from the physics before
  any run: e.g. a torque limit for a supply that sags under load, dry friction for a tight
  spot); or other effects while the report itself says they do not explain the logs (its
  verdict or a cause's ``stand_in`` note reads "not explained", "partial stand-in", "may stand
  in"); a catalogue effect hidden beside it (25 ms latency) must be named too, its
  intervals holding the truth. And the report must carry the residual: the held-out RMSE left
  (``gain.extended_rmse``, or the nominal one's when nothing is named) and the noise floor,
  whose ratio the grade records (``residual_floors``).

Misses are strict xfails whose reason is the measured result; they fail (XPASS) when fixed and
must then lose their mark. Every analysis is slow (63-350 s CPU on the earlier sets); the
default tests check the truth's physics, the logs' spelling and the grade (a few s CPU).
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import sys

import numpy as np
import pytest

from lowcostdex.cli import main

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import gap_truth_sim10 as sim  # noqa: E402
import redteam_check  # noqa: E402

FAST: frozenset[str] = frozenset()

# what the analysis showed instead, per case it misses (``gap analyze --seed 0 --threads 1`` as
# the test runs it; CPU: the child's user + sys). Measured on main dd7d93a (session 24,
# gap-sim11; bench/gap_redteam10.py), every case passes: clean_finger nothing (0.66 mrad, 1.2
# floors, 23 s CPU); latency40_finger exact (40.2-40.3 ms, intervals hold 40; 104.6 -> 1.64
# mrad, 77 s); series_spring_base nothing ("not explained", 3.64 mrad = 6.4 floors; stopped at
# "train + select within 3 floors", 12 s); encoder_ripple_middle nothing (3.86 mrad, 7.1
# floors, 151 s); friction_drift_finger nothing (12.7 mrad, 22 floors: coulomb_friction kept by
# the backward search, dropped on its interval, 118 s); supply_sag_finger torque_limit 2.62-2.63
# N m, its nearest (7.81 -> 1.29 mrad, 2.2 floors, 130 s); tight_spot_middle gain_error flagged
# "no reliable gain ... at best a partial stand-in" (2.42 -> 3.76 mrad, 87 s). Then (same
# code): gear_spring_middle nothing (3.09 mrad, 5.2 floors, 111 s); the six-log cases nothing
# ("not explained"): tight spot 4.34 mrad 7.6 floors 157 s, ripple 1.56 / 2.8 / 165 s, series
# spring 1.40 / 2.6 / 216 s, friction drift 7.96 / 13.6 / 109 s. latency_friction_drift: latency
# 28.3 / 26.9 / 27.4 ms (intervals hold 25) alone, 75.8 -> 11.6 mrad (19.5 floors left; the
# verdict says "85 % lower" and nothing of what is left), 208 s. On main 8120f65:
# latency_gear_spring: latency 26.0 / 26.4 / 26.0 ms (intervals hold 25) + inertia_error 0.954
# on the middle [0.917, 0.992] (its nearest), 46.7 -> 4.17 mrad (7.2 floors), 208 s;
# latency_supply_sag: latency 25.5-25.8 ms (hold 25) + torque_limit 2.48 / 2.67 / 2.76 N m
# (its nearest; the truth's limit 2.33-2.74 with the load), 45.5 -> 0.98 mrad (1.7), 96 s.
# latency_tight_spot was a strict xfail on main bbea588 (a CONFIDENT WRONG name, fixed by
# standin.rival_notes, gap-sim11: the inertia_error now carries a 'may stand in' note):
_WAS = {
    "latency_tight_spot": "main bbea588, 172 s CPU: a CONFIDENT WRONG name: 'latency, "
    "inertia_error: held-out RMSE 0.03798 -> 0.001591 rad (96 % lower)', no flag. latency "
    "25.8 / 28.8 / 25.9 ms (intervals hold 25) and inertia_error 0.974 / 0.895 / 0.976, shown "
    "on the middle only ([0.828, 0.967]: the tight spot's joint) as its stand-in; held-out "
    "after latency alone 3.10 mrad, with the inertia 1.59 (3.0 floors left): the stand-in "
    "really lowers the held-out error, and the verdict judges the whole model's gain, which the "
    "true latency makes reliable (alone, tight_spot_middle's gain_error was worse on held-out "
    "and flagged). Nothing in the report tells a position-localised friction from an inertia",
}
# On the fix: latency_tight_spot passes flagged (179 s CPU in-process); latency_tight_spot_6logs
# names latency + coulomb_friction, its nearest (39.05 -> 5.07 mrad, 8.8 floors, 288 s).
MISSES: dict[str, str] = {}


def analyse(name: str, root: pathlib.Path) -> dict:
    files = sim.write_case(sim.CASE_BY_NAME[name], root / "data")
    out = root / "report"
    code = main(["gap", "analyze", "--model", files["model"], "--log", *files["logs"],
                 "--out", str(out), "--seed", "0", "--threads", "1", *files["args"]])
    assert code == 0, f"gap analyze exited {code} on {name}"
    return sim.score(json.loads((out / "report.json").read_text()), files["truth"])


@pytest.mark.parametrize("name", redteam_check.case_params(sim, FAST, MISSES))
def test_no_confident_wrong_cause_and_the_residual_reported(name, tmp_path):
    s = analyse(name, tmp_path)
    assert s["residual_floors"] is not None, s
    if sim.CASE_BY_NAME[name].outside:
        assert s["grade"].startswith("pass"), (
            f"{s['grade']}: named {s['named']} (not among the nearest: {s['wrong']}); "
            f"verdict: {s['verdict']}")
    else:
        assert s["result"] in ("exact", "clean"), (
            f"hidden {s['hidden'] or 'nothing'}, named {s['named'] or 'nothing'}")
    outside = [p for p in s["params"] if not p["inside"]]
    assert not outside, f"true values outside their 95 % intervals: {outside}"


def test_truth_simulator_imports_nothing_from_the_project():
    names = redteam_check.imported_top_modules(HERE / "gap_truth_sim10.py")
    assert names <= {"__future__", "dataclasses", "json", "math", "pathlib", "mujoco",
                     "numpy", "redteam_grade"}, names
    assert redteam_check.imported_top_modules(HERE / "redteam_grade.py") <= {"__future__"}


def _report(named: list[str], verdict: str = "", before: float = 0.01, after: float = 0.004,
            floor: float | None = 0.0006, notes: tuple[str, ...] = ()) -> dict:
    causes = [{"effect": n, "joints": list(sim.JOINTS), "stand_in": list(notes),
               "params": {"delay": {"value": [0.04] * 3,
                                    "interval": [[0.039, 0.041]] * 3}}} for n in named]
    return {"causes": causes, "verdict": verdict, "gain": {
        "baseline_rmse": before, "extended_rmse": after, "noise_floor": floor,
        "ci95": [0.001, 0.009]}}


def test_the_grade_on_hand_written_reports():
    """An outside case (a sagging supply: nearest torque_limit, voltage_sag, motor_strength)
    passes with nothing named, a nearest effect, or another effect the report flags; fails on an
    unflagged other effect or without the residual; the catalogue case is exact only with
    exactly its effect and its intervals are checked."""
    truth = json.loads(json.dumps({"causes": [], "outside": True,
                                   "nearest": sim.CASE_BY_NAME["supply_sag_finger"].nearest,
                                   "expected_params": []}))
    assert sim.score(_report([]), truth)["grade"] == "pass_nothing"
    assert sim.score(_report([]), truth)["residual_floors"] == pytest.approx(0.01 / 0.0006)
    assert sim.score(_report(["torque_limit"]), truth)["grade"] == "pass_nearest"
    s = sim.score(_report(["position_offset", "torque_limit"]), truth)
    assert (s["grade"], s["wrong"], s["result"]) == ("fail_wrong", ["position_offset"], "false")
    flagged = _report(["gain_error"], verdict="gain_error: no reliable gain (...): the extended "
                      "model is not recommended; the discrepancy is not explained (9x the "
                      "noise floor left): gain_error at best a partial stand-in")
    assert sim.score(flagged, truth)["grade"] == "pass_flagged"
    noted = _report(["position_offset"], notes=("may stand in for a centre-of-mass shift",))
    assert sim.score(noted, truth)["grade"] == "pass_flagged"
    assert sim.score(_report(["torque_limit"], floor=None), truth)["grade"] == \
        "fail_no_residual"
    mixed = {**truth, "causes": ["latency"]}
    assert sim.score(_report(["torque_limit"]), mixed)["grade"] == "fail_missed"
    assert sim.score(_report(["latency", "torque_limit"]), mixed)["grade"] == "pass_nearest"
    lat = sim.CASE_BY_NAME["latency40_finger"]
    truth = {"causes": sorted(lat.causes), "outside": False, "nearest": [],
             "expected_params": sim.expected_params(lat)}
    s = sim.score(_report(["latency"]), truth)
    assert s["result"] == "exact" and len(s["params"]) == 3 and all(
        p["inside"] for p in s["params"])
    assert sim.score(_report(["latency", "gain_error"]), truth)["result"] == "extra"
    assert sim.score(_report(["gain_error"]), truth)["result"] == "miss"
    clean = {"causes": [], "outside": False, "nearest": [], "expected_params": []}
    assert sim.score(_report([]), clean)["result"] == "clean"
    assert sim.score(_report(["gain_error"]), clean)["result"] == "false"


def _run(case: sim.Case, seconds: float, style: str = "steps", goals: dict | None = None,
         session: tuple[float, float] = (0.0, 1.0)) -> tuple[np.ndarray, dict]:
    rng = np.random.default_rng(0)
    t = sim.row_times(seconds, case.rate, rng)
    goals = goals or {j: sim.targets(j, style, t, rng) for j in sim.JOINTS}
    if callable(goals):
        goals = goals(t)
    return t, sim.simulate(case, t, goals, np.random.default_rng(1), session=session,
                           true_angles=True)


def test_each_hidden_effect_moves_its_reading():
    """Against the same goals without the effect (same seeds), each hidden effect moves the
    reading of the joint it sits on by more than the read floor (0.4 mrad noise + ticks: ~0.6
    mrad RMS) over 4 s of steps: measured latency 46-113, spring 4.9 (base), gear spring 5.6
    (middle), ripple 4.4 (middle), friction drift 5.8-6.8 (mid-session), supply sag 9.5 / 4.7
    (middle / distal) over 6 s, 10.9 on the distal over 4 s (the joints whose steps
    saturate), tight spot 9.6 mrad (middle); the joints without an effect of their own stay
    within a few floors (coupling through the links). Cases with two effects are left out."""
    for case in sim.CASES[1:]:
        if len(case.effects) > 1:
            continue
        _, clean = _run(dataclasses.replace(case, effects=()), 4.0, session=(6.0, 18.0))
        _, hidden = _run(case, 4.0, session=(6.0, 18.0))
        rms = {j: float(np.sqrt(np.mean((hidden[f"qpos:{j}"] - clean[f"qpos:{j}"]) ** 2)))
               for j in sim.JOINTS}
        e = case.effects[0]
        if e.kind == "supply_sag":   # on the joints whose steps saturate
            assert max(rms.values()) > 0.005, (case.name, rms)
            continue
        on = sim.JOINTS if e.kind in ("latency", "friction_drift") else (e.joint,)
        assert all(rms[j] > 0.0015 for j in on), (case.name, rms)
        assert all(rms[j] < 0.0015 for j in sim.JOINTS if j not in on), (case.name, rms)


def test_the_truth_physics_written_out():
    """Statics by hand, the finger straight below its mount (masses 80 / 80 / 30 g at 30, 90
    and 165 mm below the base axis: m g l = 0.1427 N m) and the base held at 0.3 rad:
    - series spring (2 N m/rad): the horn (what the log reads) rests at 0.3 - m g l sin(link)
      / kp and the link sags behind it by d, k d = -m g l sin(0.3 + d) (d = -19.7 mrad);
    - encoder ripple on the middle joint: at rest the log reads the true angle plus 20 mrad
      sin(4 q + 0.7);
    - supply sag (0.5 ohm): no servo delivers more than 3 / (1 + 0.5 x 3 / (12 x 1.3)) =
      2.737 N m (one servo at its limit alone), and when all three push at their limit each
      gets 3 / (1 + 3 x 0.5 x 3 / 15.6) = 2.33 N m."""
    mgl = 9.81 * (0.08 * 0.030 + 0.08 * 0.090 + 0.03 * 0.165)
    assert mgl == pytest.approx(0.1427, abs=1e-4)
    held = {"base": 0.3, "middle": 0.0, "distal": 0.0}
    t, out = _run(sim.CASE_BY_NAME["series_spring_base"], 3.0,
                  goals=lambda t: {j: np.full_like(t, held[j]) for j in sim.JOINTS})
    d = 0.0
    for _ in range(20):
        d = -mgl * math.sin(0.3 + d) / 2.0
    assert d == pytest.approx(-0.0197, abs=2e-4)
    rest = t > 1.5
    assert np.mean(out["true:base"][rest] - out["qpos:base"][rest]) == pytest.approx(d, abs=1e-3)
    horn = sim.TICK * round(0.3 / sim.TICK) - mgl * math.sin(0.3 + d) / sim.KP
    assert np.mean(out["qpos:base"][rest]) == pytest.approx(horn, abs=1e-3)

    case = sim.CASE_BY_NAME["encoder_ripple_middle"]
    t, out = _run(case, 4.0)
    a, n, phi = case.effects[0].values
    q = out["true:middle"]
    err = out["qpos:middle"] - q - a * np.sin(n * q + phi)
    assert np.sqrt(np.mean(err ** 2)) < 0.001
    assert np.sqrt(np.mean((out["qpos:middle"] - q) ** 2)) > 0.008

    case = sim.CASE_BY_NAME["supply_sag_finger"]
    big = {"base": (-0.4, 0.4), "middle": (-0.4, 1.2), "distal": (-0.4, 1.2)}
    _, out = _run(case, 3.0, goals=lambda t: {
        j: np.where((t % 1.0) < 0.5, *big[j]) for j in sim.JOINTS})
    force = np.abs(np.column_stack([out[f"force:{j}"] for j in sim.JOINTS]))
    r = case.effects[0].values[0]
    alone = sim.FORCE / (1 + r * sim.FORCE / (sim.V0 * sim.KT))
    three = sim.FORCE / (1 + 3 * r * sim.FORCE / (sim.V0 * sim.KT))
    assert alone == pytest.approx(2.737, abs=1e-3) and three == pytest.approx(2.33, abs=0.01)
    assert force.max() <= alone + 1e-3
    together = force.min(axis=1) > 2.0
    assert together.any()
    assert np.all(force[together] <= three + 0.01)


def test_the_logs_are_spelled_as_the_user_writes_them(tmp_path):
    """Degrees with integer millis() stamps of a clock that did not start at 0, or the project's
    radians and seconds; readings on the 4096-tick grid either way."""
    for name in ("encoder_ripple_middle", "clean_finger"):
        case = dataclasses.replace(sim.CASE_BY_NAME[name], durations=(1.0,))
        files = sim.write_case(case, tmp_path / name)
        path = pathlib.Path(files["logs"][0]) / "log0.csv"
        head = path.read_text().splitlines()[0].split(",")
        a = np.genfromtxt(path, delimiter=",", skip_header=1)
        log = {h: a[:, k] for k, h in enumerate(head)}
        scale = math.radians(1.0) if case.deg else 1.0
        for j in sim.JOINTS:
            ticks = log[f"qpos:{j}"] * scale / sim.TICK
            np.testing.assert_allclose(ticks, np.round(ticks), atol=2e-3)
            assert f"goal:{j}_servo" in head
        if case.ms:
            assert log["time"][0] > 9e4 and np.all(log["time"] == np.round(log["time"]))
            assert files["args"] == ["--units", "deg", "--time-unit", "ms"]
        else:
            assert log["time"][0] == 0.0 and files["args"] == []
        truth = json.loads((tmp_path / name / "truth.json").read_text())
        assert truth["outside"] == (name != "clean_finger")


def test_a_rival_of_another_mechanism_makes_the_name_a_stand_in():
    """sim10's latency_tight_spot, as measured (its report's round 2 on main bbea588):
    inertia_error was accepted at 15.41 % lower select error with viscous_damping at 14.46 %
    (94 % of it): the data do not tell an inertia from a damping (nor from the tight spot
    behind both), so the named inertia_error carries a 'may stand in' note, which the grade
    reads as a flag; the latency (98.68 %, the best rival 84.15 %: 85 %), an exact cause
    whose rivals explain most but leave far more (sim4's viscous damping) and a named rival
    carry none. Fails on the code before gap-sim11's change (no standin.rival_notes)."""
    from lowcostdex.gap import standin
    from lowcostdex.gap.results import CandidateResult, Cause

    def cand(name, gain, accepted=False):
        return CandidateResult(name, gain, fitted=True, select_gain=gain, accepted=accepted)

    rounds = [[cand("latency", 0.9868, True), cand("gearbox_friction", 0.8415),
               cand("load_dependent_friction", 0.8289)],
              [cand("stribeck_friction", 0.0558), cand("inertia_error", 0.1541, True),
               cand("viscous_damping", 0.1446), cand("velocity_limit", -22.8)]]
    causes = [Cause("latency", sim.JOINTS, {}), Cause("inertia_error", sim.JOINTS, {})]
    standin.rival_notes(causes, rounds)
    assert causes[0].stand_in == []
    assert len(causes[1].stand_in) == 1 and "viscous_damping 14.5 %" in causes[1].stand_in[0]
    report = {"causes": [{"effect": c.effect, "joints": list(c.joints), "params": {},
                          "stand_in": c.stand_in} for c in causes],
              "verdict": "latency, inertia_error: held-out RMSE 0.03798 -> 0.001591 rad (96 % "
                         "lower)",
              "gain": {"baseline_rmse": 0.03798, "extended_rmse": 0.001591,
                       "noise_floor": 0.00053}}
    truth = json.loads(json.dumps({"causes": ["latency"], "outside": True, "expected_params": [],
                                   "nearest": sim.CASE_BY_NAME["latency_tight_spot"].nearest}))
    assert sim.score(report, truth)["grade"] == "pass_flagged"
    # sim4 viscous_motor_posonly (exact, main c49b98b): viscous_damping 99.997 % with
    # load_dependent_friction 93.5 % and gearbox_friction 93.35 %: the rivals leave 2000x its
    # error, no tie (the first rule, gains alone, noted it)
    exact = [Cause("viscous_damping", ("hinge",), {})]
    standin.rival_notes(exact, [[cand("viscous_damping", 0.99997, True),
                                 cand("load_dependent_friction", 0.935),
                                 cand("gearbox_friction", 0.9335)]])
    assert exact[0].stand_in == []
    named = [Cause("latency", sim.JOINTS, {}), Cause("inertia_error", sim.JOINTS, {}),
             Cause("viscous_damping", sim.JOINTS, {})]
    standin.rival_notes(named, rounds)
    assert all(c.stand_in == [] for c in named)


def _replayed(name: str, root: pathlib.Path, latency: float = 0.0) -> tuple:
    """Case ``name``'s logs replayed open loop by the user's model at 1 ms (the analysis refines
    the model's 2 ms step for this rig; at 2 ms latency40's exact model leaves 3.00 floors, at 1
    ms 2.1) with the truth's catalogue part only (``latency`` [s] on every servo): each log one
    episode. Returns (per-log rows, the gain over the logs, the noise floor [rad])."""
    from lowcostdex.gap.dataset import episodes, load_dataset
    from lowcostdex.gap.diagnostics import noise_floor, per_log
    from lowcostdex.gap.gain import gain_with_ci
    from lowcostdex.gap.replay import Replayer
    from lowcostdex.gap.selection import mse_by_episode
    from lowcostdex.sim.effects import AppliedEffect

    case = sim.CASE_BY_NAME[name]
    files = sim.write_case(case, root / name)
    ds = load_dataset(files["logs"][0], files["model"], angle_unit="deg" if case.deg else "rad",
                      time_unit="ms" if case.ms else "s").with_timestep(0.5)
    eps = episodes(ds)
    effects = [AppliedEffect("latency", ds.effect_joints, {"delay": latency})] if latency else []
    nominal, named = Replayer(ds, ["latency"], nthread=1).run(eps, [[], effects])[0]
    floor = float(np.sqrt(np.mean(noise_floor(ds.trajectories) ** 2)))
    b, e = mse_by_episode(ds, eps, nominal), mse_by_episode(ds, eps, named)
    gain = gain_with_ci(b[0], e[0], b[2], b[1], e[1], floor ** 2, np.random.default_rng(0), 200)
    return per_log(ds, eps, named), gain, floor


def test_the_verdict_says_what_the_named_causes_leave_and_a_drift(tmp_path):
    """With the truth's catalogue part as the named cause (the true latency; nothing on the
    clean and drift-only cases), the project's replay of sim10's logs leaves (measured, 1 ms):
    clean 1.46 floors, latency40 (exact) 2.14: within the 3 floors an exact model's replay
    leaves; beside an effect outside the catalogue the true 25 ms leaves 13.4 floors (friction
    rising 4x over the session), 8.2 (a tight spot), 7.7 (a sagging supply): well above, and the
    verdict says so ("named X; 0.8 mrad left, at the floor" vs "named X; 12 mrad left, something
    else"). The logs of the sessions whose friction rises fit consistently worse in file order
    (3 logs; tau 1, the later half 4.1-4.2x the earlier): a drift note; none on the others
    (tau <= 0.33). ~4 s CPU. Fails before gap-sim12 (no
    standin.residual_left, diagnostics.session_drift)."""
    from lowcostdex.gap import standin
    from lowcostdex.gap.diagnostics import session_drift
    from lowcostdex.gap.results import Cause

    cases = {"clean_finger": (0.0, True, False), "latency40_finger": (0.040, True, False),
             "friction_drift_finger": (0.0, False, True),
             "latency_friction_drift": (0.025, False, True),
             "latency_tight_spot": (0.025, False, False),
             "latency_supply_sag": (0.025, False, False)}
    for name, (latency, at_floor, drifts) in cases.items():
        logs, gain, floor = _replayed(name, tmp_path, latency)
        left = standin.residual_left(gain)
        assert left["at_floor"] is at_floor, (name, left)
        assert left["floors"] < 2.5 if at_floor else left["floors"] > 6.0, (name, left)
        assert left["rmse"] == gain.extended_rmse and left["noise_floor"] == gain.noise_floor
        drift = session_drift(logs, floor)
        assert bool(drift["note"]) is drifts, (name, drift)
        assert drift["order"] == "file order"  # each log's clock starts again (0 s or 97.5 s)
        if latency:
            causes = [Cause("latency", sim.JOINTS, {})]
            text = standin.judge(causes, None, gain, "x", drift_note=drift["note"])
            assert text.startswith("latency: held-out RMSE") and f"{left['floors']:.3g}x" in text
            assert ("within the 3 floors" in text) is at_floor, text
            assert ("something beyond the named causes" in text) is not at_floor, text
            assert ("drift over the session" in text) is drifts, text
            if not at_floor:  # the sim10 grader's words for a flag are not what this adds
                assert not any(f in text for f in sim.FLAGS), text
    # a non-drift six-log case whose logs alternate (steps / sines) far apart: no note
    logs, _, floor = _replayed("tight_spot_middle_6logs", tmp_path)
    assert not session_drift(logs, floor)["note"], logs


def test_the_drift_test_orders_logs_by_a_shared_clock():
    """Logs given out of order but stamped by one clock are ordered by time; a clock starting
    again at every log keeps the file order; fewer than 3 logs are not judged; a rise that stays
    within the exact-model floors is no drift."""
    from lowcostdex.gap.diagnostics import kendall_tau, session_drift

    def log(name, start, rmse):
        return {"log": f"/data/{name}.csv", "start": start, "stop": start + 5.0, "rmse": rmse}

    shuffled = [log("b", 10.0, 0.004), log("c", 20.0, 0.008), log("a", 0.0, 0.002)]
    d = session_drift(shuffled, 0.0005)
    assert d["order"] == "time stamps" and [x["log"][-5] for x in d["logs"]] == ["a", "b", "c"]
    assert d["tau"] == 1.0 and d["ratio"] == pytest.approx(4.0)
    assert "a.csv 4, b.csv 8, c.csv 16" in d["note"] and "time stamps" in d["note"]
    restarts = [log("b", 0.0, 0.004), log("c", 0.0, 0.008), log("a", 0.0, 0.002)]
    d = session_drift(restarts, 0.0005)
    assert d["order"] == "file order" and d["tau"] == pytest.approx(-1 / 3) and not d["note"]
    assert not session_drift(shuffled[:2], 0.0005)["note"]
    assert session_drift(shuffled[:2], 0.0005)["tau"] is None
    assert not session_drift(shuffled, 0.003)["note"]  # a rise of 2 floors: within 3
    # sim6 deadband_torque's final model (deadband, exact; gap-sig19's report): 2.4 / 2.9 / 3.5
    # floors, tau 1, 1.48x: a rise of 1.1 floors is no drift, even at a ratio of 1.5
    near = [log("a", 0.0, 2.4), log("b", 10.0, 2.9), log("c", 20.0, 3.6)]
    d = session_drift(near, 1.0)
    assert d["tau"] == 1.0 and d["ratio"] == pytest.approx(1.5) and not d["note"]
    assert kendall_tau([1.0, 2.0, 2.0]) == pytest.approx(2 / 3)


# the whole analysis (``gap analyze`` as the CLI runs it): what its report says is left and
# whether it notes a drift (measured on gap-sim12's code, bench/RESULTS.md "gap-sim12")
LEFT = {"clean_finger": (True, False), "latency40_finger": (True, False),
        "friction_drift_finger": (False, True), "latency_friction_drift": (False, True)}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(LEFT))
def test_the_report_states_the_residual_and_the_drift(name, tmp_path):
    at_floor, drifts = LEFT[name]
    files = sim.write_case(sim.CASE_BY_NAME[name], tmp_path / "data")
    assert main(["gap", "analyze", "--model", files["model"], "--log", *files["logs"], "--out",
                 str(tmp_path / "report"), "--seed", "0", "--threads", "1", *files["args"]]) == 0
    rep = json.loads((tmp_path / "report" / "report.json").read_text())
    left, g = rep["residual"], rep["gain"]
    assert left["rmse"] == g["extended_rmse"] and left["noise_floor"] == g["noise_floor"]
    assert left["at_floor"] is at_floor and (left["floors"] <= 3.0) is at_floor, left
    assert bool(rep["drift"]["note"]) is drifts, rep["drift"]
    assert ("drift over the session" in rep["verdict"]) is drifts, rep["verdict"]
    if rep["causes"]:
        assert ("something beyond the named causes" in rep["verdict"]) is not at_floor
    md = (tmp_path / "report" / "report.md").read_text()
    assert f"Left on held-out: {1e3 * left['rmse']:.3g} mrad RMSE" in md
    assert "Open-loop RMSE per log in file order [mrad]: log0.csv" in md
    assert ("Drift over the session" in md) is drifts
