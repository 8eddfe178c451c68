"""The gap analysis' decision rules as pure functions, on hand-computed inputs (no replay).

Each test takes its expected numbers from the rule written in the function's docstring (or the
module's), worked out by hand in the comments, on tiny per-episode / per-block error arrays and a
stand-in data set of a few samples. They run in well under a second, so mutation testing can judge
the whole population of these modules (``python bench/mutation.py gap-pure``) instead of waiting
for whole analyses per mutant (test_gap_decisions.py, ~0.03 mutants/s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from lowcostdex.gap import significance as S
from lowcostdex.gap.dataset import Window
from lowcostdex.gap.gain import Gain, bootstrap_ci, episode_errors, gain_with_ci
from lowcostdex.gap.results import UNEXPLAINED, CandidateResult, Cause, GapConfig, verdict_text
from lowcostdex.gap.selection import (
    fit_batches,
    mse_by_episode,
    probe_gains,
    select_gain_ci,
    select_results,
)


@dataclass
class _Traj:
    qpos: np.ndarray
    time: np.ndarray


@dataclass
class _DS:
    """What the functions under test read of a Dataset: trajectories' qpos/time, the step."""

    trajectories: list
    joints: tuple = ("j0",)
    timestep: float = 0.002


def _gain(rb: float, re: float, floor: float) -> Gain:
    rel = (rb - re) / rb
    # a 95 % interval about the gain, clear of zero when the gain is (the verdict reads it: a
    # gain whose interval reaches zero is "no reliable gain")
    ci = (0.5 * (rb - re), 1.5 * (rb - re))
    return Gain(rb, re, rb, re, rb - re, rel, ci, (ci[0] / rb, ci[1] / rb), floor, None, 2)


# -- verdicts -------------------------------------------------------------------------------------


def test_no_cause_and_a_held_out_error_above_two_floors_is_an_unexplained_discrepancy():
    assert UNEXPLAINED == 2.0  # results.py: "above this many noise floors"
    text = verdict_text([], _gain(3e-3, 3e-3, 1e-3), "no candidate signature explains it")
    assert text == ("discrepancy not explained by the candidate effects (held-out RMSE 0.003 rad,"
                    " 3x the noise floor; the selection stopped: no candidate signature "
                    "explains it)")


def test_no_cause_within_two_floors_is_no_significant_discrepancy():
    assert verdict_text([], _gain(2e-3, 2e-3, 1e-3), "x") == "no significant discrepancy"
    assert verdict_text([], _gain(1e-3, 1e-3, 1e-3), "x") == "no significant discrepancy"
    assert verdict_text([], _gain(2.001e-3, 2e-3, 1e-3), "x").startswith("discrepancy not")


def test_named_causes_with_the_held_out_error_before_and_after():
    causes = [Cause("latency", ("j0",), {}), Cause("coulomb_friction", ("j0",), {})]
    # 4 mrad -> 1 mrad: 75 % lower
    assert verdict_text(causes, _gain(4e-3, 1e-3, 1e-3), "x") == (
        "latency, coulomb_friction: held-out RMSE 0.004 -> 0.001 rad (75 % lower)")


def test_a_gain_worse_on_most_episodes_or_with_an_interval_through_zero_is_no_reliable_gain():
    # issue 11 item 5: Pham XL330's analysis read "79 % lower" while the extended model was worse
    # on 3 of its 4 test episodes and the gain's interval crossed zero
    causes = [Cause("gain_error", ("j0",), {})]
    g = Gain(0.01, 0.0021, 0.01, 0.0021, 0.0079, 0.79, (-0.001, 0.02), (-0.1, 0.9), 1e-3, None,
             4)
    text = verdict_text(causes, g, "x", worse=3)
    assert text.startswith("gain_error: no reliable gain (held-out RMSE 0.01 -> 0.0021 rad; ")
    assert "worse than the nominal model on 3 of 4 test episodes" in text
    assert "interval [-1, 20] mrad includes zero" in text and "not recommended" in text
    assert "% lower" not in text
    # better on 3 of 4 and an interval above zero: the gain stands
    ok = Gain(0.01, 0.0021, 0.01, 0.0021, 0.0079, 0.79, (0.002, 0.02), (0.2, 0.9), 1e-3, None, 4)
    assert verdict_text(causes, ok, "x", worse=1).endswith("(79 % lower)")
    # worse on 2 of 4 is not "most"; 3 of 4 is, whatever the interval says
    assert "no reliable gain" not in verdict_text(causes, ok, "x", worse=2)
    assert "on 3 of 4 test episodes" in verdict_text(causes, ok, "x", worse=3)
    # an effect acting in some test episodes only (sim4's torque_limit06_motor_posonly, session
    # 15: 126.4 -> 1.35 mrad, interval [0, 206] mrad): the episodes it leaves unchanged resample
    # to a gain of exactly 0 - a tie, not a loss; the gain stands
    tie = Gain(0.126, 0.00135, 0.1, 0.001, 0.12465, 0.989, (0.0, 0.206), (0.0, 0.99), 7e-4,
               None, 3)
    assert verdict_text(causes, tie, "x", worse=0).endswith("(99 % lower)")
    # ... but any resampled loss below zero, however small, is "no reliable gain"
    below = Gain(0.126, 0.00135, 0.1, 0.001, 0.12465, 0.989, (-1e-9, 0.206), (-1e-8, 0.99),
                 7e-4, None, 3)
    assert "includes zero" in verdict_text(causes, below, "x", worse=1)
    # one test episode has no interval: its sign decides
    one = Gain(0.01, 0.012, 0.01, 0.012, -0.002, -0.2, (-0.002, -0.002), (-0.2, -0.2), 1e-3,
               None, 1)
    assert "no lower than the nominal" in verdict_text(causes, one, "x", worse=0)


# -- the held-out gain ----------------------------------------------------------------------------


def test_gain_of_identical_episodes_has_a_degenerate_interval_at_its_value():
    # sse 0.04 / 0.01 over 100 samples each: RMSE sqrt(0.08/200) = 0.02 and sqrt(0.02/200) = 0.01;
    # every resample of identical episodes gives the same numbers
    g = gain_with_ci([0.04, 0.04], [0.01, 0.01], [100, 100], [1.0, 3.0], [0.5, 0.5], 1e-4,
                     np.random.default_rng(0), 50)
    assert (g.baseline_rmse, g.extended_rmse) == pytest.approx((0.02, 0.01))
    assert (g.absolute, g.relative) == pytest.approx((0.01, 0.5))
    assert g.ci95 == pytest.approx((0.01, 0.01)) and g.relative_ci95 == pytest.approx((0.5, 0.5))
    assert (g.baseline_mae, g.extended_mae) == pytest.approx((4.0 / 200, 1.0 / 200))
    # reducible (4e-4 - 1e-4) / (4e-4 - 1e-4) ... MSE_b 4e-4, MSE_e 1e-4, floor 1e-4
    assert g.reducible_explained == pytest.approx(1.0)
    assert g.noise_floor == pytest.approx(0.01) and g.episodes == 2
    d = g.to_dict()
    assert d == {"baseline_rmse": g.baseline_rmse, "extended_rmse": g.extended_rmse,
                 "baseline_mae": g.baseline_mae, "extended_mae": g.extended_mae,
                 "absolute": g.absolute, "relative": g.relative, "ci95": list(g.ci95),
                 "relative_ci95": list(g.relative_ci95), "noise_floor": g.noise_floor,
                 "reducible_explained": g.reducible_explained, "episodes": 2}


def test_gain_interval_spans_the_episodes_and_pairs_them():
    # episode 0 improves from 0.08 to 0.02, episode 1 not at all (0.02): resamples {0,0} give
    # relative 1 - sqrt(0.04/0.16) = 0.5, {1,1} give 0, mixed 1 - sqrt(0.04/0.10)
    g = gain_with_ci([0.08, 0.02], [0.02, 0.02], [100, 100], [0, 0], [0, 0], 0.0,
                     np.random.default_rng(1), 400)
    assert g.relative_ci95 == pytest.approx((0.0, 0.5))
    assert g.ci95 == pytest.approx((0.0, math.sqrt(0.16 / 200) - math.sqrt(0.04 / 200)))
    assert g.relative == pytest.approx(1 - math.sqrt(0.04 / 0.10))
    # floor 0: everything reducible, (MSE_b - MSE_e) / MSE_b = 0.06 / 0.10
    assert g.reducible_explained == pytest.approx(0.6)


def test_reducible_fraction_needs_more_than_five_percent_of_the_error_above_the_floor():
    # MSE_b = 0.02 / 100 = 2e-4; 5 % of it is 1e-5
    kw = dict(n=[50, 50], sae_b=[0, 0], sae_e=[0, 0], rng=np.random.default_rng(0), n_boot=10)
    at = gain_with_ci([0.01, 0.01], [0.005, 0.005], floor_mse=1.9e-4 + 1e-12, **kw)
    assert at.reducible_explained is None  # reducible 1e-5 - 1e-12: not above 5 %
    above = gain_with_ci([0.01, 0.01], [0.0095, 0.0095], floor_mse=1.8e-4, **kw)
    # (2e-4 - 1.9e-4) / (2e-4 - 1.8e-4) = 0.5
    assert above.reducible_explained == pytest.approx(0.5)


@pytest.mark.filterwarnings("ignore:invalid value:RuntimeWarning")  # 0/0 resamples
def test_a_perfect_baseline_has_no_relative_gain():
    g = gain_with_ci([0.0, 0.0], [0.0, 0.0], [10, 10], [0, 0], [0, 0], 0.0,
                     np.random.default_rng(0), 10)
    assert g.relative == 0.0 and g.absolute == 0.0 and g.reducible_explained is None


def test_bootstrap_ci_resamples_k_units_and_takes_the_central_percentiles():
    seen = {}

    def stat(idx):
        seen["idx"] = idx
        return np.arange(idx.shape[0], dtype=float)  # 0 .. n_boot - 1

    lo, hi = bootstrap_ci(stat, 3, np.random.default_rng(0), n_boot=1001)
    assert seen["idx"].shape == (1001, 3)
    assert set(np.unique(seen["idx"])) == {0, 1, 2}
    # numpy's linear percentiles of 0..1000: 2.5 % -> 25, 97.5 % -> 975
    assert (lo, hi) == pytest.approx((25.0, 975.0))
    lo, hi = bootstrap_ci(stat, 3, np.random.default_rng(0), n_boot=1001, level=0.5)
    assert (lo, hi) == pytest.approx((250.0, 750.0))
    assert bootstrap_ci(stat, 2, np.random.default_rng(0))[1] == pytest.approx(0.975 * 1999)


def test_episode_errors_by_hand():
    # two episodes of one joint... two joints: residuals [[1, 0], [1, 2]] and [[-3, 0]]
    ds = _DS([_Traj(np.array([[1.0, 0.0], [1.0, 2.0], [9.0, 9.0]]), np.arange(3.0)),
              _Traj(np.array([[9.0, 9.0], [-3.0, 0.0]]), np.arange(2.0))], ("a", "b"))
    eps = [Window(0, 0, 2, 0), Window(1, 1, 2, 1)]
    pred = [np.zeros((2, 2)), np.zeros((1, 2))]
    e = episode_errors(ds, eps, pred, ["a", "b"])
    # all residuals 1, 0, 1, 2, -3, 0: squares 1+0+1+4+9+0 = 15 over 6, abs 7 over 6
    assert e["heldout_rmse"] == pytest.approx(math.sqrt(15 / 6))
    assert e["heldout_mae"] == pytest.approx(7 / 6)
    assert e["per_joint_rmse"] == pytest.approx({"a": math.sqrt(11 / 3), "b": math.sqrt(4 / 3)})
    assert e["per_joint_mae"] == pytest.approx({"a": 5 / 3, "b": 2 / 3})
    assert e["per_episode_rmse"] == pytest.approx([math.sqrt(6 / 4), math.sqrt(9 / 2)])
    assert e["per_episode_mae"] == pytest.approx([1.0, 1.5])


# -- one selection round --------------------------------------------------------------------------


def _table(*scores):
    return [CandidateResult(f"c{i}", s) for i, s in enumerate(scores)]


def test_fit_batches_top_k_then_score_ties_then_a_second_batch():
    cfg = GapConfig(top_k=2, rank_tie=0.5, min_gain=0.05)
    t = _table(0.96, 0.95, 0.945, 0.90, 0.5, 0.3, 0.04)
    first, second = fit_batches(t, cfg)
    # best unexplained share 0.04, ties within 1.5 x 0.04 = 0.06: 0.945 (0.055) ties
    assert [c.effect for c in first] == ["c0", "c1", "c2"]
    # then the next top_k with a score of at least min_gain
    assert [c.effect for c in second] == ["c3", "c4"]
    assert fit_batches([], cfg) == [[], []]


def test_fit_batches_boundaries_are_inclusive():
    # unexplained 0.25, rank_tie 1: a share of exactly 0.5 ties; a score of exactly min_gain
    # reaches the second batch
    cfg = GapConfig(top_k=1, rank_tie=1.0, min_gain=0.25)
    first, second = fit_batches(_table(0.75, 0.5, 0.25, 0.125), cfg)
    assert [c.effect for c in first] == ["c0", "c1"]
    assert [c.effect for c in second] == ["c2"]
    first, second = fit_batches(_table(0.75, 0.4, 0.3, 0.2), GapConfig(top_k=2, min_gain=0.1))
    assert [c.effect for c in first] == ["c0", "c1"] and [c.effect for c in second] == ["c2", "c3"]


def test_select_gain_is_one_minus_the_mse_ratio_with_its_5_percent_bound():
    rel, low = select_gain_ci(np.array([1.0, 1.0]), np.array([0.5, 0.5]),
                              np.random.default_rng(0), 100)
    assert (rel, low) == pytest.approx((0.5, 0.5))  # 1 - 1/2 on every resample
    # episode 0 halves, episode 1 unchanged: 1 - 1.5/2 = 0.25; the resamples of episode 1 twice
    # (a quarter of them) give 0, so the 5 % bound is 0
    rel, low = select_gain_ci(np.array([1.0, 1.0]), np.array([0.5, 1.0]),
                              np.random.default_rng(0), 400)
    assert rel == pytest.approx(0.25) and low == pytest.approx(0.0)
    # a worse model: negative gain
    rel, low = select_gain_ci(np.array([1.0, 1.0]), np.array([2.0, 2.0]),
                              np.random.default_rng(0), 20)
    assert (rel, low) == pytest.approx((-1.0, -1.0))
    # nothing to lower: the ratio does not divide by zero (no nan reaches the comparisons)
    rel, low = select_gain_ci(np.zeros(2), np.zeros(2), np.random.default_rng(0), 20)
    assert math.isfinite(rel) and math.isfinite(low)


def _two_episode_ds():
    # episode 0: samples 1..3 of traj 0 (the first is scored too: start, not score_from);
    # episode 1: samples 0..1 of traj 1
    ds = _DS([_Traj(np.array([[5.0], [1.0], [2.0], [3.0]]), np.arange(4) * 0.125),
              _Traj(np.array([[-1.0], [1.0]]), np.arange(2) * 0.125)])
    return ds, [Window(0, 1, 4, 2), Window(1, 0, 2, 1)]


def test_mse_by_episode_sums_squares_and_absolutes_per_episode():
    ds, eps = _two_episode_ds()
    sse, sae, n = mse_by_episode(ds, eps, [np.zeros((3, 1)), np.ones((2, 1))])
    assert sse.tolist() == [1 + 4 + 9, 4 + 0] and sae.tolist() == [6, 2]
    assert n.tolist() == [3, 2] and n.dtype == float


def test_select_results_and_probe_gains_replay_each_model_and_compare():
    ds, eps = _two_episode_ds()
    truth = [np.array([[1.0], [2.0], [3.0]]), np.array([[-1.0], [1.0]])]

    class Track:
        def __init__(self, err):
            self.err = err

        def effects(self):
            return self.err

    def predict(windows, columns):
        assert windows == eps
        return [[t + err for t in truth] for err in columns]

    sel_cur = mse_by_episode(ds, eps, [t + 1.0 for t in truth])  # SSE 3 and 2
    out = select_results(predict, ds, eps, {"a": Track(0.5), "b": Track(2.0)}, ["a", "b"],
                         sel_cur, np.random.default_rng(0), GapConfig(bootstrap=50))
    # a: SSE 0.75 + 0.5 = 1.25 of 5 -> 0.75 lower on every episode; b: 12 + 8 = 20 -> -3
    assert out["a"][0] == pytest.approx(0.75) and out["a"][1] == pytest.approx(0.75)
    assert out["a"][2].tolist() == pytest.approx([0.75, 0.5])
    assert out["b"][0] == pytest.approx(-3.0) and out["b"][2].tolist() == pytest.approx([12, 8])

    calls = []

    def run(windows, columns, goal_shift):
        calls.append(goal_shift)
        cur, new = columns
        assert cur == [0.2] and new == [0.1]
        # the later goals add 10 x shift [steps] to both models' errors
        k = goal_shift / ds.timestep * 10
        return [[t + cur[0] + k for t in truth], [t + new[0] + k for t in truth]], None

    g = probe_gains(run, ds, eps, [0.2], [0.1], (0.0, 0.01))
    assert calls == pytest.approx([0.0, 0.01 * 0.002])
    # shift 0: errors 0.2 vs 0.1 on 5 samples: 1 - 0.01/0.04 = 0.75;
    # shift 0.01: 0.3 vs 0.2: 1 - 0.04/0.09
    assert g == pytest.approx([0.75, 1 - 0.04 / 0.09])
    assert probe_gains(run, ds, eps, [0.2], [0.1], ()) == []


# -- significance ---------------------------------------------------------------------------------


def test_paired_bound_leaves_out_ties_so_a_gain_in_one_block_counts():
    # significance.py: a torque limit's gain sat in one block of 11; the resamples that miss it
    # are ties and left out. Here block 5 of 11 is explained entirely: 11 blocks drawn per
    # resample, each draw of block 5 lowers the sum by 1 -> a resample's gain is m / 11 (m: how
    # often block 5 was drawn); m = 0 is a tie, so the 5 % bound is 1 / 11, not 0
    cur = np.ones(11)
    new = np.ones(11)
    new[5] = 0.0
    assert S.TIE == 1e-4
    low = S.paired_gain_bound(cur, new, np.random.default_rng(0), 2000)
    assert low == pytest.approx(1 / 11)
    # with ties counted (tie < 0) a quarter of the resamples miss the block: bound 0
    assert S.paired_gain_bound(cur, new, np.random.default_rng(0), 2000, tie=-1.0) == 0.0


def test_paired_bound_edge_cases():
    rng = np.random.default_rng(0)
    assert S.paired_gain_bound([1.0], [0.0], rng, 100) == -math.inf  # fewer than 2 blocks
    assert S.paired_gain_bound([1.0, 1.0], [1.0, 1.0], rng, 100) == 0.0  # every resample a tie
    # a uniformly better model: every resample 1 - 0.5 = 0.5, whatever the run length
    for length in (None, 1, 2, 5):
        assert S.paired_gain_bound(np.ones(5), np.full(5, 0.5), rng, 100, length=length) \
            == pytest.approx(0.5)
    # a uniformly worse one
    assert S.paired_gain_bound(np.ones(4), np.full(4, 1.5), rng, 100) == pytest.approx(-0.5)
    # a change of exactly... 5e-5 relative is a tie (|1 - 0.99995| <= 1e-4): bound 0
    assert S.paired_gain_bound(np.ones(4), np.full(4, 0.99995), rng, 100) == 0.0


def test_paired_bound_runs_of_blocks_and_its_level():
    # runs of all 4 blocks (length 4): every resample is the whole series -> exact gain
    cur, new = np.array([4.0, 1.0, 1.0, 1.0]), np.array([1.0, 1.0, 1.0, 1.0])
    assert S.paired_gain_bound(cur, new, np.random.default_rng(0), 50, length=4) \
        == pytest.approx(1 - 4 / 7)
    # single blocks: resamples without block 0 are ties (left out); with it, m draws of block 0
    # among 4: gain 1 - 4 / (3m + 4); the lowest (m = 1) is 1 - 4/7 = 3/7, at the 5 % level
    low = S.paired_gain_bound(cur, new, np.random.default_rng(0), 2000, length=1)
    assert low == pytest.approx(3 / 7)
    high = S.paired_gain_bound(cur, new, np.random.default_rng(0), 2000, length=1, level=0.999)
    assert high > 3 / 7


def test_block_sse_splits_each_episode_into_blocks_and_joins_a_short_tail():
    dt = 0.125
    # 10 samples over 1.125 s in 0.375 s blocks: edges 0, 3, 6, 9 and a one-sample tail (0 s
    # long, < half a block) joined to the block before it
    r1 = np.arange(1.0, 11.0)[:, None]
    # 12 samples: the tail 9..11 spans 0.25 s >= 0.1875 s and stays its own block
    r2 = np.ones((12, 2))
    ds = _DS([_Traj(r1, np.arange(10) * dt), _Traj(r2, 5.0 + np.arange(12) * dt)], ("a", "b"))
    eps = [Window(0, 0, 10, 0), Window(1, 0, 12, 0)]
    out = S.block_sse(ds, eps, [np.zeros((10, 1)), np.zeros((12, 2))], 0.375)
    sq = (np.arange(1.0, 11.0) ** 2)
    assert out.tolist() == pytest.approx([sq[:3].sum(), sq[3:6].sum(), sq[6:].sum(),
                                          6.0, 6.0, 6.0, 6.0])


def test_residual_blocks_index_the_scored_samples_of_each_segment():
    dt = 0.125
    ds = _DS([_Traj(np.zeros((14, 2)), np.arange(14) * dt)], ("a", "b"))
    # segment 0 scores samples 2..11 (10 samples, as above: 3 blocks of 3, 3, 4 samples);
    # segment 1 scores samples 10..13 (4 samples, 0.375 s: one block plus a 0 s tail)
    segs = [Window(0, 0, 12, 2), Window(0, 8, 14, 10)]
    out = S.residual_blocks(ds, segs, 0.375)
    assert out == [slice(0, 6), slice(6, 12), slice(12, 20), slice(20, 28)]


def test_step_interval_holds_the_extrapolated_step_bias_on_either_side():
    # shift 0.4 at half the step -> zero-step bias 0.4 / (1 - 0.5) = 0.8; plus hypot(0.3, 0.4)
    mid, half = S.step_interval(np.array([1.0, 2.0]), np.array([0.3, 0.0]),
                                np.array([0.4, -0.25]), 0.5)
    assert mid.tolist() == [1.0, 2.0]
    assert half.tolist() == pytest.approx([0.8 + 0.5, 0.5 + 0.25])
    _, half = S.step_interval(np.array([0.0]), np.array([0.1]), np.array([0.0]), 0.75)
    assert half.tolist() == pytest.approx([0.1])


def test_andrews_bandwidth_small_samples_and_flat_scores():
    assert S.andrews_bandwidth(np.ones((2, 1))) == 0.0  # fewer than 3 blocks
    assert S.andrews_bandwidth(np.ones((10, 2))) == 0.0  # no variation: nothing to fit
    # an AR(1) plug-in by hand for x = [1, -1, 1, -1, 1, -1] centred (mean 0):
    # rho = sum x_t x_(t-1) / sum x_(t-1)^2 = -5 / 5 = -1 -> clipped to -0.97;
    # residuals x_t - rho x_(t-1) = +-(1 - 0.97) = +-0.03 -> s2 = 0.0009
    x = np.array([1.0, -1.0, 1.0, -1.0, 1.0, -1.0])[:, None]
    rho, s2 = -0.97, 0.03 ** 2
    assert _andrews_eq_6_4(x[:, 0], rho, s2) == pytest.approx(21.3, abs=0.1)  # > nb - 1
    assert S.andrews_bandwidth(x) == 5.0  # capped at nb - 1
    # an AR(1) series with coefficient 0.5 (64 blocks, seeded normal innovations); the plug-in
    # from the sample's own rho and s2
    e = np.random.default_rng(3).normal(size=64)
    y = np.zeros(64)
    for t in range(1, 64):
        y[t] = 0.5 * y[t - 1] + e[t]
    yc = y - y.mean()
    rho = float(yc[1:] @ yc[:-1] / (yc[:-1] @ yc[:-1]))
    s2 = float(np.mean((yc[1:] - rho * yc[:-1]) ** 2))
    want = _andrews_eq_6_4(yc, rho, s2)
    assert 0 < want < 63 and 0.3 < rho < 0.9
    assert S.andrews_bandwidth(y[:, None]) == pytest.approx(want)
    # two identical columns: the same bandwidth as one (unit weights in numerator and denominator)
    assert S.andrews_bandwidth(np.stack([y, y], 1)) == pytest.approx(want)


def _andrews_eq_6_4(x, rho, s2):
    """Andrews (1991) eq. 6.4, Bartlett kernel, AR(1) plug-in of one series of nb values:
    alpha(1) = 4 rho^2 s2^2 / ((1 - rho)^6 (1 + rho)^2) / (s2^2 / (1 - rho)^4),
    bandwidth = 1.1447 (alpha(1) nb)^(1/3)."""
    alpha = (4 * rho ** 2 * s2 ** 2 / ((1 - rho) ** 6 * (1 + rho) ** 2)) / (s2 ** 2 / (1 - rho) ** 4)
    return 1.1447 * (alpha * len(x)) ** (1 / 3)


def test_residual_blocks_keep_a_tail_of_half_a_block_and_never_lose_a_short_segment():
    dt = 0.125
    ds = _DS([_Traj(np.zeros((30, 1)), np.arange(30) * dt)])
    # 12 samples, 0.375 s blocks: edges 0, 3, 6, 9; the tail 9..11 spans 0.25 s >= 0.1875 s: kept
    assert S.residual_blocks(ds, [Window(0, 0, 12, 0)], 0.375) == [
        slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)]
    # 0.25 s blocks of 6 samples: edges 0, 2, 4; the tail 4..5 spans exactly half a block
    # (0.125 s, not shorter): kept
    assert S.residual_blocks(ds, [Window(0, 0, 6, 0)], 0.25) == [
        slice(0, 2), slice(2, 4), slice(4, 6)]
    # a segment shorter than half a block is one block, not none
    assert S.residual_blocks(ds, [Window(0, 5, 7, 5)], 1.0) == [slice(0, 2)]
    # blocks of one sample each (edges 0, 1, 2; the last, 0 s long, joins the one before)
    assert S.residual_blocks(ds, [Window(0, 0, 3, 0)], dt) == [slice(0, 1), slice(1, 3)]


def test_block_sse_keeps_a_tail_of_half_a_block_and_never_loses_a_short_episode():
    dt = 0.125
    e = np.arange(1.0, 31.0)[:, None]
    ds = _DS([_Traj(e, np.arange(30) * dt)])
    sq = e[:, 0] ** 2
    out = S.block_sse(ds, [Window(0, 0, 6, 0)], [np.zeros((6, 1))], 0.25)
    assert out.tolist() == pytest.approx([sq[0:2].sum(), sq[2:4].sum(), sq[4:6].sum()])
    out = S.block_sse(ds, [Window(0, 5, 7, 5)], [np.zeros((2, 1))], 1.0)
    assert out.tolist() == pytest.approx([sq[5:7].sum()])
    out = S.block_sse(ds, [Window(0, 0, 3, 0)], [np.zeros((3, 1))], dt)
    assert out.tolist() == pytest.approx([sq[0], sq[1] + sq[2]])


def test_andrews_bandwidth_is_scale_free_and_clips_rho_at_097():
    # eq. 6.4 is a ratio of s2^2 terms: scores a thousand times smaller (J^T r of a small
    # residual) give the same bandwidth
    y = np.zeros(64)
    e = np.random.default_rng(3).normal(size=64)
    for t in range(1, 64):
        y[t] = 0.5 * y[t - 1] + e[t]
    assert S.andrews_bandwidth(1e-3 * y[:, None]) == pytest.approx(S.andrews_bandwidth(y[:, None]))
    # a ramp of 1000 blocks has a sample rho of about 0.999: clipped to 0.97, whose bandwidth
    # 1.1447 (alpha 1000)^(1/3) = 117 blocks stays below the cap of 999
    x = np.arange(1000.0)
    xc = x - x.mean()
    assert xc[1:] @ xc[:-1] / (xc[:-1] @ xc[:-1]) > 0.99
    s2 = float(np.mean((xc[1:] - 0.97 * xc[:-1]) ** 2))
    want = _andrews_eq_6_4(xc, 0.97, s2)
    assert 100 < want < 130
    assert S.andrews_bandwidth(x[:, None]) == pytest.approx(want)
