"""The step shift of a play's width (``significance.step_shift``): the interval's allowance for
the replay's physics step when the width's cost is not smooth in it.

The truth is written out here: least-squares problems whose residual is a formula of the width
(no replay, no MuJoCo). The "finer replay" has its optimum 0.6 mrad from the coarse fit's but a
local minimum at the coarse value (a cost jagged in the width, as sim2 backlash_body_turntable's
is at 0.5 ms), so Levenberg-Marquardt started there does not move.
"""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import significance as sig

N = 400
W0, W1 = 0.0300, 0.0306  # the coarse replay's best width and the finer one's [rad]


def _structure() -> fitmod.Structure:
    free = [fitmod.Free("backlash", "width", 0, 0.0, 0.1, 0.01, False, 2e-4)]
    return fitmod.Structure(("backlash",), ("j",), free)


def _width(s, x) -> float:
    return float(s.to_effects(x)[0].values["width"][0])


def _problem(seed: int):
    y = np.random.default_rng(seed).normal(0.0, 0.01, N)
    y -= y.mean()  # the coarse fit lands on W0 exactly

    def coarse(points):
        return [y + 3.0 * (_width(s, x) - W0) for s, x in points]

    def fine(points):  # optimum W1; a local minimum (a V of +-0.3 mrad) at W0
        out = []
        for s, x in points:
            w = _width(s, x)
            out.append(y + 3.0 * (abs(w - W0) + 2e-4 if abs(w - W0) < 3e-4 else w - W1))
        return out

    s = _structure()
    t = fitmod.Track(s, s.u(np.array([0.02])))
    fitmod.lockstep_lm([t], coarse, 60, rtol=1e-12)
    return t, fine


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_width_the_jagged_finer_replay_moves_is_found(seed):
    t, fine = _problem(seed)
    assert _width(t.structure, t.x) == pytest.approx(W0, abs=1e-4)
    assert fitmod.step_shift(t, fine, 20)[0] == 0.0  # LM alone: no move
    shift = sig.step_shift(t, fine, 20, 5e-4)
    moved = _width(t.structure, t.structure.x(t.u + shift))
    assert moved == pytest.approx(W1, abs=2.5e-4), moved
    assert abs(moved - W1) < abs(_width(t.structure, t.x) - W1)


def test_a_width_the_finer_replay_agrees_with_stays():
    t, _ = _problem(3)

    def same(points):
        return [t.r + 0.0 * _width(s, x) + 3.0 * (_width(s, x) - _width(t.structure, t.x))
                for s, x in points]

    assert sig.step_shift(t, same, 20, 5e-4)[0] == pytest.approx(0.0, abs=1e-6)
