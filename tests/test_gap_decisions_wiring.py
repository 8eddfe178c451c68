"""What ``analyze._analyze`` hands each stage and the user: settings, progress, timing, widening.

The stand-in engine of ``test_gap_decisions_loop`` (a model replays as the sum of value x
pattern of its effects; patterns orthogonal over an episode) with every stand-in recording the
arguments it was called with. A user's settings must reach the stage they set (the episode chunk,
the held-out logs, the segment length and burn-in, the candidate list), the progress callback
names each stage with a fraction done that follows the documented schedule (round k's ranking at
0.1 + 0.25 (k - 1), its LM round r at + 0.2 r / max_rounds, the joint refit at + 0.2, the
backward search 0.8, the final refit 0.85, the held-out test 0.95, done 1.0), and the report's
timings are wall seconds of the stages, each within the total. No MuJoCo: milliseconds a test.
"""

from __future__ import annotations

import dataclasses
import math
import re
import time

import numpy as np
import pytest
from test_gap_decisions_backward import NOISE, P_A, P_B
from test_gap_decisions_loop import AZ, EPS, make_loop

SCORES = {"position_offset": 0.7, "mounting_offset": 0.6}
LM = re.compile(r"round (\d+): fitting (\d+) tracks \(LM round (\d+)\)")


@pytest.fixture
def loop(monkeypatch):
    """``_analyze`` on the stand-in engine (``test_gap_decisions_loop.make_loop``)."""
    return make_loop(monkeypatch)


def _schedule(calls: list[tuple[str, float]], max_rounds: int = 20) -> list[tuple[str, float]]:
    """The progress calls with the LM rounds' lines checked against the documented fraction
    (0.1 + 0.25 (k - 1) + 0.2 r / max_rounds) and left out."""
    out = []
    for stage, frac in calls:
        assert 0.0 <= frac <= 1.0, (stage, frac)
        m = LM.fullmatch(stage)
        if m:
            k, r = int(m.group(1)), int(m.group(3))
            assert frac == pytest.approx(0.1 + 0.25 * (k - 1) + 0.2 * r / max_rounds), stage
            continue
        out.append((stage, pytest.approx(frac)))
    return out


def test_progress_names_each_stage_with_its_scheduled_fraction(loop):
    # two real offsets: round 1 fits both candidates (2 tracks), round 2 the one left (1 track)
    # and its joint refit with the first; then the final refit, the held-out test
    calls = []
    res = loop(0.05, 0.03, 0.01, floor=0.001, scores=SCORES,
               prog=lambda s, f: calls.append((s, f)))
    assert [c.effect for c in res.causes] == ["position_offset", "mounting_offset"]
    assert _schedule(calls) == [
        ("baseline replay", 0.02),
        ("round 1: ranking 2 candidates", 0.1),
        ("round 2: ranking 1 candidates", 0.35),
        ("round 2: joint refit of 1 candidates", 0.55),
        ("final refit on train + select", 0.85),
        ("held-out test", 0.95),
        ("done", 1.0)]
    fits = [LM.fullmatch(s).groups() for s, _ in calls if LM.fullmatch(s)]
    assert {(k, n) for k, n, _ in fits} == {("1", "2"), ("2", "1")}  # tracks per round
    assert all(r == "1" for k, n, r in fits[:1])  # LM rounds counted from 1


def test_progress_of_a_backward_search(loop):
    # the forward steps stop in round 2 (mounting_offset's score 0.01 < min_gain); the backward
    # search (0.8) then fits both together; with two causes kept above backward_above noise
    # floors, each is tried against the others in its place (the exchange step, 0.82)
    calls = []
    loop(0.05, 0.03, 0.01, floor=0.001, search="both",
         scores={"position_offset": 0.9, "mounting_offset": [0.5, 0.01]},
         prog=lambda s, f: calls.append((s, f)))
    assert _schedule(calls) == [
        ("baseline replay", 0.02),
        ("round 1: ranking 2 candidates", 0.1),
        ("round 2: ranking 1 candidates", 0.35),
        ("backward search from the top candidates", 0.8),
        ("exchange: each accepted cause against what the model without it needs", 0.82),
        ("final refit on train + select", 0.85),
        ("held-out test", 0.95),
        ("done", 1.0)]


def test_timings_are_wall_seconds_of_each_stage_within_the_total(loop):
    t0 = time.perf_counter()
    res = loop(0.05, 0.03, 0.01, floor=0.001, scores=SCORES)
    wall = time.perf_counter() - t0
    tm = res.timing
    assert set(tm) == {"baseline", "round1", "round2", "final_fit", "total"}
    assert all(isinstance(v, float) and v >= 0 for v in tm.values())
    assert tm["total"] <= wall
    # the stages run one after the other inside the total
    assert tm["baseline"] + tm["round1"] + tm["round2"] + tm["final_fit"] <= tm["total"]
    # the round that stops the selection is timed too; a backward search has its own entry, and
    # so has the exchange step after it (two causes above backward_above noise floors)
    res = loop(0.05, 0.03, 0.01, floor=0.001, search="both",
               scores={"position_offset": 0.9, "mounting_offset": [0.5, 0.01]})
    tm = res.timing
    assert set(tm) == {"baseline", "round1", "backward_search", "exchange", "final_fit", "total"}
    assert (tm["baseline"] + tm["round1"] + tm["backward_search"] + tm["exchange"]
            + tm["final_fit"] <= tm["total"])
    assert all(v >= 0 for v in tm.values())


def test_a_users_settings_reach_the_stage_they_set(loop):
    seen, prog = {}, (lambda s, f: None)
    res = loop(0.05, 0.03, 0.01, floor=0.001, scores=SCORES, seen=seen, prog=prog,
               chunk=0.5, test_logs=(2,), segment=0.8, burn_in=0.05,
               candidates=("position_offset", "mounting_offset"))
    ds = seen["ds"]
    assert seen["episodes"] == [(ds, 0.5)]
    ((d, eps, rng, test_logs),) = seen["split_episodes"]
    assert d is ds and eps == EPS and isinstance(rng, np.random.Generator) and test_logs == (2,)
    assert seen["available_candidates"] == [(ds, ("position_offset", "mounting_offset"))]
    # training segments from the train episode, the final refit's from train + select
    assert seen["segments"] == [(ds, [EPS[0]], 0.8, 0.05), (ds, [EPS[0], EPS[1]], 0.8, 0.05)]
    assert seen["noise_floor"] == [(ds.trajectories,)]
    # the nominal replay (every pattern at 0: zeros) of all three episodes, joint column 0
    ((trajs, eps, base, col),) = seen["residual_diagnostics"]
    assert trajs is ds.trajectories and eps == EPS and col == 0
    assert len(base) == 3 and all(np.array_equal(b, np.zeros((40, 1))) for b in base)
    assert res.diagnostics == {"j0": {"lag": 0.0}}
    # the first model's actuators, resolved for the effect joints
    ((model, joints),) = seen["Targets.resolve"]
    assert joints == ("j0",) and model.dof_damping.tolist() == [0.1]
    ((d, targets, m),) = seen["_act_cols"]
    assert d is ds and m is model and targets.actuators.tolist() == [0]
    ((m, acts),) = seen["stall_torque"]
    assert m is model and acts.tolist() == [0]
    ((m, acts),) = seen["dcmotor_mask"]
    assert m is model and acts.tolist() == [0]
    # the fit context: the log's step, the nominal replay's peak force (the stand-in's 1.0 at
    # column 0), the stall torque, the model's damping
    for segs, _, _, ctx in seen["_rank"]:
        assert segs == [EPS[0]]
        assert ctx.dt == 0.002 and ctx.peak_force.tolist() == [1.0]
        assert ctx.stall.tolist() == [math.inf] and ctx.damping.tolist() == [0.1]
        assert ctx.is_dcmotor.tolist() == [False]
    assert [(c, r) for _, c, r, _ in seen["_rank"]] == [
        ((), ["position_offset", "mounting_offset"]), (("position_offset",),
                                                       ["mounting_offset"])]
    # the intervals of the final model on the final refit's segments, with the caller's
    # progress callback and the report's timing dict
    ((d, effects, segs, cfg, p, timing),) = seen["_intervals"]
    assert d is ds and effects == ("position_offset", "mounting_offset")
    assert segs == [EPS[0], EPS[1]] and cfg is res.config and p is prog
    assert timing is res.timing
    # the traces: the test episode, nominal and extended predictions
    ((d, eps, base, ext),) = seen["_traces"]
    assert d is ds and eps == [EPS[2]] and np.array_equal(base[0], np.zeros((40, 1)))
    np.testing.assert_allclose(ext[0][:, 0], 0.05 * P_A + 0.03 * P_B, atol=1e-6)
    assert res.traces == [{"name": "trace"}]
    assert res.models == {"m": "<mujoco/>"} and res.models is not ds.models
    assert res.sources == ("log0", "log1", "log2") and res.joints == ("j0",)
    assert res.timestep == {"model": 0.002, "used": 0.002, "rmse": []}


def test_a_fit_on_its_search_bound_is_widened_toward_the_hard_limit_and_reported(loop):
    """position_offset's search range is +-0.2 rad, its hard limit +-0.8 rad (the catalogue):
    data with a 0.3 rad offset puts the fit on +0.2, where it beats every in-range fit (the
    mounting offset's signal is absent); the round refits it in a wider range and names it
    at 0.3 rad, with the widening on the candidate and the cause."""
    calls = []
    res = loop(0.3, 0.0, 0.01, floor=0.001,
               scores={"position_offset": 0.9, "mounting_offset": 0.2},
               prog=lambda s, f: calls.append((s, f)))
    assert [c.effect for c in res.causes] == ["position_offset"]
    cause = res.causes[0]
    assert cause.params["offset"]["value"] == pytest.approx([0.3], abs=1e-6)
    assert cause.widened and all("offset" in line for line in cause.widened)
    first = {c.effect: c for c in res.rounds[0]}
    assert first["position_offset"].widened == cause.widened
    assert first["position_offset"].accepted and not first["position_offset"].at_bound
    assert first["mounting_offset"].widened == []
    # select MSE (a^2 + c^2) / 2 -> c^2 / 2 once widened
    assert first["position_offset"].select_gain == pytest.approx(1 - 1e-4 / (0.09 + 1e-4),
                                                                 rel=1e-4)
    assert ("round 1: position_offset on a bound, refit in a wider range",
            pytest.approx(0.32)) in calls


def test_a_cause_reports_the_intervals_it_was_judged_by(loop):
    """The named offset (0.05 rad) reports the final intervals' parts as the user reads them:
    value, the 95 % interval about the (step-extrapolated) centre 0.051 rad +- 4 mrad, the
    residual-noise (+-1 mrad) and data (+-2 mrad) intervals about the value, and the fit's move
    at the finer step (+0.5 mrad)."""
    def parts(t):
        u = t.u.copy()
        return (u + 0.001, np.full_like(u, 0.004), np.full_like(u, 0.001),
                np.full_like(u, 0.002), np.full_like(u, 0.0005))

    res = loop(0.05, 0.0, 0.01, floor=0.001, parts=parts,
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    (cause,) = res.causes
    p = cause.params["offset"]
    assert p["value"] == pytest.approx([0.05], abs=1e-6)
    assert p["interval"] == [pytest.approx([0.047, 0.055], abs=1e-6)]
    assert p["interval_noise"] == [pytest.approx([0.049, 0.051], abs=1e-6)]
    assert p["interval_data"] == [pytest.approx([0.048, 0.052], abs=1e-6)]
    assert p["step_shift"] == pytest.approx([0.0005], abs=1e-9)
    assert p["unit"] == "rad" and cause.flags == [] and cause.equivalent == []


def test_a_finer_physics_step_found_after_the_first_cause_chooses_it_again(loop, monkeypatch):
    """refine_step: the nominal step check (``stepsize.refine``) gets the train + select episodes;
    after round 1 accepts position_offset, ``stepsize.refine_fitted`` (a stand-in: the step halves
    to 1 ms) gets that model at its fitted 0.05 rad with the training residual 0.03 pB + 0.01 n,
    the noise floor's MSE (1 mrad^2); the analysis then continues on the 1 ms data set with a
    1 ms fit context, the first round chosen again (its coarse-step time kept apart), and the
    report records the steps."""
    refined, fitted = [], []

    def refine(ds, eps, cfg):
        refined.append((ds, eps, cfg))
        return ds, {"model": 0.002, "used": 0.002, "rmse": [0.0123]}

    def refine_fitted(ds, make_fn, s, x, ctx, cfg, floor_mse):
        fine = dataclasses.replace(ds, timestep=0.001)
        fitted.append((ds, tuple(s.effects), x.copy(), ctx, cfg, floor_mse,
                       make_fn(fine)([(s, x)])[0]))
        return fine, dataclasses.replace(ctx, dt=0.001), s, x, [(0.002, 0.02), (0.001, 0.01)]

    monkeypatch.setattr(AZ, "_refine_step", refine)
    monkeypatch.setattr(AZ.stepsize, "refine_fitted", refine_fitted)
    seen = {}
    res = loop(0.05, 0.03, 0.01, floor=0.001, scores=SCORES, seen=seen, refine_step=True)
    ds = seen["ds"]
    ((d, eps, cfg),) = refined
    assert d is ds and eps == [EPS[0], EPS[1]] and cfg is res.config
    ((d, effects, x, ctx, cfg, floor_mse, r),) = fitted  # once: the first cause only
    assert d is ds and effects == ("position_offset",) and cfg is res.config
    assert x == pytest.approx([0.05], abs=1e-6) and ctx.dt == 0.002
    assert floor_mse == pytest.approx(1e-6)
    np.testing.assert_allclose(r, 0.03 * P_B + 0.01 * NOISE, atol=1e-6)
    assert res.timestep == {"model": 0.002, "used": 0.001, "rmse": [0.0123],
                            "fitted": [(0.002, 0.02), (0.001, 0.01)], "servo_period": 0.0,
                            "first_at_coarse_step": "position_offset"}
    assert set(res.timing) == {"baseline", "round1_coarse_step", "round1", "round2",
                               "final_fit", "total"}
    # the coarse round is replaced by the round chosen again: two rounds, both causes
    assert [[c.effect for c in r] for r in res.rounds] == [
        ["position_offset", "mounting_offset"], ["mounting_offset"]]
    assert [c.effect for c in res.causes] == ["position_offset", "mounting_offset"]
    assert [c.params["offset"]["value"][0] for c in res.causes] == pytest.approx(
        [0.05, 0.03], abs=1e-6)
    # engines: the analysis', the one refine_fitted asked for on the 1 ms data, the analysis'
    # again on it; each with the caller's settings and the candidates
    assert [(d.timestep, c is res.config, n) for d, c, n in seen["_Engine"]] == [
        (0.002, True, ["position_offset", "mounting_offset"]),
        (0.001, True, ["position_offset", "mounting_offset"]),
        (0.001, True, ["position_offset", "mounting_offset"])]
    # rounds, intervals and traces after the refinement run on the 1 ms data set
    assert [c.dt for _, _, _, c in seen["_rank"]] == [0.002, 0.001, 0.001]
    ((d, *_),) = seen["_intervals"]
    assert d.timestep == 0.001 and seen["_traces"][0][0].timestep == 0.001
    # no finer step: nothing changes
    monkeypatch.setattr(AZ.stepsize, "refine_fitted", lambda *a: fitted.append(a))
    res = loop(0.05, 0.03, 0.01, floor=0.001, scores=SCORES, refine_step=True)
    assert len(fitted) == 2 and res.timestep == {"model": 0.002, "used": 0.002,
                                                 "rmse": [0.0123]}
    assert "round1_coarse_step" not in res.timing and len(res.rounds) == 2


def test_each_fitted_candidate_reports_its_train_and_select_error(loop):
    """Round 1 on data 0.05 pA + 0.01 n: position_offset fits 0.05 rad and leaves c n, RMS
    c / sqrt(2) on train and select; mounting_offset (signal absent) fits 0 and leaves the whole
    RMS sqrt((a^2 + c^2) / 2)."""
    res = loop(0.05, 0.0, 0.01, floor=0.001,
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    first = {c.effect: c for c in res.rounds[0]}
    left, whole = 0.01 / math.sqrt(2), math.sqrt((0.05 ** 2 + 0.01 ** 2) / 2)
    assert first["position_offset"].train_rmse == pytest.approx(left, rel=1e-4)
    assert first["position_offset"].select_rmse == pytest.approx(left, rel=1e-4)
    assert first["mounting_offset"].train_rmse == pytest.approx(whole, rel=1e-4)
    assert first["mounting_offset"].select_rmse == pytest.approx(whole, rel=1e-4)
    assert first["position_offset"].params == {"offset": [pytest.approx(0.05, abs=1e-6)]}
    assert first["mounting_offset"].params == {"offset": [pytest.approx(0.0, abs=1e-6)]}


def test_the_selection_stops_at_max_effects(loop):
    res = loop(0.05, 0.03, 0.01, floor=0.001, scores=SCORES, max_effects=1)
    assert [c.effect for c in res.causes] == ["position_offset"]
    assert res.stop_reason == "max_effects reached" and len(res.rounds) == 1


def test_the_selection_stops_when_errors_reach_the_noise_floor(loop):
    # after position_offset the select and train MSE are c^2 / 2 = 0.5e-6 rad^2, within
    # (1.2 floors)^2 = 1.44e-6: nothing left to find
    res = loop(0.05, 0.0, 0.001, floor=0.001,
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    assert [c.effect for c in res.causes] == ["position_offset"]
    assert res.stop_reason == "train and select errors at the noise floor"
    assert len(res.rounds) == 2 and not res.rounds[1][0].fitted
    # both must be there: train 3 mrad (MSE 4.5e-6) with select 1 mrad is not at the floor
    # (it is within 3 floors on train + select: (0.5 + 4.5) / 2 e-6 <= 9e-6)
    res = loop(0.05, 0.0, None, cs=(0.003, 0.001, 0.001), floor=0.001,
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    assert res.stop_reason.endswith("within 3 noise floors on train + select: nothing more to "
                                    "explain")
    # the margin is squared: c = 1.789 mrad leaves 1.6e-6 rad^2, above 1.2^2 = 1.44 floors^2
    # (not at the floor) and below 1.2^3 = 1.73
    res = loop(0.05, 0.0, math.sqrt(2 * 1.6e-6), floor=0.001,
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    assert res.stop_reason.endswith("within 3 noise floors on train + select: nothing more to "
                                    "explain")
    # with floor_margin and explain_above 0.5 (0.25e-6) the round is fitted and rejected
    res = loop(0.05, 0.0, 0.001, floor=0.001, floor_margin=0.5, explain_above=0.5,
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    assert res.stop_reason == "no candidate lowers the select error significantly"
    assert res.rounds[1][0].fitted


def test_a_model_within_explain_above_floors_is_not_extended_or_searched_further(loop):
    # after position_offset the train + select MSE is c^2 / 2 = 4.5e-6 rad^2 (c = 3 mrad):
    # above (1.2 floors)^2 = 1.44e-6, within 3^2 floors^2 = 9e-6: nothing more to explain,
    # and no backward search either
    res = loop(0.05, 0.0, 0.003, floor=0.001, search="both",
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    assert [c.effect for c in res.causes] == ["position_offset"]
    assert res.stop_reason == ("the model with position_offset is within 3 noise floors on "
                               "train + select: nothing more to explain")
    assert "backward_search" not in res.timing and not res.rounds[1][0].fitted
    # explain_above 2 (4e-6): explained further (mounting_offset is fitted, and gains nothing)
    res = loop(0.05, 0.0, 0.003, floor=0.001, explain_above=2.0,
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    assert res.rounds[1][0].fitted
    assert res.stop_reason == "no candidate lowers the select error significantly"


def test_a_fit_at_its_hard_limit_is_not_named(loop):
    """A 1 rad offset is beyond position_offset's hard limit (0.8 rad): the fit is widened to
    the limit and still sits on it, so it names nothing."""
    res = loop(1.0, 0.0, 0.01, floor=0.001, scores={"position_offset": 0.9})
    assert res.causes == []
    assert res.stop_reason == ("every fitted candidate ended at a parameter bound (at its hard "
                               "limit, or not the best fit)")
    (cand,) = res.rounds[0]
    assert cand.at_bound and cand.fitted and not cand.accepted
    assert cand.params["offset"] == [pytest.approx(0.8)]
    assert cand.widened


def test_candidates_the_select_split_cannot_tell_apart_are_named_once_as_equivalents(
        loop, monkeypatch):
    """mounting_offset replays exactly as position_offset here (same pattern): both fit the
    offset and gain alike; the earlier in the canonical list (position_offset) is named, even
    ranked second, and mounting_offset is reported as its equivalent."""
    import test_gap_decisions_loop as L

    monkeypatch.setitem(L.PATTERN, "mounting_offset", P_A)
    res = loop(0.05, 0.0, 0.01, floor=0.001,
               scores={"position_offset": 0.6, "mounting_offset": 0.7})
    assert [c.effect for c in res.causes] == ["position_offset"]
    assert res.causes[0].equivalent == ["mounting_offset"]
    first = {c.effect: c for c in res.rounds[0]}
    assert first["position_offset"].accepted and not first["mounting_offset"].accepted
    assert first["mounting_offset"].select_gain == pytest.approx(
        first["position_offset"].select_gain)


def test_an_effect_a_later_pair_makes_redundant_is_dropped_by_the_backward_pass(
        loop, monkeypatch):
    """Three linear effects: position_offset replays p1 + p2 + p3, viscous_damping p2 and
    mounting_offset p1 (p1, p2, p3, n orthogonal sinusoids of 1, 3, 7, 5 cycles, equal energy).
    On data 0.05 (p1 + p2) + 0.001 n, position_offset alone explains the most (2/3 of the
    signal's energy against 1/2 for either other) and is accepted first; viscous_damping
    (earlier in the canonical list than its tie mounting_offset) then mounting_offset follow,
    and with both the first is fitted to 0: leaving it out raises no error, so the backward
    pass drops it."""
    import test_gap_decisions_loop as L

    p3 = np.sin(2 * np.pi * 7 * L.T)
    monkeypatch.setitem(L.PATTERN, "position_offset", P_A + P_B + p3)
    monkeypatch.setitem(L.PATTERN, "viscous_damping", P_B)
    monkeypatch.setitem(L.PATTERN, "mounting_offset", P_A)
    scores = {"position_offset": [0.67, 0.6, 0.6], "viscous_damping": [0.5, 0.4, 0.4],
              "mounting_offset": [0.5, 0.4, 0.4]}
    res = loop(0.05, 0.05, 0.001, floor=0.001, scores=scores)
    assert [c.effect for r in res.rounds for c in r if c.accepted] == [
        "position_offset", "viscous_damping", "mounting_offset"]
    assert res.stop_reason == ("max_effects reached; dropped by the backward pass: "
                               "position_offset")
    assert sorted(c.effect for c in res.causes) == ["mounting_offset", "viscous_damping"]
    assert all(c.params[next(iter(c.params))]["value"] == [pytest.approx(0.05, abs=1e-6)]
               for c in res.causes)
    # the held-out error of the model without it: the 1 mrad pattern no effect explains
    assert res.gain.extended_rmse == pytest.approx(0.001 / math.sqrt(2), rel=1e-3)
    # the model after the drop fits to c / sqrt(2) = 0.7 mrad on select, within
    # backward_above 1.5 floors: no backward search follows
    res = loop(0.05, 0.05, 0.001, floor=0.001, scores=scores, search="both")
    assert "backward_search" not in res.timing
    assert sorted(c.effect for c in res.causes) == ["mounting_offset", "viscous_damping"]


def test_a_delay_stuck_on_a_flat_step_is_polished_in_its_round_and_in_the_final_fit(loop):
    """The stand-in replays a delay as the 1-cycle sine delayed by the delay rounded down to the
    2 ms step. Data lag 34.5 ms. Round 1 fits the three starts (10, 30, 60 ms); LM's 0.5 ms
    finite difference sees no slope within a step, so each stays put; the best (30 ms) is
    scanned over +-2 ms and moves to 32 ms, refitted (rescued) and judged there: its training
    RMS is that of two unit sines 2.5 ms apart, 2 sin(pi 0.0025) / sqrt(2), with the 1 mrad
    pattern beside it. The final fit scans again from 32 ms and reaches 34 ms, the step
    below the truth."""
    T_ = np.arange(40) * 0.025
    lag = np.sin(2 * np.pi * (T_ - 0.0345)) - np.sin(2 * np.pi * T_)
    res = loop(0.0, 0.0, 0.001, floor=0.001, scores={"latency": 0.9}, extra=lag)
    (cand,) = res.rounds[0]
    assert cand.accepted and cand.params == {"delay": [pytest.approx(0.032, abs=1e-9)]}
    rms = 2 * math.sin(math.pi * 0.0025) / math.sqrt(2)
    assert cand.train_rmse == pytest.approx(math.sqrt(rms ** 2 + 0.001 ** 2 / 2), rel=1e-6)
    (cause,) = res.causes
    assert cause.effect == "latency"
    assert cause.params["delay"]["value"] == [pytest.approx(0.034, abs=1e-9)]


def test_the_backward_search_must_pay_on_training_data_and_on_the_probes(loop):
    """The backward search of ``test_gap_decisions_loop`` (position_offset then the missed
    mounting_offset, 90 % lower select MSE) is refused (a) when the pair lowers the training
    error by less than min_gain: train noise c = 0.2 rad makes it b^2 / (b^2 + c^2) =
    0.0009 / 0.0409 = 2.2 %; (b) when a fraction of a step later its gain is gone (the stand-in
    flips mounting_offset's signal on a goal shift: the select error rises). (Here the search's
    own pruning, ``_backward``'s rules on the training segments and the probes, already drops
    mounting_offset; the checks after it in ``_analyze`` are a second line that no stand-in
    case has reached.)"""
    scores = {"position_offset": 0.9, "mounting_offset": [0.5, 0.01]}
    res = loop(0.05, 0.03, None, cs=(0.2, 0.01, 0.01), floor=0.001, search="both",
               scores=scores)
    assert "backward_search" in res.timing
    assert [c.effect for c in res.causes] == ["position_offset"]
    assert res.stop_reason == "no candidate signature explains the residual"
    res = loop(0.05, 0.03, 0.01, floor=0.001, search="both", flip="mounting_offset",
               scores=scores)
    assert "backward_search" in res.timing
    assert [c.effect for c in res.causes] == ["position_offset"]
    assert res.stop_reason == "no candidate signature explains the residual"
    # neither: kept (as in test_gap_decisions_loop)
    res = loop(0.05, 0.03, 0.01, floor=0.001, search="both", scores=scores)
    assert [c.effect for c in res.causes] == ["position_offset", "mounting_offset"]


def test_a_second_effect_is_sized_by_how_much_it_changes_the_first_ones_predictions(loop):
    """Round 2 on data 0.05 pA + 0.03 pB + 0.01 n: adding mounting_offset (0.03 rad) to the
    model with position_offset moves the predictions by 0.03 pB: RMS 0.03 / sqrt(2) = 21.2
    mrad, whatever the first effect predicts."""
    res = loop(0.05, 0.03, 0.01, floor=0.001, scores=SCORES)
    (second,) = res.rounds[1]
    assert second.accepted
    assert second.effect_rms == pytest.approx(0.03 / math.sqrt(2), rel=1e-4)


def test_of_two_effects_whose_intervals_hold_no_effect_the_closer_one_goes_first(loop):
    # 1 rad half-widths: position_offset (0.03 rad, margin 0.03) is nearer "no effect" than
    # mounting_offset (0.05 rad, margin 0.05) and is dropped first, although its name sorts later
    res = loop(0.03, 0.05, 0.01, floor=0.001, half=1.0, scores=SCORES)
    assert res.causes == []
    assert res.stop_reason.endswith("position_offset dropped: its 95 % interval holds no "
                                    "effect; mounting_offset dropped: its 95 % interval holds "
                                    "no effect")


def test_the_backward_search_takes_round_one_candidates_scoring_exactly_min_gain(loop):
    # mounting_offset scores exactly min_gain (0.05) in round 1: it is one of the top candidates
    # the backward search fits together, and it is kept (select MSE 90 % below the forward one)
    scores = {"position_offset": 0.9, "mounting_offset": [0.05, 0.01]}
    res = loop(0.05, 0.03, 0.01, floor=0.001, search="both", scores=scores)
    assert [c.effect for c in res.causes] == ["position_offset", "mounting_offset"]
    assert "backward search from position_offset, mounting_offset kept" in res.stop_reason
