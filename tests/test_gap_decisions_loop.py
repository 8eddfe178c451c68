"""The gap analysis' forward loop and verdicts (``analyze._analyze``) on a stand-in engine.

The replay, the split, the ranking's score statistic, the noise floor and the parameter intervals
are stand-ins (monkeypatched in ``lowcostdex.gap.analyze``); everything that decides runs for
real: which candidates a round fits, the Levenberg-Marquardt fits, the select split's judgement
(gain, bootstrap bound, paired block bound, min_effect, training gain, goal-shift probes), the
stop reasons, the backward pass, the final refit, the interval drop, the held-out gain and the
verdict. The stand-in replays a model as the sum of ``value x pattern`` of its effects, with
patterns orthogonal over an episode (``test_gap_decisions_backward``): on data a pA + c n the
fitted offset is a, the select MSE falls from (a^2 + c^2) / 2 to c^2 / 2 and the held-out RMSE
from sqrt((a^2 + c^2) / 2) to c / sqrt(2), all by hand. Three 1 s episodes: train, select, test.
"""

from __future__ import annotations

import importlib
import json
import math
from dataclasses import dataclass

import numpy as np
import pytest
from test_gap_decisions_backward import NOISE, P_A, P_B, PATTERN, N, T

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.dataset import Split, Window
from lowcostdex.gap.results import CandidateResult, GapConfig

AZ = importlib.import_module("lowcostdex.gap.analyze")  # the package exports analyze() by name
EPS = [Window(0, 0, N, 0), Window(1, 0, N, 0), Window(2, 0, N, 0)]


@dataclass
class _Traj:
    qpos: np.ndarray
    time: np.ndarray
    name: str
    model: str = "m"


@dataclass
class _DS:
    trajectories: list
    joints: tuple = ("j0",)
    timestep: float = 0.002
    sources: tuple = ()
    models: dict | None = None
    servo_period: float = 0.0  # as gap.dataset.Dataset's (the servos' update period)


class _Model:
    dof_damping = np.array([0.1])
    jnt_type = np.array([3])   # one hinge (mjJNT_HINGE)
    actuator_trntype, actuator_trnid = np.array([0]), np.array([[0, -1]])  # on the joint

    def joint(self, name):
        return _Joint()


@dataclass
class _Joint:
    id: int = 0


class _Targets:
    actuators = np.array([0])
    dofs = np.array([0])

    @classmethod
    def resolve(cls, model, joints):
        return cls()


class _Engine:
    """Replays a model as the sum of its effects' signals; a goal shift > 0 flips the sign of
    ``FLIP``'s signal (a gain that is gone a fraction of a step later)."""

    FLIP: str | None = None

    def __init__(self, ds, cfg, candidates):
        self.ds, self.joints, self.rep = ds, ("j0",), self
        self.models = {"m": _Model()}

    def _one(self, effects, shift):
        out = np.zeros(N)
        for e in effects:
            sign = -1.0 if shift and e.name == self.FLIP else 1.0
            value = float(next(iter(e.values.values()))[0])  # an offset, or another value
            if e.name == "latency":  # the 1-cycle sine delayed by the delay rounded down to
                # the physics step (a step phase: flat within a step)
                value = math.floor(value / self.ds.timestep + 1e-9) * self.ds.timestep
                out = out + np.sin(2 * np.pi * (T - value)) - np.sin(2 * np.pi * T)
                continue
            out = out + sign * value * PATTERN[e.name]
        return out[:, None]

    def run(self, windows, columns, goal_shift=0.0, force_peak=False):
        preds = [[self._one(col, goal_shift) for _ in windows] for col in columns]
        return preds, [np.array([1.0]) for _ in columns]

    def predict(self, windows, columns):
        return self.run(windows, columns)[0]

    def residuals(self, windows, columns):
        return [np.concatenate([(self.ds.trajectories[w.traj].qpos[w.score_from:w.stop]
                                 - p[w.score_from - w.start:]).ravel()
                                for w, p in zip(windows, col, strict=True)])
                for col in self.predict(windows, columns)]

    def residual_fn(self, windows):
        return lambda points: self.residuals(windows, [s.to_effects(x) for s, x in points])


@pytest.fixture
def loop(monkeypatch):
    """Run ``_analyze`` on data a pA + b pB + c n (every episode alike) with a noise floor,
    the ranking's scores and the intervals' half-widths given (``make_loop``)."""
    return make_loop(monkeypatch)


def make_loop(monkeypatch):
    """The ``loop`` fixture's runner (other test files build their fixture from it)."""

    def run(a, b, c, *, floor, scores, half=1e-6, flip=None, seen=None, prog=None, parts=None,
            cs=None, extra=None, **cfg):
        """``seen``: a dict that receives each stand-in's arguments (name -> list of calls);
        ``prog``: the progress callback (default: none); ``parts``: the intervals' whole answer
        (centre, half, noise, data, shift) from the final track (default: from ``half``);
        ``cs``: c per log (train, select, test) instead of one for all; ``extra``: a signal
        added to every log."""
        calls = seen if seen is not None else {}

        def log(name, *args):
            calls.setdefault(name, []).append(args)
        cs = cs if cs is not None else (c, c, c)
        more = extra if extra is not None else 0.0
        ds = _DS([_Traj((a * P_A + b * P_B + cs[i] * NOISE + more)[:, None], T.copy(), f"log{i}")
                  for i in range(3)],
                 sources=("log0", "log1", "log2"), models={"m": "<mujoco/>"})
        names = list(scores)

        def rank(eng, segs, current, cur_x, remaining, ctx):
            log("_rank", segs, tuple(current.effects), list(remaining), ctx)
            r = eng.residuals(segs, [current.to_effects(cur_x) if current.effects else []])[0]
            k = len(current.effects)  # a list of scores: one per round
            return ([CandidateResult(n, scores[n][min(k, len(scores[n]) - 1)]
                                     if isinstance(scores[n], list) else scores[n])
                     for n in remaining], float(np.sqrt(np.mean(r * r))))

        def intervals(ds, t, segs, cfg, prog, timing):
            log("_intervals", ds, tuple(t.structure.effects), segs, cfg, prog, timing)
            if parts is not None:
                return parts(t)
            if callable(half):  # half-widths from the fitted point: h(free, u_i)
                h = np.array([half(f, ui) for f, ui in zip(t.structure.free, t.u, strict=True)])
            else:
                h = np.array([half.get(f.effect, 1e-6) if isinstance(half, dict) else half
                              for f in t.structure.free])
            return t.u, h, h, h, None

        class engine(_Engine):
            FLIP = flip

            def __init__(self, ds, cfg, candidates):
                log("_Engine", ds, cfg, list(candidates))
                super().__init__(ds, cfg, candidates)
        for name, value in {
                "episodes": lambda ds, chunk: log("episodes", ds, chunk) or list(EPS),
                "split_episodes": lambda ds, eps, rng, test_logs: log(
                    "split_episodes", ds, eps, rng, test_logs) or Split((0,), (1,), (2,)),
                "segments": lambda ds, eps, length, burn_in: log(
                    "segments", ds, eps, length, burn_in) or list(eps),
                "available_candidates": lambda ds, requested: log(
                    "available_candidates", ds, requested) or names,
                "_Engine": engine, "Targets": type("Targets", (_Targets,), {
                    "resolve": classmethod(lambda cls, model, joints: log(
                        "Targets.resolve", model, joints) or cls())}),
                "noise_floor": lambda trajectories: log(
                    "noise_floor", trajectories) or np.array([floor]),
                "residual_diagnostics": lambda *args: log("residual_diagnostics", *args) or {
                    "lag": 0.0},
                "_act_cols": lambda ds, targets, model: log("_act_cols", ds, targets, model)
                or [0],
                "_rank": rank, "_intervals": intervals,
                "_traces": lambda *args, **kw: log("_traces", *args) or [{"name": "trace"}]}.items():
            monkeypatch.setattr(AZ, name, value)
        monkeypatch.setattr(fitmod, "stall_torque", lambda model, acts: log(
            "stall_torque", model, acts) or np.array([np.inf]))
        monkeypatch.setattr(fitmod, "dcmotor_mask", lambda model, acts: log(
            "dcmotor_mask", model, acts) or np.array([False]))
        config = GapConfig(**{"refine_step": False, "bootstrap": 200, "search": "forward",
                              "probes": (0.01, 0.02), **cfg})
        calls["ds"] = ds
        return AZ._analyze(ds, config, prog if prog is not None else (lambda s, f: None))

    return run


def test_a_real_offset_is_named_with_the_held_out_error_before_and_after(loop):
    # a 0.05 rad offset signal under a 0.01 rad unexplained one; position_offset ranks first,
    # mounting_offset's signal is absent (its fit stays at 0: no gain, not accepted)
    res = loop(0.05, 0.0, 0.01, floor=0.001,
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    assert [c.effect for c in res.causes] == ["position_offset"]
    assert res.causes[0].params["offset"]["value"] == pytest.approx([0.05], abs=1e-6)
    rb, re_ = math.sqrt((0.05 ** 2 + 0.01 ** 2) / 2), 0.01 / math.sqrt(2)
    assert res.gain.baseline_rmse == pytest.approx(rb) and res.gain.extended_rmse == \
        pytest.approx(re_, rel=1e-4)
    lower = round(100 * (1 - re_ / rb))
    assert lower == 80  # 1 - 0.01 / sqrt(0.0026) = 0.804
    # ... and what is left: the planted 0.01 rad signal no candidate explains, 7.07 floors of 1
    # mrad (gap-sim12: a reliable verdict says what it leaves)
    assert res.verdict == (f"position_offset: held-out RMSE {rb:.4g} -> {re_:.4g} rad "
                           f"(80 % lower); left: 7.07 mrad held-out RMSE (20 % of the nominal "
                           "model's), 7.07x the noise floor 1 mrad: above the 3 floors a replay "
                           "of an exact model leaves, so something beyond the named causes is at "
                           "work")
    first = {c.effect: c for c in res.rounds[0]}
    assert first["position_offset"].accepted and not first["mounting_offset"].accepted
    # select MSE 1 - c^2 / (a^2 + c^2) lower
    assert first["position_offset"].select_gain == pytest.approx(1 - 0.01 ** 2 / 0.0026, rel=1e-4)
    assert first["position_offset"].effect_rms == pytest.approx(0.05 / math.sqrt(2), rel=1e-4)
    # round 2 holds only mounting_offset (0.2 >= min_gain: fitted, no gain)
    assert [c.effect for c in res.rounds[1]] == ["mounting_offset"]
    assert res.stop_reason == "no candidate lowers the select error significantly"


def test_two_real_offsets_are_both_named_largest_rise_first(loop):
    res = loop(0.05, 0.03, 0.01, floor=0.001,
               scores={"position_offset": 0.7, "mounting_offset": 0.6})
    assert [c.effect for c in res.causes] == ["position_offset", "mounting_offset"]
    assert [c.params["offset"]["value"][0] for c in res.causes] == pytest.approx(
        [0.05, 0.03], abs=1e-6)
    assert res.stop_reason == "no candidates left"
    # held-out RMSE after each prefix: with A only sqrt((b^2 + c^2) / 2), with both c / sqrt(2)
    assert res.causes[0].heldout_rmse_after == pytest.approx(math.sqrt((0.03 ** 2 + 1e-4) / 2),
                                                             rel=1e-4)
    assert res.causes[1].heldout_rmse_after == pytest.approx(0.01 / math.sqrt(2), rel=1e-4)


def test_no_candidate_signature_gives_the_unexplained_verdict(loop):
    # every score below min_gain 0.05: nothing is fitted; the held-out RMSE is
    # sqrt((0.05^2 + 0.01^2) / 2) = 0.036 rad = 36 floors of 1 mrad > 2 floors
    res = loop(0.05, 0.0, 0.01, floor=0.001,
               scores={"position_offset": 0.04, "mounting_offset": 0.01})
    assert res.causes == [] and res.effects == []
    assert res.stop_reason == "no candidate signature explains the residual"
    rb = math.sqrt((0.05 ** 2 + 0.01 ** 2) / 2)
    assert res.verdict == ("discrepancy not explained by the candidate effects (held-out RMSE "
                           f"{rb:.4g} rad, 36x the noise floor; the selection stopped: no "
                           "candidate signature explains the residual)")
    assert not any(c.fitted for c in res.rounds[0])


def test_a_nominal_model_within_explain_above_floors_is_not_explained(loop):
    # nominal RMSE sqrt((0.002^2 + 0.001^2) / 2) = 1.58 mrad <= 3 floors of 1 mrad: quiet
    res = loop(0.002, 0.0, 0.001, floor=0.001,
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    assert res.causes == []
    assert res.stop_reason == ("the nominal model's train + select RMSE is within 3 noise "
                               "floors: nothing to explain")
    assert res.verdict == "no significant discrepancy"  # 1.58 mrad < 2 floors
    # with explain_above 1.5 (1.5 mrad) it is explained
    res = loop(0.002, 0.0, 0.001, floor=0.001, explain_above=1.5, floor_margin=1.0,
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    assert [c.effect for c in res.causes] == ["position_offset"]


def test_an_effect_below_min_effect_floors_is_not_accepted(loop):
    # a = 0.01: the offset changes predictions by RMS 0.01 / sqrt(2) = 7.07 mrad, below
    # 0.75 floors of 10 mrad (7.5 mrad) although it lowers the select MSE by
    # a^2 / (a^2 + c^2) = 0.0001 / 0.001 = 10 % (c = 0.03; explain_above 1: nominal 22 mrad)
    kw = dict(floor=0.01, explain_above=1.0,
              scores={"position_offset": 0.9, "mounting_offset": 0.01})
    res = loop(0.01, 0.0, 0.03, **kw)
    assert res.causes == []
    assert res.stop_reason == "the best candidate changes predictions by less than the noise floor"
    c = {c.effect: c for c in res.rounds[0]}["position_offset"]
    assert c.effect_rms == pytest.approx(0.01 / math.sqrt(2), rel=1e-4)
    assert c.select_gain == pytest.approx(0.1, rel=1e-4) and not c.accepted
    assert res.verdict.startswith("discrepancy not explained")  # 22 mrad > 2 floors of 10
    res = loop(0.01, 0.0, 0.03, min_effect=0.7, **kw)  # 7.0 mrad < 7.07: accepted
    assert [c.effect for c in res.causes] == ["position_offset"]


def test_a_gain_that_is_gone_a_fraction_of_a_step_later_is_not_robust(loop):
    res = loop(0.05, 0.0, 0.01, floor=0.001, flip="position_offset",
               scores={"position_offset": 0.9, "mounting_offset": 0.01})
    assert res.causes == []
    # probes: the flipped offset leaves residual 2a pA + c n against a pA + c n:
    # 1 - (4a^2 + c^2) / (a^2 + c^2) = 1 - 0.0101 / 0.0026
    probe = 100 * (1 - (4 * 0.0025 + 1e-4) / 0.0026)
    assert res.stop_reason == (
        f"the best candidate (position_offset, select MSE 96 % lower) lowers the training "
        f"error by 96.2 % and the select error with goals a fraction of a step later by "
        f"{probe:.0f}, {probe:.0f} %: not robust")
    res = loop(0.05, 0.0, 0.01, floor=0.001, flip="position_offset", probes=(),
               scores={"position_offset": 0.9, "mounting_offset": 0.01})
    assert [c.effect for c in res.causes] == ["position_offset"]


def test_an_effect_whose_interval_holds_no_effect_is_dropped_after_the_final_fit(loop):
    # both accepted; the final intervals (stand-in half-widths) put mounting_offset's 0.03 rad
    # within 0.05 rad of "no effect" (margin 0.6 <= 1): dropped, the rest refitted
    res = loop(0.05, 0.03, 0.01, floor=0.001, half={"mounting_offset": 0.05},
               scores={"position_offset": 0.7, "mounting_offset": 0.6})
    assert [c.effect for c in res.causes] == ["position_offset"]
    assert res.stop_reason == ("no candidates left; mounting_offset dropped: its 95 % interval "
                               "holds no effect")
    # both dropped in turn: no cause left, unexplained
    res = loop(0.05, 0.03, 0.01, floor=0.001, half=1.0,
               scores={"position_offset": 0.7, "mounting_offset": 0.6})
    assert res.causes == [] and res.effects == []
    assert res.stop_reason.endswith("mounting_offset dropped: its 95 % interval holds no "
                                    "effect; position_offset dropped: its 95 % interval holds "
                                    "no effect")


def test_the_interval_drop_is_at_exactly_one_half_width_from_no_effect(loop):
    """The final interval drop (``analyze``: margin <= 1) at its edge, margins by construction:
    a half-width equal to the fitted distance from "no effect" (mounting_offset's null is 0 rad)
    puts "no effect" exactly on the interval's end (margin 1.0): dropped, the interval holds
    it; two thirds of that distance (margin 1.5) excludes it: kept. (mutation run of
    2026-11-26 at c3ff5c5: `<= 1` -> `< 1` and `<= 2` survived every fast test.)"""
    scores = {"position_offset": 0.7, "mounting_offset": 0.6}

    def edge(ratio):
        return lambda f, u: abs(u) / ratio if f.effect == "mounting_offset" else 1e-6

    res = loop(0.05, 0.03, 0.01, floor=0.001, half=edge(1.0), scores=scores)
    assert [c.effect for c in res.causes] == ["position_offset"]
    assert res.stop_reason.endswith("mounting_offset dropped: its 95 % interval holds no effect")
    res = loop(0.05, 0.03, 0.01, floor=0.001, half=edge(1.5), scores=scores)
    assert sorted(c.effect for c in res.causes) == ["mounting_offset", "position_offset"]
    assert "dropped" not in res.stop_reason


def test_the_report_payload_carries_what_was_decided(loop):
    res = loop(0.05, 0.0, 0.01, floor=0.001,
               scores={"position_offset": 0.9, "mounting_offset": 0.2})
    d = json.loads(json.dumps(res.to_dict()))  # report.json: plain JSON
    assert (d["version"], d["verdict"], d["stop_reason"]) == (1, res.verdict, res.stop_reason)
    assert d["metric"] == "position error [rad]: RMSE (and MAE) over held-out test episodes"
    assert d["sources"] == ["log0", "log1", "log2"] and d["joints"] == ["j0"]
    assert d["split"] == {role: [{"log": f"log{i}", "start": 0, "stop": N}]
                          for role, i in (("train", 0), ("select", 1), ("test", 2))}
    assert d["noise_floor"] == {"rmse": pytest.approx(0.001), "per_joint": {"j0": 0.001}}
    (cause,) = d["causes"]
    assert cause["effect"] == "position_offset" and cause["joints"] == ["j0"]
    assert cause["params"]["offset"]["value"] == pytest.approx([0.05], abs=1e-6)
    assert cause["heldout_rmse_after"] == pytest.approx(0.01 / math.sqrt(2), rel=1e-4)
    assert (cause["flags"], cause["equivalent"], cause["widened"]) == ([], [], [])
    assert d["gain"] == json.loads(json.dumps(res.gain.to_dict()))
    first = {c["effect"]: c for c in d["candidates"][0]}
    assert first["position_offset"]["accepted"] and first["position_offset"]["score"] == 0.9
    assert first["mounting_offset"]["fitted"] and not first["mounting_offset"]["accepted"]
    assert d["config"]["probes"] == [0.01, 0.02] and d["config"]["search"] == "forward"
    assert d["timestep"] == {"model": 0.002, "used": 0.002, "rmse": []}
    assert {"baseline", "round1", "total"} <= set(d["timing_s"])
    assert d["baseline"]["heldout_rmse"] == pytest.approx(math.sqrt(0.0026 / 2))
    assert d["extended"]["heldout_rmse"] == pytest.approx(0.01 / math.sqrt(2), rel=1e-4)
    # the baseline's select RMSE: the nominal replay of the select episode, sqrt(0.0026 / 2)
    assert d["baseline"]["select_rmse"] == pytest.approx(math.sqrt(0.0026 / 2))


def test_the_backward_search_finds_an_effect_the_forward_steps_stopped_before(loop):
    # round 1 accepts position_offset; in round 2 mounting_offset's score (0.01) is below
    # min_gain and the forward steps stop. The backward search fits the round-1 top candidates
    # together (scores >= min_gain there: both) and keeps both: the select MSE falls from
    # (b^2 + c^2) / 2 to c^2 / 2, 1 - 0.01^2 / (0.03^2 + 0.01^2) = 90 % below the forward model's
    scores = {"position_offset": 0.9, "mounting_offset": [0.5, 0.01]}
    res = loop(0.05, 0.03, 0.01, floor=0.001, search="both", scores=scores)
    assert res.stop_reason == (
        "no candidate signature explains the residual; backward search from position_offset, "
        "mounting_offset kept position_offset, mounting_offset (select MSE 90 % below the "
        "forward model's)")
    assert [c.effect for c in res.causes] == ["position_offset", "mounting_offset"]
    assert [c.params["offset"]["value"][0] for c in res.causes] == pytest.approx(
        [0.05, 0.03], abs=1e-6)
    assert "backward_search" in res.timing
    # forward only: the offset the forward steps missed stays missing
    res = loop(0.05, 0.03, 0.01, floor=0.001, search="forward", scores=scores)
    assert [c.effect for c in res.causes] == ["position_offset"]
    # a forward model within backward_above floors is not searched further: select RMSE after
    # position_offset is sqrt((0.03^2 + 0.01^2) / 2) = 22.4 mrad; 30 floors of 1 mrad is more
    res = loop(0.05, 0.03, 0.01, floor=0.001, search="both", backward_above=30.0, scores=scores)
    assert [c.effect for c in res.causes] == ["position_offset"]
    assert "backward_search" not in res.timing
