"""The edges of ``significance``'s "no effect" and block bookkeeping, by hand.

"No effect" of a parameter (``null_u``) comes from the catalogue: an offset's 0 rad, a gain's
scale 1 (log coordinates: 0), a torque limit's peak force (values *below* it act: side -1), none
for a limit without a finite null (a speed limit) or a shape parameter judged through its
amplitude (a Stribeck velocity). ``null_margins`` measures the distance in half-widths;
``block_sse`` / ``residual_blocks`` cut episodes into blocks of about ``seconds`` with a short
tail (under half a block) joined to the block before it. Times here are multiples of 0.25 s
(exact in binary), so every block edge is known by hand.
"""

from __future__ import annotations

import math
import pathlib
import sys

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.dataset import Window
from lowcostdex.gap.significance import block_sse, null_margins, null_u, residual_blocks

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from test_gap_decisions_pure import _DS, _Traj  # noqa: E402  (the stand-in Dataset, one home)


def _ctx(peak):
    return fitmod.Context(dt=0.002, peak_force=np.array([peak]), stall=np.array([math.inf]),
                          damping=np.array([0.1]))


def _free(name, param, peak=1.0):
    return fitmod.space(name, param, 0, _ctx(peak))


def test_no_effect_of_each_kind_of_parameter():
    # a torque limit acts below the peak force the model asks for: its null is the peak
    # (log coordinates), the side -1; 0.5 N m is a peak below 1 N m too
    assert null_u(_free("torque_limit", "torque", 0.5), _ctx(0.5)) == (
        pytest.approx(math.log(0.5)), -1)
    assert null_u(_free("torque_limit", "torque", 2.0), _ctx(2.0)) == (
        pytest.approx(math.log(2.0)), -1)
    # ... without a known positive finite peak it cannot be judged
    for peak in (0.0, math.inf):
        assert null_u(_free("torque_limit", "torque"), _ctx(peak)) is None
    # no finite null: a speed limit
    assert null_u(_free("velocity_limit", "speed"), _ctx(1.0)) is None
    # the catalogue nulls, both sides: an offset 0 rad, a gain's scale 1 (log: 0)
    assert null_u(_free("position_offset", "offset"), _ctx(1.0)) == (0.0, 0)
    assert null_u(_free("gain_error", "scale"), _ctx(1.0)) == (pytest.approx(0.0), 0)
    # an effect with several parameters is judged by its amplitude only
    assert null_u(_free("stribeck_friction", "static"), _ctx(1.0)) == (0.0, 0)
    assert null_u(_free("stribeck_friction", "velocity"), _ctx(1.0)) is None
    assert null_u(_free("backlash", "width"), _ctx(1.0)) == (0.0, 0)
    assert null_u(_free("backlash", "sensor"), _ctx(1.0)) is None


def test_margins_in_half_widths_from_no_effect():
    ctx = _ctx(0.5)
    s = fitmod.Structure.build(("stribeck_friction", "position_offset", "torque_limit"),
                               ("j0",), ctx)
    assert [(f.effect, f.param) for f in s.free] == [
        ("stribeck_friction", "static"), ("stribeck_friction", "velocity"),
        ("stribeck_friction", "coulomb"), ("position_offset", "offset"),
        ("torque_limit", "torque")]
    # Stribeck judged by its static level alone (its velocity and Coulomb level have no null
    # of their own): 0.02 N m, 0.005 wide: 4; an offset of -0.03 rad 0.01 wide: 3 (judged
    # after the unjudged ones); a torque limit 0.3 N m below a 0.5 N m peak: log(0.5 / 0.3) =
    # 0.511 from no effect, 0.1 wide: 5.1
    u = np.array([0.02, math.log(0.2), 0.5, -0.03, math.log(0.3)])
    half = np.array([0.005, 0.01, 0.01, 0.01, 0.1])
    m = null_margins(s, u, half, ctx)
    assert m == {"torque_limit": pytest.approx(math.log(0.5 / 0.3) / 0.1),
                 "position_offset": pytest.approx(3.0), "stribeck_friction": pytest.approx(4.0)}
    # a limit *above* the peak does nothing: negative distance, never a margin
    u[4] = math.log(0.6)
    assert null_margins(s, u, half, ctx)["torque_limit"] == pytest.approx(
        math.log(0.5 / 0.6) / 0.1)
    # an infinite interval holds everything: margin 0; a zero-width interval excludes every
    # value but the null itself: inf off it (0.5 rad), 0 at it
    half = np.array([0.0, 0.01, 0.01, 0.0, math.inf])
    u = np.array([0.0, math.log(0.2), 0.0, 0.5, math.log(0.3)])
    assert null_margins(s, u, half, ctx) == {"torque_limit": 0.0, "position_offset": math.inf,
                                             "stribeck_friction": 0.0}
    # no parameter that can be judged (no finite peak for the limit): inf
    assert null_margins(s, u, half, _ctx(math.inf))["torque_limit"] == math.inf


def _ds(nj=1, start=0.0):
    t = start + 0.25 * np.arange(40)  # 10 s at 4 Hz
    return _DS([_Traj(np.tile(np.arange(1.0, nj + 1.0), (40, 1)), t)],
               tuple(f"j{i}" for i in range(nj)))


def test_blocks_of_an_episode_with_a_short_tail_joined():
    # 0 .. 9.75 s in 3 s blocks: edges at 3, 6, 9 s (samples 12, 24, 36); the 0.75 s tail is
    # under half a block and joins the last: 12, 12, 16 samples
    ds, w = _ds(), [Window(0, 0, 40, 0)]
    zero = [np.zeros((40, 1))]
    assert block_sse(ds, w, zero, 3.0).tolist() == [12.0, 12.0, 16.0]
    assert residual_blocks(ds, w, 3.0) == [slice(0, 12), slice(12, 24), slice(24, 40)]
    # 2 s blocks: edges 8, 16, 24, 32; the 1.75 s tail stays its own block
    assert block_sse(ds, w, zero, 2.0).tolist() == [8.0] * 5
    # 7 s: one edge (sample 28) and a 2.75 s tail, under 3.5: one block
    assert block_sse(ds, w, zero, 7.0).tolist() == [40.0]
    assert residual_blocks(ds, w, 7.0) == [slice(0, 40)]
    # blocks shorter than a sample: each sample its own block, none empty
    assert block_sse(ds, w, zero, 0.1).tolist() == [1.0] * 40
    assert residual_blocks(ds, w, 0.1) == [slice(i, i + 1) for i in range(40)]


def test_blocks_of_an_episode_that_starts_inside_its_log_and_of_two_joints():
    # samples 8 .. 39 (2 .. 9.75 s) in 3 s blocks from 2 s: edges at 5, 8 s (samples 12, 24 of
    # the window); the 1.75 s tail stays: 12, 12, 8 samples. Two joints: errors 1 and 2 rad
    # per sample, 5 rad^2
    ds = _ds(nj=2, start=0.0)
    w = [Window(0, 8, 40, 8)]
    assert block_sse(ds, w, [np.zeros((32, 2))], 3.0).tolist() == [60.0, 60.0, 40.0]
    # residual vectors interleave the joints: blocks of 2 x samples; each further segment
    # follows the 64 entries of each one before it
    assert residual_blocks(ds, w * 3, 3.0) == [
        slice(64 * k + a, 64 * k + b) for k in range(3) for a, b in ((0, 24), (24, 48),
                                                                     (48, 64))]
    # a log that starts at 100 s: the same blocks
    ds = _ds(nj=1, start=100.0)
    assert block_sse(ds, [Window(0, 0, 40, 0)], [np.zeros((40, 1))], 3.0).tolist() == [
        12.0, 12.0, 16.0]
    # the predictions are subtracted: a prediction equal to the data leaves nothing
    assert block_sse(ds, [Window(0, 0, 40, 0)], [np.ones((40, 1))], 3.0).tolist() == [
        0.0, 0.0, 0.0]


def test_gains_of_errors_far_below_one_square_radian():
    """Real select errors are small (here 0.01 - 0.02 rad^2 per episode or block): a model
    that halves every one of them gains 50 % in every resample, so the bootstrap bounds are
    50 % too (nothing of the scale of the numbers may enter)."""
    from lowcostdex.gap.selection import select_gain_ci
    from lowcostdex.gap.significance import paired_gain_bound

    rng = np.random.default_rng(0)
    rel, low = select_gain_ci(np.full(3, 0.02), np.full(3, 0.01), rng, 200)
    assert (rel, low) == (pytest.approx(0.5), pytest.approx(0.5))
    assert paired_gain_bound(np.full(8, 0.01), np.full(8, 0.005), rng, 200) == pytest.approx(0.5)
    assert paired_gain_bound(np.full(8, 0.01), np.full(8, 0.005), rng, 200,
                             length=1) == pytest.approx(0.5)
    # one block: no bound
    assert paired_gain_bound(np.array([0.01]), np.array([0.005]), rng, 200) == -math.inf


def _andrews(g):
    """Andrews (1991) eq. 6.4, Bartlett kernel, unit weights, written out: each column's AR(1)
    fit (rho, innovation variance s2) on the demeaned column, alpha(1) = sum 4 rho^2 s2^2 /
    ((1 - rho)^6 (1 + rho)^2) / sum s2^2 / (1 - rho)^4, bandwidth 1.1447 (alpha nb)^(1/3)."""
    num = den = 0.0
    for col in g.T:
        x = col - col.mean()
        rho = float(np.dot(x[1:], x[:-1]) / np.dot(x[:-1], x[:-1]))
        s2 = float(np.mean([(x[i + 1] - rho * x[i]) ** 2 for i in range(len(x) - 1)]))
        num += 4 * rho ** 2 * s2 ** 2 / ((1 - rho) ** 6 * (1 + rho) ** 2)
        den += s2 ** 2 / (1 - rho) ** 4
    return 1.1447 * (num / den * len(g)) ** (1 / 3)


def test_the_hac_bandwidth_is_andrews_plug_in_over_the_score_columns():
    from lowcostdex.gap.significance import andrews_bandwidth

    # two score columns of different scale and persistence over 12 blocks
    a = np.array([1.0, 1.4, 1.1, 0.3, -0.2, -0.9, -1.2, -0.4, 0.2, 0.9, 0.5, -0.1])
    b = 10 * np.array([0.5, -0.3, 0.4, -0.6, 0.2, 0.1, -0.4, 0.3, -0.1, 0.2, -0.5, 0.4])
    g = np.stack([a, b], axis=1)
    want = _andrews(g)
    assert 0 < want < 11
    assert andrews_bandwidth(g) == pytest.approx(want, rel=1e-12)
    # a constant column carries no autocorrelation and is skipped, not the end of the sum
    g3 = np.stack([np.full(12, 2.0), a, b], axis=1)
    assert andrews_bandwidth(g3) == pytest.approx(want, rel=1e-12)
    # three blocks are enough for an estimate; two are not
    assert andrews_bandwidth(g[:3]) == pytest.approx(min(_andrews(g[:3]), 2.0), rel=1e-12)
    assert andrews_bandwidth(g[:3]) > 0
    assert andrews_bandwidth(g[:2]) == 0.0


class _Recording:
    """A generator that records what ``paired_gain_bound`` asks of it (numpy's draws)."""

    def __init__(self, seed):
        self.rng, self.calls = np.random.default_rng(seed), []

    def integers(self, low, high=None, size=None):
        self.calls.append((low, high, size))
        self.starts = self.rng.integers(low, high, size=size)
        return self.starts


@pytest.mark.parametrize("nb,ell", [(64, 4), (27, 3), (28, 4), (2, 2), (8, 2)])
def test_the_paired_block_bootstrap_is_kunsch_moving_blocks_of_cube_root_length(nb, ell):
    """Kunsch (1989)'s moving-block bootstrap with the block length of order n^(1/3) (Hall,
    Horowitz & Jing 1995, for variance-type estimates): runs of ceil(nb^(1/3)) consecutive
    blocks, each start uniform over 0..nb - ell, ceil(nb / ell) runs cut to nb blocks; the
    bound is the 5 % quantile of 1 - sum(new) / sum(cur) over the resamples, written out
    here. 64 blocks: runs of 4 (not 16 = 64^(2/3), not 3 = ceil(64^(1/4)))."""
    from lowcostdex.gap.significance import paired_gain_bound
    rng = np.random.default_rng(nb)
    cur = rng.uniform(1.0, 2.0, nb)
    new = cur * rng.uniform(0.6, 1.1, nb)
    rec = _Recording(5)
    got = paired_gain_bound(cur, new, rec, 300)
    k = math.ceil(nb / ell)
    assert rec.calls == [(0, nb - ell + 1, (300, k))]
    boot = []
    for row in rec.starts:
        idx = [s + j for s in row for j in range(ell)][:nb]
        boot.append(1.0 - new[idx].sum() / cur[idx].sum())
    boot = np.array(boot)
    assert got == pytest.approx(float(np.quantile(boot[np.abs(boot) > 1e-4], 0.05)), abs=1e-12)
