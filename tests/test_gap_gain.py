"""The gain report's numbers computed by hand from per-episode error sums (issue 19: the
'reducible explained' fraction could be multiplied instead of divided with every test green)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lowcostdex.gap.gain import gain_with_ci


def test_gain_numbers_by_hand():
    # two held-out episodes of 100 samples each
    n = np.array([100, 100])
    sse_b = np.array([0.04, 0.06])    # baseline MSE 0.10 / 200 = 5e-4 -> RMSE 0.022360...
    sse_e = np.array([0.01, 0.01])    # extended MSE 0.02 / 200 = 1e-4 -> RMSE 0.01
    sae_b = np.array([2.0, 2.4])      # MAE 4.4 / 200 = 0.022
    sae_e = np.array([1.0, 1.0])      # MAE 0.01
    floor_mse = 5e-5
    g = gain_with_ci(sse_b, sse_e, n, sae_b, sae_e, floor_mse, np.random.default_rng(0), 200)
    rb, re = math.sqrt(5e-4), 0.01
    assert g.baseline_rmse == pytest.approx(rb) and g.extended_rmse == pytest.approx(re)
    assert g.baseline_mae == pytest.approx(0.022) and g.extended_mae == pytest.approx(0.01)
    assert g.absolute == pytest.approx(rb - re)
    assert g.relative == pytest.approx((rb - re) / rb)
    # (MSE_b - MSE_e) / (MSE_b - floor) = (5e-4 - 1e-4) / (5e-4 - 5e-5) = 4 / 4.5
    assert g.reducible_explained == pytest.approx(4 / 4.5)
    assert g.noise_floor == pytest.approx(math.sqrt(5e-5))
    assert g.episodes == 2
    lo, hi = g.ci95
    assert lo <= g.absolute <= hi


def test_nothing_reducible_gives_no_fraction():
    n = np.array([50, 50])
    sse = np.array([0.01, 0.01])      # MSE 0.02 / 100 = 2e-4, floor 1.95e-4: 2.5 % reducible
    g = gain_with_ci(sse, sse * 0.99, n, sse, sse, 1.95e-4, np.random.default_rng(0), 100)
    assert g.reducible_explained is None
