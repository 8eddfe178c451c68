"""KL-constrained update: constraint satisfaction, dual limits, non-PD handling, step rule
(reference 03, sections 8.5, 8.6, 8.8, 8.10)."""

import numpy as np
import pytest

from lowcostdex.algos.local_models.controller import LinearGaussianController
from lowcostdex.algos.local_models.costs import QuadraticCost
from lowcostdex.algos.local_models.dynamics import LinearGaussianDynamics
from lowcostdex.algos.local_models.lqr import (
    augment_cost,
    expected_cost,
    forward_pass,
    kl_per_step,
    lqr_backward,
)
from lowcostdex.algos.local_models.traj_opt import (
    TrajOptConfig,
    TrajOptError,
    kl_constrained_update,
    solve_for_eta,
    step_mult_update,
)
from lowcostdex.errors import ConfigError

T, DT = 60, 0.05


def _point_mass_problem():
    """Exact linear model of a 2-D point mass, quadratic cost with a final x10, start K=0, Sigma=I."""
    A = np.eye(4)
    A[:2, 2:] = DT * np.eye(2)
    B = np.zeros((4, 2))
    B[2:] = DT * np.eye(2)
    dyn = LinearGaussianDynamics(
        F=np.broadcast_to(np.hstack([A, B]), (T - 1, 4, 6)).copy(),
        f=np.zeros((T - 1, 4)),
        cov=np.broadcast_to(1e-4 * np.eye(4), (T - 1, 4, 4)).copy(),
        x0_mean=np.array([1.0, -1.0, 0.0, 0.0]),
        x0_cov=1e-6 * np.eye(4),
    )
    C = np.zeros((T, 6, 6))
    C[:, :4, :4] = np.diag([1.0, 1.0, 0.1, 0.1])
    C[-1, :4, :4] *= 10.0
    C[:, 4:, 4:] = 0.01 * np.eye(2)
    cost = QuadraticCost(C, np.zeros((T, 6)), np.zeros(T))
    start = LinearGaussianController.from_cov(
        np.zeros((T, 2, 4)), np.zeros((T, 2)), np.broadcast_to(np.eye(2), (T, 2, 2))
    )
    return dyn, cost, start


def _expected(dyn, cost, ctl) -> float:
    return float(expected_cost(cost, *forward_pass(dyn, ctl)).sum())


def _kl(dyn, new, old) -> float:
    return float(kl_per_step(new, old, *forward_pass(dyn, new)).sum())


@pytest.mark.parametrize("epsilon", [0.5, 5.0, 30.0])
def test_kl_constraint_holds_within_ten_percent(epsilon: float) -> None:
    dyn, cost, start = _point_mass_problem()
    res = kl_constrained_update(dyn, cost, start, epsilon, 1.0, TrajOptConfig())
    assert res.converged
    assert abs(res.kl - epsilon) < 0.1 * epsilon
    assert res.kl == pytest.approx(_kl(dyn, res.controller, start))
    assert res.dual_iterations <= 10
    assert _expected(dyn, cost, res.controller) < _expected(dyn, cost, start)


def test_kl_decreases_monotonically_in_eta() -> None:
    dyn, cost, start = _point_mass_problem()
    kls = []
    for eta in np.logspace(-6, 8, 15):
        ctl = lqr_backward(dyn.F, dyn.f, *augment_cost(cost, start, eta))
        kls.append(_kl(dyn, ctl, start))
    assert np.all(np.diff(kls) < 0)
    assert kls[-1] < 1e-6


def test_unreachable_small_epsilon_or_inactive_constraint_are_reported() -> None:
    dyn, cost, start = _point_mass_problem()
    # A huge budget: the constraint is inactive at min_eta, which counts as converged.
    res = kl_constrained_update(dyn, cost, start, 1e9, 1.0, TrajOptConfig())
    assert res.converged and res.kl < 1e9 and res.eta == pytest.approx(1e-8)
    # Too few dual iterations to reach the target: not converged, but the result is feasible.
    res = kl_constrained_update(dyn, cost, start, 1.0, 1e6, TrajOptConfig(max_dual_iterations=2))
    assert not res.converged
    assert res.kl <= 1.0


def test_monotone_improvement_to_lqr_optimum_on_exact_model() -> None:
    dyn, cost, ctl = _point_mass_problem()
    opt = lqr_backward(dyn.F, dyn.f, cost.C, cost.c)
    deterministic = LinearGaussianController.from_cov(
        opt.K, opt.k, np.broadcast_to(1e-12 * np.eye(2), (T, 2, 2))
    )
    best = _expected(dyn, cost, deterministic)
    costs, eta = [_expected(dyn, cost, ctl)], 1.0
    for _ in range(12):
        res = kl_constrained_update(dyn, cost, ctl, 0.2 * T, eta, TrajOptConfig())
        assert res.converged
        ctl, eta = res.controller, res.eta
        costs.append(_expected(dyn, cost, ctl))
    assert np.all(np.diff(costs) <= 0)
    assert costs[-1] <= 1.01 * best
    assert costs[1] > 1.5 * best  # the trust region really limits the first step


def test_indefinite_cost_raises_eta_instead_of_crashing() -> None:
    dyn, cost, start = _point_mass_problem()
    C = cost.C.copy()
    C[10, 4:, 4:] = -50.0 * np.eye(2)  # concave in u at one step
    bad = QuadraticCost(C, cost.c, cost.cc)
    with pytest.raises(Exception, match="positive definite"):
        lqr_backward(dyn.F, dyn.f, bad.C, bad.c)
    ctl, eta_used, retries = solve_for_eta(dyn, bad, start, 1e-3, TrajOptConfig())
    assert retries > 0 and eta_used > 1e-3
    assert np.all(np.linalg.eigvalsh(ctl.cov) > 0)
    res = kl_constrained_update(dyn, bad, start, 2.0, 1e-3, TrajOptConfig())
    assert res.pd_fixes > 0 and abs(res.kl - 2.0) < 0.2


def test_nan_dynamics_raise_a_clear_error() -> None:
    dyn, cost, start = _point_mass_problem()
    F = dyn.F.copy()
    F[3, 0, 0] = np.nan
    nan_dyn = LinearGaussianDynamics(F, dyn.f, dyn.cov, dyn.x0_mean, dyn.x0_cov)
    with pytest.raises(TrajOptError, match="NaNs in dynamics"):
        kl_constrained_update(nan_dyn, cost, start, 1.0, 1.0, TrajOptConfig())


def test_step_rule() -> None:
    cfg = TrajOptConfig(min_step_mult=0.01, max_step_mult=10.0)
    # actual == predicted: the quadratic model says go further; capped at x5.
    assert step_mult_update(1.0, 10.0, 8.0, 8.0, cfg) == pytest.approx(5.0)
    # actual == predicted / 2: keep the step.
    assert step_mult_update(1.0, 10.0, 8.0, 9.0, cfg) == pytest.approx(1.0)
    # actual got worse: shrink, at most to x0.1.
    assert 0.1 <= step_mult_update(1.0, 10.0, 8.0, 12.0, cfg) < 0.5
    assert step_mult_update(1.0, 10.0, 8.0, 1e6, cfg) == pytest.approx(0.1)
    # Overall bounds.
    assert step_mult_update(9.0, 10.0, 8.0, 8.0, cfg) == pytest.approx(10.0)
    assert step_mult_update(0.02, 10.0, 8.0, 1e6, cfg) == pytest.approx(0.01)


def test_config_validation_lists_bounds() -> None:
    with pytest.raises(ConfigError, match="kl_step"):
        TrajOptConfig(kl_step=0.0)
    with pytest.raises(ConfigError, match="min_step_mult"):
        TrajOptConfig(min_step_mult=2.0, max_step_mult=1.0)
    with pytest.raises(ConfigError, match="kl_tolerance"):
        TrajOptConfig(kl_tolerance=1.5)
