"""Small stages of the gap analysis that decide what it may name and what it looks at, on
stand-in data sets (no replay): which candidates a data set allows (``available_candidates``) and
which training segments the ranking replays (``_subset``).

Expected values are typed from the catalogue's list of causes and the rules in the docstrings,
worked out by hand in each test; every test runs in milliseconds so the gap-pure mutation group
(``python bench/mutation.py gap-pure``) can judge these functions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import mujoco
import numpy as np
import pytest
import test_gap_decisions_loop as _loop_tests
from test_gap_decisions_backward import CTX, NOISE, P_A, P_B, N, T, _case
from test_gap_decisions_backward import _Engine as BwEngine

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import significance
from lowcostdex.gap.analyze import _backward, _rank, _subset, available_candidates
from lowcostdex.gap.dataset import Window
from lowcostdex.gap.results import GapConfig

loop = _loop_tests.loop  # the _analyze loop's stand-in fixture

# A plain MuJoCo arm with one hinge per actuator; plain MJCF typed here (not the project's models).
_ARM = """
<mujoco>
  <worldbody>
    <body name="a"><joint name="j0" type="hinge"/><geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0"/>
      <body name="b" pos="0.1 0 0"><joint name="j1" type="hinge"/>
        <geom type="capsule" size="0.02" fromto="0 0 0 0.1 0 0"/></body></body>
  </worldbody>
  <actuator>{acts}</actuator>
</mujoco>
"""
_POS = '<position name="{n}" joint="{j}" kp="5"/>'
_VEL = '<intvelocity name="{n}" joint="{j}" kp="5" actrange="-3 3"/>'


def _model(kinds: tuple[str, str]) -> mujoco.MjModel:
    acts = "".join(k.format(n=f"a{i}", j=f"j{i}") for i, k in enumerate(kinds))
    return mujoco.MjModel.from_xml_string(_ARM.format(acts=acts))


@dataclass
class _Tr:
    model: str
    time: np.ndarray | None = None


@dataclass
class _Log(_Tr):
    """Ten rows (0.09 s) of a log at rest: too short for a rest of the deadband gate (which
    ``offer.available_candidates`` reads the logs for): the opt-in deadband is not offered."""
    time: np.ndarray = field(default_factory=lambda: np.arange(10) * 0.01)
    joints: tuple[str, ...] = ("j0", "j1")
    actuators: tuple[str, ...] = ("a0", "a1")
    qpos: np.ndarray = field(default_factory=lambda: np.zeros((10, 2)))
    qvel: np.ndarray = field(default_factory=lambda: np.zeros((10, 2)))
    goal: np.ndarray = field(default_factory=lambda: np.zeros((10, 2)))
    channels: dict = field(default_factory=dict)


class _DS:
    """What ``available_candidates`` reads of a Dataset: channels logged in every trajectory,
    the commanded actuators, the compiled model of the first trajectory, and (the deadband's
    gate) the logs of the effect joints."""

    effect_joints = ("j0", "j1")

    def __init__(self, models: dict[str, mujoco.MjModel], trajs: list[_Tr], chans: set[str],
                 actuators=("a0", "a1")):
        self._models, self.trajectories, self._chans = models, trajs, chans
        self.actuators = actuators

    def channels(self) -> set[str]:
        return set(self._chans)

    def compiled(self, key: str) -> mujoco.MjModel:
        return self._models[key]


# The catalogue's canonical causes in their order (lowcostdex/sim/effects/catalogue.py CAUSES);
# only thermal_derating (temperature) and voltage_sag (voltage) require a measured channel.
_ALL = ["latency", "backlash", "coulomb_friction", "stribeck_friction", "load_dependent_friction",
        "viscous_damping", "gain_error", "torque_limit", "velocity_limit", "position_offset",
        "inertia_error", "mass_error", "thermal_derating", "voltage_sag",
        "gearbox_friction", "mounting_offset", "motor_strength", "sensor_scale", "goal_profile"]
# goal_profile is a default cause offered only where the logs show a profile's ramps
# (lowcostdex.gap.ramps): the stand-ins' joints hold still under constant goals, so not here.
_SHOWN = [n for n in _ALL if n != "goal_profile"]


def _ds(first: tuple[str, str], chans: set[str], second=(_POS, _POS)) -> _DS:
    # the second trajectory's model differs on purpose: the rule reads the FIRST one's
    return _DS({"m0": _model(first), "m1": _model(second)}, [_Log("m0"), _Log("m1")], chans)


def test_position_servos_without_extra_channels_may_name_every_cause_but_the_exogenous_two():
    """Position actuators: offsets are visible, so they stay; no temperature or voltage logged,
    so thermal_derating and voltage_sag are left out; the catalogue's order is kept."""
    want = [n for n in _SHOWN if n not in ("thermal_derating", "voltage_sag")]
    assert available_candidates(_ds((_POS, _POS), set()), None) == want


def test_a_logged_temperature_allows_thermal_derating_and_voltage_allows_voltage_sag():
    got_t = available_candidates(_ds((_POS, _POS), {"temperature"}), None)
    assert got_t == [n for n in _SHOWN if n != "voltage_sag"]
    got_both = available_candidates(_ds((_POS, _POS), {"temperature", "voltage"}), None)
    assert got_both == _SHOWN


def test_velocity_goal_servos_cannot_be_given_position_or_mounting_offsets():
    """Every commanded actuator is an intvelocity (the set of actuators EQUALS the set of rate-goal
    actuators, the boundary of ``<=``): position_offset and mounting_offset are removed, the rest
    as for position servos. The second trajectory's model is of position servos: the rule reads
    the first trajectory's model."""
    want = [n for n in _SHOWN if n not in ("thermal_derating", "voltage_sag", "position_offset",
                                         "mounting_offset")]
    assert available_candidates(_ds((_VEL, _VEL), set()), None) == want
    # and the other way round: the first model has position servos, the second velocity ones
    got = available_candidates(_ds((_POS, _POS), set(), second=(_VEL, _VEL)), None)
    assert "position_offset" in got and "mounting_offset" in got


def test_one_velocity_servo_among_position_servos_keeps_the_offsets():
    """Only a1 integrates a velocity: {a0, a1} is not within {a1}, offsets stay."""
    got = available_candidates(_ds((_POS, _VEL), set()), None)
    assert got == [n for n in _SHOWN if n not in ("thermal_derating", "voltage_sag")]


def test_a_requested_list_is_kept_in_its_order_and_filtered_by_channels_and_servo_kind():
    req = ("voltage_sag", "position_offset", "latency", "mounting_offset", "thermal_derating")
    assert available_candidates(_ds((_POS, _POS), {"voltage"}), req) == [
        "voltage_sag", "position_offset", "latency", "mounting_offset"]
    assert available_candidates(_ds((_POS, _POS), set()), req) == [
        "position_offset", "latency", "mounting_offset"]
    assert available_candidates(_ds((_VEL, _VEL), {"temperature"}), req) == [
        "latency", "thermal_derating"]
    assert available_candidates(_ds((_POS, _POS), set()), []) == []


# -- _subset: the ranking's training segments -------------------------------------------------------

# One trajectory sampled every 0.125 s (exact in binary); segment i spans samples [8i, 8i + 9), so
# its duration time[stop - 1] - time[start] is exactly 1.0 s; ten segments, 10 s in all.
_T = np.arange(8 * 10 + 1, dtype=float) * 0.125
_SEGS = [Window(0, 8 * i, 8 * i + 9, 8 * i) for i in range(10)]
_SDS = _DS({}, [_Tr("m0", _T)], set())


def test_subset_spreads_the_segments_evenly_over_the_requested_seconds():
    """3.4 s of 10 x 1 s: k = round(10 * 3.4 / 10) = 3 segments at linspace(0, 9, 3) =
    [0, 4.5, 9] rounded (half to even) = [0, 4, 9]. (Durations measured one sample short,
    0.875 s, would give total 8.75 and k = round(3.89) = 4; durations of time[stop-1] + time[start]
    would total 100 s and k = 1.)"""
    assert _subset(_SDS, _SEGS, 3.4) == [_SEGS[0], _SEGS[4], _SEGS[9]]


def test_subset_of_a_few_seconds_keeps_at_least_the_first_segment():
    """0.4 s: round(10 * 0.4 / 10) = round(0.4) = 0, raised to the minimum of one segment:
    linspace(0, 9, 1) = [0]."""
    assert _subset(_SDS, _SEGS, 0.4) == [_SEGS[0]]


def test_subset_with_more_seconds_than_logged_keeps_every_segment_as_a_new_list():
    for seconds in (10.0, 25.0):  # total 10 s <= seconds: all, in order
        got = _subset(_SDS, _SEGS, seconds)
        assert got == _SEGS and got is not _SEGS


def test_subset_of_seven_seconds():
    """7 s: k = round(7.0) = 7, linspace(0, 9, 7) = [0, 1.5, 3, 4.5, 6, 7.5, 9] rounded half to
    even = [0, 2, 3, 4, 6, 8, 9]."""
    assert _subset(_SDS, _SEGS, 7.0) == [_SEGS[i] for i in (0, 2, 3, 4, 6, 8, 9)]


# -- _backward: which split's rise binds, which weak effect goes first, the size boundary, the seed --
# The stand-in engine and patterns of test_gap_decisions_backward: each effect adds value x its
# orthogonal pattern (P_A: position_offset, P_B: mounting_offset, NOISE: what none explains),
# every pattern's sum of squares over an episode is 20, so an error ratio is a ratio of squared
# amplitudes.

def _bw(sel, train, x0, *, rng=None, floor_rms=1e-4, **cfg):
    """``_backward`` with select episodes holding ``sel`` = (a, b, c) and training segments
    holding ``train`` (two identical episodes each), from the model values ``x0`` = [a, b]."""
    def data(a, b, c):
        return (a * P_A + b * P_B + c * NOISE)[:, None]

    ds = _DS({}, [_Tr("m", T.copy()), _Tr("m", T.copy())], set())
    for tr, abc in zip(ds.trajectories, (sel, train), strict=True):
        tr.qpos = data(*abc)
    ds.joints, ds.timestep = ("j0",), 0.002
    sel_eps, train_eps = [Window(0, 0, N, 0)] * 2, [Window(1, 0, N, 0)] * 2
    eng = BwEngine(ds)
    s = fitmod.Structure.build(("position_offset", "mounting_offset"), ("j0",), CTX)
    dropped: list[str] = []
    config = GapConfig(**{"bootstrap": 200, "probes": (0.01, 0.02), **cfg})
    out, out_x = _backward(eng, ds, sel_eps, s, np.asarray(x0, float), config, floor_rms, CTX,
                           lambda pts: eng.residuals(sel_eps + train_eps,
                                                     [st.to_effects(x) for st, x in pts]),
                           dropped, train_eps, rng=rng)
    return out, out_x, dropped


def test_an_effect_that_barely_helps_the_select_split_is_dropped_whatever_training_says():
    """Select: b = 0.01 sqrt(0.02), fitted exactly: rise (b / c)^2 = 0.02 < min_gain / 2 = 0.025.
    Training: b_t = 0.03 against the model's b: rise (b_t^2 + c^2) / ((b_t - b)^2 + c^2) - 1 =
    0.001 / 0.000917 - 1 = 0.09. The smallest rise (select, 0.02) decides: dropped. (A select rise
    of 1.02, or one measured in absolute errors, would have kept it.)"""
    b = 0.01 * math.sqrt(0.02)
    # no goal-shift probes: they replay the select episodes and would repeat its rise
    s, x, dropped = _bw((0.05, b, 0.01), (0.05, 0.03, 0.01), [0.05, b], probes=())
    assert dropped == ["mounting_offset"] and s.effects == ("position_offset",)
    assert x == pytest.approx([0.05], abs=1e-6)


def test_an_effect_that_helps_the_select_split_but_worsens_the_training_fit_is_dropped():
    """Select: b = 0.03 fitted exactly, rise (0.03 / 0.01)^2 = 9. Training holds no B (b_t = 0):
    with B its residual is 0.03 pB + c n, without it c n: rise 1e-4 / 1e-3 - 1 = -0.9 < 0.025,
    dropped. (A training rise of -0.9 + 2 = 1.1 would have kept it.)"""
    s, _, dropped = _bw((0.05, 0.03, 0.01), (0.05, 0.0, 0.01), [0.05, 0.03])
    assert dropped == ["mounting_offset"] and s.effects == ("position_offset",)


def test_of_two_weak_effects_inside_their_bounds_the_smaller_rise_goes_first():
    """Rises: A (0.001 / 0.01)^2 = 0.01, B (0.0015 / 0.01)^2 = 0.0225, both < 0.025 and neither on
    a bound: A (position_offset) goes first although its name sorts after B's; B alone is then
    kept (min_size 1) and refitted to its value 0.0015."""
    s, x, dropped, _ = _case(0.001, 0.0015, 0.01)
    assert dropped == ["position_offset"] and s.effects == ("mounting_offset",)
    assert x == pytest.approx([0.0015], abs=1e-7)


def test_an_effect_whose_predictions_move_by_exactly_min_effect_floors_is_kept():
    """min_effect 1.0 and a floor equal to B's change of predictions (computed here as the
    stand-in sums its signals: RMS of (0 + a pA) - (0 + a pA + b pB) over both episodes): "less
    than min_effect floors" is false at equality, B stays; a floor 1e-9 above drops it."""
    a, b = 0.15, 0.03
    full = np.zeros(len(P_A)) + a * P_A + b * P_B
    without = np.zeros(len(P_A)) + a * P_A
    d = np.concatenate([(without - full)[:, None].ravel()] * 2)
    size = float(np.sqrt(np.mean(d * d)))
    assert size == pytest.approx(b / math.sqrt(2))
    _, _, dropped, _ = _case(a, b, 0.01, floor_rms=size, min_effect=1.0)
    assert dropped == []
    _, _, dropped, _ = _case(a, b, 0.01, floor_rms=size + 1e-9, min_effect=1.0)
    assert dropped == ["mounting_offset"]


def test_the_backward_bootstrap_draws_from_the_configured_seed_or_the_given_generator(
        monkeypatch):
    """A re-run must reach the same verdict: without a generator the paired block bootstrap
    draws from default_rng([cfg.seed, 1]); a generator passed in is the one used."""
    seen = []
    orig = significance.paired_gain_bound

    def spy(cur, new, rng, n):
        seen.append((rng, rng.bit_generator.state))
        return orig(cur, new, rng, n)

    monkeypatch.setattr(significance, "paired_gain_bound", spy)
    _bw((0.05, 0.03, 0.01), (0.05, 0.03, 0.01), [0.05, 0.03], seed=7)
    assert seen[0][1] == np.random.default_rng([7, 1]).bit_generator.state
    seen.clear()
    mine = np.random.default_rng(123)
    _bw((0.05, 0.03, 0.01), (0.05, 0.03, 0.01), [0.05, 0.03], rng=mine, seed=7)
    assert seen[0][0] is mine


# -- the backward search (_joint_then_prune) on the _analyze loop's stand-in ----------------------

def test_the_backward_search_widens_a_joint_fit_stuck_on_a_search_bound(loop):
    """Data 0.45 pA + 0.35 pB + 0.01 n. Round 1 accepts position_offset (value 0.45); the
    forward steps then stop (mounting_offset's round-2 score 0.01 < min_gain). The forward model
    leaves sqrt((0.35^2 + 0.01^2) / 2) = 0.25 rad on the select split, far above backward_above
    x 1 mrad, so the round-1 candidates (scores 0.9 and 0.5 >= min_gain) are fitted together:
    mounting_offset's search range ends at 0.3 rad (fit.space), short of 0.35, so its joint fit
    sits on that bound. Until session 15 the pruning dropped it there as an implausible fit and
    the forward model stood (0.25 rad left); issue 11 item 2: a fit at a range's edge is a reason
    to widen it, never to drop the effect. The pruning refits it in the range widened toward its
    0.8 rad hard limit (gates.widen_at_bounds): both offsets, at their true values."""
    scores = {"position_offset": 0.9, "mounting_offset": [0.5, 0.01]}
    res = loop(0.45, 0.35, 0.01, floor=0.001, search="both", scores=scores)
    assert "backward_search" in res.timing  # the search ran and switched
    assert [c.effect for c in res.causes] == ["position_offset", "mounting_offset"]
    assert res.causes[0].params["offset"]["value"] == pytest.approx([0.45], abs=1e-6)
    assert res.causes[1].params["offset"]["value"] == pytest.approx([0.35], abs=1e-6)
    assert "backward search from position_offset, mounting_offset kept" in res.stop_reason
    assert res.causes[1].widened == ["offset[j0] reached a search bound in the backward pass: "
                                     "range widened to [-0.3, 0.8]"]  # said, not silent


def test_a_final_fit_that_lands_on_a_search_bound_is_refitted_in_a_widened_range(loop, monkeypatch):
    """Training log: 0.29 pB + 0.01 n; select log: 0.40 pB + 0.01 n (test log as training). The
    forward round fits mounting_offset on training alone: 0.29, inside its +-0.3 rad search range,
    accepted. The final refit on training + select minimises 20 [(0.29 - v)^2 + (0.40 - v)^2]:
    v = 0.345 lies beyond 0.3, so the fit stops on the bound and is refitted in the range widened
    toward the hard limit 0.8 rad: the cause reports 0.345 and says its range was widened."""
    per_traj = {"log0": 0.29, "log1": 0.40, "log2": 0.29}
    real_ds = _loop_tests._DS

    def ds_with_own_b(trajectories, **kw):
        for tr in trajectories:
            tr.qpos = (per_traj[tr.name] * P_B + 0.01 * NOISE)[:, None]
        return real_ds(trajectories, **kw)

    monkeypatch.setattr(_loop_tests, "_DS", ds_with_own_b)
    res = loop(0.0, 0.0, 0.0, floor=0.001, scores={"mounting_offset": 0.9})
    assert [c.effect for c in res.causes] == ["mounting_offset"]
    assert res.rounds[0][0].accepted and res.rounds[0][0].widened == []  # forward: inside
    assert res.causes[0].params["offset"]["value"] == pytest.approx([0.345], abs=1e-6)
    assert res.causes[0].widened == ["offset[j0] reached its upper search bound 0.3 rad: range "
                                     "widened to [-0.3, 0.8] rad (hard limit [-0.8, 0.8])"]


def test_each_named_cause_reports_the_held_out_errors_of_the_model_up_to_it(loop):
    """Data 0.05 pA + 0.03 pB + 0.01 n, both offsets named (position_offset first: rise 25 > 9).
    After position_offset the held-out residual is 0.03 pB + 0.01 n: RMSE sqrt((0.03^2 + 0.01^2)
    / 2) = 22.4 mrad, MAE its mean absolute value; after mounting_offset too it is 0.01 n: RMSE
    0.01 / sqrt(2), MAE 0.01 mean |n| (both MAEs computed here from the patterns). Neither
    cause sits on a bound nor has an equivalent: empty lists, not None."""
    res = loop(0.05, 0.03, 0.01, floor=0.001,
               scores={"position_offset": 0.7, "mounting_offset": 0.6})
    a_cause, b_cause = res.causes
    assert (a_cause.effect, b_cause.effect) == ("position_offset", "mounting_offset")
    assert a_cause.heldout_rmse_after == pytest.approx(math.sqrt((0.03 ** 2 + 0.01 ** 2) / 2),
                                                       rel=1e-4)
    assert a_cause.heldout_mae_after == pytest.approx(
        float(np.mean(np.abs(0.03 * P_B + 0.01 * NOISE))), rel=1e-4)
    assert b_cause.heldout_rmse_after == pytest.approx(0.01 / math.sqrt(2), rel=1e-4)
    assert b_cause.heldout_mae_after == pytest.approx(float(np.mean(np.abs(0.01 * NOISE))),
                                                      rel=1e-4)
    assert 0.0058 < b_cause.heldout_mae_after < 0.0066  # 0.01 x mean |sin| ~ 0.01 x 2 / pi
    for c in res.causes:
        assert c.equivalent == [] and c.flags == [] and c.widened == []


# -- analyze(): what a user passing the wrong things is told; defaults passed on ---------------------

def test_analyze_refuses_log_paths_and_a_dict_config_with_what_to_do(monkeypatch):
    from lowcostdex.gap import analyze as public_analyze
    from lowcostdex.gap.dataset import Dataset

    with pytest.raises(TypeError) as e:
        public_analyze(["log_0.csv"])
    assert str(e.value) == ("analyze takes a Dataset, not list: read the logs first, e.g. "
                            "analyze(load_dataset(['log_0.csv', ...], model='model.xml'))")
    ds = Dataset.__new__(Dataset)  # a Dataset (the analysis itself is replaced below)
    with pytest.raises(TypeError) as e:
        public_analyze(ds, {"min_gain": 0.1})
    assert str(e.value) == "config must be a GapConfig, not dict"

    seen = []

    class _Result:
        mujoco_warnings = None

    def fake(ds_, cfg, prog):
        seen.append((ds_, cfg, prog, prog("stage", 0.5)))
        return _Result()

    monkeypatch.setattr(_loop_tests.AZ, "_analyze", fake)
    res = public_analyze(ds)  # defaults: GapConfig(), a progress callback that does nothing
    assert seen[0][0] is ds and seen[0][1] == GapConfig() and seen[0][3] is None
    assert res.mujoco_warnings == {}  # nothing raised by MuJoCo: an empty count, not None
    mine, calls = GapConfig(min_gain=0.1), []
    public_analyze(ds, mine, lambda s, f: calls.append((s, f)))
    assert seen[1][1] is mine and calls == [("stage", 0.5)]


def test_the_backward_search_keeps_an_effect_only_if_its_predictions_differ_visibly(loop):
    """Data 0.05 pA + 0.03 pB + 0.001 n; forward: position_offset only (mounting_offset's round-2
    score 0.01 < min_gain). The joint model adds 0.03 pB, which moves the predictions by RMS
    0.03 / sqrt(2) = 21.2 mrad. With a 30 mrad floor, min_effect 0.75 asks for 22.5 mrad: the
    pruning drops it (and the switch check would refuse it: on this stand-in both measure the
    same 21.2 mrad); with a 28 mrad floor (21.0 mrad) it is kept and the search switches. (explain_above and
    backward_above lowered so that these floors leave the analysis running: baseline select RMSE
    sqrt((0.05^2 + 0.03^2) / 2) = 41 mrad, forward 21.2 mrad.)"""
    scores = {"position_offset": 0.9, "mounting_offset": [0.5, 0.01]}
    kw = dict(search="both", scores=scores, explain_above=1.0, backward_above=0.5)
    assert 0.75 * 0.028 < 0.03 / math.sqrt(2) < 0.75 * 0.030
    res = loop(0.05, 0.03, 0.001, floor=0.030, **kw)
    assert "backward_search" in res.timing
    assert [c.effect for c in res.causes] == ["position_offset"]
    res = loop(0.05, 0.03, 0.001, floor=0.028, **kw)
    assert [c.effect for c in res.causes] == ["position_offset", "mounting_offset"]


# -- _rank: the score statistic on the stand-in engine -----------------------------------------------

def test_rank_scores_each_candidate_by_the_share_of_the_residual_its_signal_explains():
    """Data 0.05 pA + 0.03 pB + 0.01 n on two episodes; patterns orthogonal with equal energy, so
    the share of the residual's energy a candidate's sensitivity column (value x its pattern)
    explains is its squared amplitude over the total. Nominal model: position_offset
    0.0025 / 0.0035 = 0.714, mounting_offset 0.0009 / 0.0035 = 0.257, residual RMS
    sqrt(0.0035 / 2). With position_offset = 0.05 in the model: mounting_offset explains
    0.0009 / 0.001 = 0.9 of what is left, RMS sqrt(0.001 / 2)."""
    data = (0.05 * P_A + 0.03 * P_B + 0.01 * NOISE)[:, None]
    ds = _DS({}, [_Tr("m", T.copy())], set())
    ds.trajectories[0].qpos, ds.joints, ds.timestep = data, ("j0",), 0.002
    eng = BwEngine(ds)
    eng.joints = ("j0",)
    segs = [Window(0, 0, N, 0), Window(0, 0, N, 0)]
    empty = fitmod.Structure.build((), ("j0",), CTX)
    table, rms = _rank(eng, segs, empty, np.zeros(0), ["position_offset", "mounting_offset"], CTX)
    assert [c.effect for c in table] == ["position_offset", "mounting_offset"]
    assert [c.score for c in table] == pytest.approx([0.0025 / 0.0035, 0.0009 / 0.0035], rel=1e-9)
    assert rms == pytest.approx(math.sqrt(0.0035 / 2), rel=1e-12)
    cur = fitmod.Structure.build(("position_offset",), ("j0",), CTX)
    table, rms = _rank(eng, segs, cur, np.array([0.05]), ["mounting_offset"], CTX)
    assert [(c.effect, c.score) for c in table] == [("mounting_offset", pytest.approx(0.9))]
    assert rms == pytest.approx(math.sqrt(0.001 / 2), rel=1e-9)
