"""An effect the others, refitted, do without is dropped (``exchange.prune_refitted``), by hand.

The backward pass (``analyze._backward``) judges an effect by leaving it out with the others at
the values they took beside it. When two effects share a signature the joint fit splits the
signal between them, and leaving either out alone leaves the other wrong: both look needed
although one of them, refitted alone, explains the data as well (redteam sim2
``queue_mass_arm2_posonly``: latency + mass + a 14 mrad backlash kept, held-out 8.37 mrad with
the play, 8.32 without it).

A stand-in engine replays a model as a sum of known signals (the patterns of
``test_gap_decisions_backward``: sinusoids of 1, 3 and 5 cycles per 40-sample episode, orthogonal,
sum of squares 20 each): ``position_offset`` adds A pA, ``mounting_offset`` adds B (pA + eps pB),
a near copy. Data y = a pA + e pB + c n (n the 5-cycle pattern no effect explains). Least squares
by hand: the joint fit is B = e / eps, A = a - e / eps, residual c n. Leaving B out with A
unchanged leaves (e / eps) pA + e pB + c n: a rise of ((e / eps)^2 + e^2) / c^2, far above
``min_gain / 2``. Refitted without B, A = a and the residual is e pB + c n: a rise of (e / c)^2.
Refitted without A, B = (a + eps e) / (1 + eps^2) and the residual is y - B (pA + eps pB). No
MuJoCo replay: a few ms per test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_gap_decisions_backward import CTX, EPS, NOISE, P_A, P_B, N, T
from test_gap_decisions_backward import _Engine as _SumEngine
from test_gap_decisions_pure import _DS, _Traj

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap.analyze import _backward
from lowcostdex.gap.exchange import prune_refitted
from lowcostdex.gap.results import GapConfig

E = 0.1  # mounting_offset's signature: pA + E pB, a near copy of position_offset's


class _Engine(_SumEngine):
    def _one(self, effects, shift):
        out = np.zeros(N)
        for e in effects:
            v = float(e.values["offset"][0])
            out = out + v * (P_A if e.name == "position_offset" else P_A + E * P_B)
        return out[:, None]


def _setup(a, e, c, **cfg):
    data = (a * P_A + e * P_B + c * NOISE)[:, None]
    ds = _DS([_Traj(data.copy(), T.copy()), _Traj(data.copy(), T.copy())])
    eng = _Engine(ds)
    ctx = CTX.with_ranges({})
    s = fitmod.Structure.build(("position_offset", "mounting_offset"), ("j0",), ctx)
    x = np.array([a - e / E, e / E])  # the joint least-squares fit (module docstring)
    config = GapConfig(**{"bootstrap": 200, "probes": (0.01, 0.02), **cfg})
    return eng, ds, ctx, s, x, config


def _rises(a, e, c):
    """Rises by hand (module docstring): B left out unchanged, B refitted away, A refitted away."""
    unchanged = ((e / E) ** 2 + e ** 2) / c ** 2
    without_b = (e / c) ** 2
    b = (a + E * e) / (1 + E ** 2)
    without_a = ((a - b) ** 2 + (e - E * b) ** 2 + c ** 2) / c ** 2 - 1
    return unchanged, without_b, without_a


def test_a_near_copy_the_other_refitted_does_without_is_dropped_though_the_backward_pass_keeps_it():
    a, e, c = 0.05, 0.001, 0.01
    unchanged, without_b, without_a = _rises(a, e, c)
    assert unchanged > 1 and without_b == pytest.approx(0.01) and without_a > 0.1
    eng, ds, ctx, s, x, config = _setup(a, e, c)
    r = eng.fit_fn([(s, x)])[0]  # the joint fit is exact: its residual is c n alone
    assert r @ r == pytest.approx(2 * 20 * c ** 2)
    # the backward pass (others unchanged) keeps both
    kept, _ = _backward(eng, ds, EPS, s, x.copy(), config, 1e-4, ctx, eng.fit_fn, [], EPS)
    assert set(kept.effects) == {"position_offset", "mounting_offset"}
    # refitted, position_offset alone does as well: mounting_offset goes, A refitted to a
    out, out_x, line = prune_refitted(eng, ds, EPS, EPS, s, x.copy(), eng.fit_fn, config, ctx)
    assert out.effects == ("position_offset",)
    assert out_x == pytest.approx([a], abs=1e-6)
    assert line == ("; mounting_offset dropped: the others refitted without it raise the error "
                    "by 1.0 % (< 2.5 %)")


def test_a_near_copy_whose_refitted_absence_raises_the_error_by_half_min_gain_is_kept():
    c = 0.01
    e = c * math.sqrt(0.026)  # refitted without B: rise 0.026 >= min_gain / 2 = 0.025
    eng, ds, ctx, s, x, config = _setup(0.05, e, c)
    out, out_x, line = prune_refitted(eng, ds, EPS, EPS, s, x.copy(), eng.fit_fn, config, ctx)
    assert out.effects == s.effects and line == "" and out_x == pytest.approx(x)
    # with min_gain 0.06 (half: 0.03) it goes
    eng, ds, ctx, s, x, config = _setup(0.05, e, c, min_gain=0.06)
    out, _, line = prune_refitted(eng, ds, EPS, EPS, s, x.copy(), eng.fit_fn, config, ctx)
    assert out.effects == ("position_offset",) and "2.6 % (< 3 %)" in line


def test_a_single_effect_is_never_judged():
    eng, ds, ctx, _, _, config = _setup(0.05, 0.0, 0.01)
    s = fitmod.Structure.build(("mounting_offset",), ("j0",), ctx)
    out, out_x, line = prune_refitted(eng, ds, EPS, EPS, s, np.array([0.0]), eng.fit_fn,
                                      config, ctx)
    assert out is s and out_x.tolist() == [0.0] and line == ""
