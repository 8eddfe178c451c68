"""A scalar a fit leaves on a search bound that the data do not need is held at its null before the
bound can veto the effect (issue 11; gap-sim14, session 27).

The truth is written out here: a training residual linear in a mass_error's two scales, noise
(seeded, sigma 1 mrad, n = 1000; projected off the two pulls below so no cross term enters) plus
each joint's pull: the tilt's a constant shift 1e-2 (tilt - 2), the pan's its sensitivity e per
residual times (pan - 0.3) along an alternating +-1 pattern (its best fit on its lower search
bound, 0.3). The fitted cost is 0.5 n sigma^2 = 5e-4; the pan held at 1 adds 0.5 n (0.7 e)^2,
and the bar a held scalar must pass to be freed (``min_gain`` 0.05 of the cost: the pan at 1
costs at most 1 / 0.95 of the fit, a rise of 5.26 %) is e < 3.3e-4. The pan at 1e-5 (a 60 g
yoke on a joint the logs barely move: sim11 mass_tilt) is held at 1; at 1e-3 (a rise of 49 %) it
stays on its bound. In the third the tilt can take over most of the pan's pull (the pan also
shifts the residual 4e-2 x 1e-2 along the tilt's direction, with e = 2.3e-4 of its own): with the
tilt as fitted the pan at 1 costs 10.4 % more (above the bar), the tilt refitted 2.6 % (below):
the profile (the others refitted) decides, and the tilt moves to 2 - 4e-2 x 0.7.
"""

from __future__ import annotations

import numpy as np
import pytest

from lowcostdex.gap import fit as fitmod
from lowcostdex.gap import gates
from lowcostdex.gap.results import bound_flags


def _fitted(pan_sensitivity: float, rng: np.random.Generator, shared: float = 0.0):
    ctx = fitmod.Context(dt=0.002, peak_force=np.ones(2), stall=np.full(2, np.inf),
                         damping=np.zeros(2))
    st = fitmod.Structure.build(("mass_error",), ["pan", "tilt"], ctx)
    lo = st.free[0].lo
    noise = rng.normal(0.0, 1e-3, 1000)
    own = np.resize([1.0, -1.0], 1000)  # the pan's own pull; the tilt's is a constant shift
    noise -= noise.mean() + own * (own @ noise) / 1000  # no cross terms with either

    def fn(points):  # the scales as the replay gets them (held ones too), per joint
        out = []
        for s, x in points:
            pan, tilt = s.to_effects(x)[0].values["scale"]
            out.append(noise + pan_sensitivity * (pan - lo) * own
                       + 1e-2 * (tilt - 2.0 + shared * (pan - lo)))
        return out

    x = np.array([lo, 2.0])  # the pan on its lower search bound
    t = fitmod.Track(st, st.u(x))
    t.r = fn([(st, x)])[0]
    t.cost = 0.5 * float(t.r @ t.r)
    return t, fn, lo


def test_a_bound_the_data_do_not_need_is_held_at_the_null_and_no_longer_flagged():
    for e, shared, moves in ((1e-5, 0.0, True), (1e-3, 0.0, False), (2.3e-4, 4e-2, True)):
        t, fn, lo = _fitted(e, np.random.default_rng(3), shared)
        assert bound_flags(t.structure, t.u, "mass_error")  # on its bound before
        best = {"mass_error": t}
        moved = gates.settle_untold(best, fn, 0.05)
        assert moved == (["mass_error"] if moves else [])
        t = best["mass_error"]
        pan, tilt = t.effects()[0].values["scale"]
        assert pan == (1.0 if moves else lo)
        assert tilt == pytest.approx(2.0 - shared * (pan - lo), abs=1e-4)
        assert bool(bound_flags(t.structure, t.u, "mass_error")) is not moves
        assert ("mass_error", "scale", 0) in t.structure.held if moves else t.structure.n == 2
        r = fn([(t.structure, t.x)])[0]
        assert t.cost == pytest.approx(0.5 * float(r @ r), rel=1e-12)  # its replay's cost


def test_the_refit_decides_where_the_others_as_fitted_do_not():
    """The third case above with no refit (``max_rounds`` 0 leaves the held track as started):
    the bound with the others as fitted is above the bar, so the pan stays on its bound."""
    t, fn, lo = _fitted(2.3e-4, np.random.default_rng(3), 4e-2)
    best = {"mass_error": t}
    assert gates.settle_untold(best, fn, 0.05, max_rounds=0) == []
    assert best["mass_error"] is t
