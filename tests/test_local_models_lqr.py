"""LQR backward pass, forward-pass moments, expected cost and KL (reference 03, sections 8.2-8.4)."""

import numpy as np
import pytest
import scipy.linalg

from lowcostdex.algos.local_models.controller import (
    LinearGaussianController,
    exploration_noise,
    pd_controller,
)
from lowcostdex.algos.local_models.costs import QuadraticCost
from lowcostdex.algos.local_models.dynamics import LinearGaussianDynamics
from lowcostdex.algos.local_models.lqr import (
    augment_cost,
    expected_cost,
    forward_pass,
    kl_per_step,
    lqr_backward,
)

DX, DU = 3, 2


def _double_integrator(dt: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    A = np.eye(4)
    A[:2, 2:] = dt * np.eye(2)
    B = np.zeros((4, 2))
    B[2:] = dt * np.eye(2)
    return A, B


def _random_psd(rng, n: int, floor: float) -> np.ndarray:
    W = rng.normal(size=(n, n))
    return W @ W.T / n + floor * np.eye(n)


def _random_problem(seed: int, T: int = 8):
    """Random LTV dynamics, a PD quadratic cost and two random controllers."""
    rng = np.random.default_rng(seed)
    F = np.concatenate(
        [
            np.eye(DX) + 0.1 * rng.normal(size=(T - 1, DX, DX)),
            0.3 * rng.normal(size=(T - 1, DX, DU)),
        ],
        axis=2,
    )
    dyn = LinearGaussianDynamics(
        F=F,
        f=0.1 * rng.normal(size=(T - 1, DX)),
        cov=np.stack([_random_psd(rng, DX, 0.01) * 0.05 for _ in range(T - 1)]),
        x0_mean=rng.normal(size=DX),
        x0_cov=_random_psd(rng, DX, 0.01) * 0.1,
    )
    C = np.stack([_random_psd(rng, DX + DU, 0.1) for _ in range(T)])
    cost = QuadraticCost(C, rng.normal(size=(T, DX + DU)), rng.normal(size=T))

    def controller():
        return LinearGaussianController.from_cov(
            0.3 * rng.normal(size=(T, DU, DX)),
            rng.normal(size=(T, DU)),
            np.stack([_random_psd(rng, DU, 0.05) * 0.5 for _ in range(T)]),
        )

    return dyn, cost, controller(), controller()


def _sample(dyn, ctl, M: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """M Monte Carlo rollouts: X (M, T, dX), U (M, T, dU)."""
    T = ctl.T
    X = np.zeros((M, T, DX))
    U = np.zeros((M, T, DU))
    x = rng.multivariate_normal(dyn.x0_mean, dyn.x0_cov, size=M)
    for t in range(T):
        u = x @ ctl.K[t].T + ctl.k[t] + rng.normal(size=(M, DU)) @ ctl.chol[t].T
        X[:, t], U[:, t] = x, u
        if t < T - 1:
            xu = np.concatenate([x, u], axis=1)
            x = (
                xu @ dyn.F[t].T
                + dyn.f[t]
                + rng.multivariate_normal(np.zeros(DX), dyn.cov[t], size=M)
            )
    return X, U


def test_long_horizon_lqr_matches_discrete_riccati() -> None:
    A, B = _double_integrator()
    Q, R = np.diag([1.0, 1.0, 0.1, 0.1]), 0.01 * np.eye(2)
    T = 400
    F = np.broadcast_to(np.hstack([A, B]), (T - 1, 4, 6))
    C = np.zeros((T, 6, 6))
    C[:, :4, :4], C[:, 4:, 4:] = Q, R
    ctl = lqr_backward(F, np.zeros((T - 1, 4)), C, np.zeros((T, 6)))
    P = scipy.linalg.solve_discrete_are(A, B, Q, R)
    K_dare = -np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
    np.testing.assert_allclose(ctl.K[0], K_dare, atol=1e-8)
    np.testing.assert_allclose(ctl.cov[0], np.linalg.inv(R + B.T @ P @ B), atol=1e-8)
    np.testing.assert_allclose(ctl.k, 0.0, atol=1e-12)


def test_short_horizon_lqr_equals_brute_force_quadratic_program() -> None:
    dyn, cost, _, _ = _random_problem(0, T=5)
    ctl = lqr_backward(dyn.F, dyn.f, cost.C, cost.c)
    T, x0 = 5, dyn.x0_mean

    def trajectory(u_flat):  # deterministic y_t = [x_t; u_t], (T, DX+DU)
        u = u_flat.reshape(T, DU)
        y, x = [], x0
        for t in range(T):
            y.append(np.concatenate([x, u[t]]))
            if t < T - 1:
                x = dyn.F[t] @ y[-1] + dyn.f[t]
        return np.array(y)

    y0 = trajectory(np.zeros(T * DU))
    S = np.stack(  # y is affine in u: y = y0 + S u
        [(trajectory(e) - y0).ravel() for e in np.eye(T * DU)], axis=1
    )
    Cbig = scipy.linalg.block_diag(*cost.C)
    u_star = -np.linalg.solve(S.T @ Cbig @ S, S.T @ (Cbig @ y0.ravel() + cost.c.ravel()))
    # Roll the LQR feedback law forward from x0 without noise.
    x, u_lqr = x0, []
    for t in range(T):
        u_lqr.append(ctl.act(t, x))
        if t < T - 1:
            x = dyn.F[t] @ np.concatenate([x, u_lqr[-1]]) + dyn.f[t]
    np.testing.assert_allclose(np.ravel(u_lqr), u_star, atol=1e-8)


def test_forward_pass_moments_and_expected_cost_match_monte_carlo() -> None:
    dyn, cost, ctl, _ = _random_problem(1)
    mu, sigma = forward_pass(dyn, ctl)
    M = 100_000
    X, U = _sample(dyn, ctl, M, np.random.default_rng(2))
    Y = np.concatenate([X, U], axis=2)  # (M, T, dXU)
    se_mean = np.sqrt(np.diagonal(sigma, axis1=1, axis2=2) / M)
    assert np.all(np.abs(Y.mean(axis=0) - mu) < 4 * se_mean)
    for t in (0, 4, 7):
        S = np.cov(Y[:, t].T)
        d = np.sqrt(np.diag(sigma[t]))
        se_cov = np.sqrt((np.outer(d, d) ** 2 + sigma[t] ** 2) / M)
        assert np.all(np.abs(S - sigma[t]) < 4 * se_cov + 1e-12)
    mc = (
        0.5 * np.einsum("mti,tij,mtj->mt", Y, cost.C, Y)
        + np.einsum("mti,ti->mt", Y, cost.c)
        + cost.cc
    ).sum(axis=1)
    laplace = expected_cost(cost, mu, sigma).sum()
    assert abs(mc.mean() - laplace) < 4 * mc.std() / np.sqrt(M)


def test_kl_matches_monte_carlo_and_vanishes_for_identical_controllers() -> None:
    dyn, _, new, old = _random_problem(3)
    mu, sigma = forward_pass(dyn, new)
    kl = kl_per_step(new, old, mu, sigma)
    assert np.all(kl >= 0)
    M = 100_000
    X, U = _sample(dyn, new, M, np.random.default_rng(4))

    def logpdf(ctl):  # (M,) summed over t
        total = np.zeros(M)
        for t in range(ctl.T):
            r = U[:, t] - X[:, t] @ ctl.K[t].T - ctl.k[t]
            z = np.linalg.solve(ctl.chol[t], r.T)
            total += -0.5 * np.sum(z**2, axis=0) - np.sum(np.log(np.diag(ctl.chol[t])))
        return total

    log_ratio = logpdf(new) - logpdf(old)
    assert abs(log_ratio.mean() - kl.sum()) < 4 * log_ratio.std() / np.sqrt(M)
    assert np.max(kl_per_step(new, new, mu, sigma)) < 1e-12


def test_eta_limits_recover_old_controller_and_plain_lqr() -> None:
    dyn, cost, old, _ = _random_problem(5)
    C, c = augment_cost(cost, old, 1e16)
    same = lqr_backward(dyn.F, dyn.f, C, c)
    np.testing.assert_allclose(same.K, old.K, atol=1e-6)
    np.testing.assert_allclose(same.k, old.k, atol=1e-6)
    np.testing.assert_allclose(same.cov, old.cov, atol=1e-6)
    mu, sigma = forward_pass(dyn, same)
    assert kl_per_step(same, old, mu, sigma).sum() < 1e-6
    eta = 1e-8
    C, c = augment_cost(cost, old, eta)
    greedy = lqr_backward(dyn.F, dyn.f, C, c)
    plain = lqr_backward(dyn.F, dyn.f, cost.C, cost.c)
    np.testing.assert_allclose(greedy.K, plain.K, atol=1e-5)
    np.testing.assert_allclose(greedy.k, plain.k, atol=1e-5)
    np.testing.assert_allclose(greedy.cov / eta, plain.cov, rtol=1e-4)


def test_pd_controller_holds_start_pose_and_noise_is_unit_variance() -> None:
    x0 = np.array([0.1, -0.2, 0.3, 0.0, 0.0, 0.0])
    ctl = pd_controller(x0, np.array([0.5, 0.4, 0.0]), 4, [0, 1, 2], [3, 4, 5], 2.0, 0.1, 0.2)
    np.testing.assert_allclose(ctl.act(0, x0), [0.5, 0.4, 0.0])
    x = x0.copy()
    x[1] += 0.1
    x[4] = 1.0
    np.testing.assert_allclose(ctl.act(3, x) - ctl.act(3, x0), [0.0, -0.2 - 0.1, 0.0])
    np.testing.assert_allclose(ctl.cov[2], 0.2 * np.eye(3))
    rng = np.random.default_rng(0)
    smooth = exploration_noise(rng, 2000, 2, smooth_sigma=2.0)
    white = exploration_noise(rng, 2000, 2)
    np.testing.assert_allclose(smooth.std(axis=0), 1.0, atol=1e-9)
    lag1 = [np.corrcoef(n[:-1, 0], n[1:, 0])[0, 1] for n in (white, smooth)]
    assert abs(lag1[0]) < 0.1 and lag1[1] > 0.8


@pytest.mark.parametrize("seed", [0, 1])
def test_controller_round_trips_through_arrays(seed: int) -> None:
    _, _, ctl, _ = _random_problem(seed)
    back = LinearGaussianController.from_arrays(ctl.to_arrays())
    np.testing.assert_array_equal(back.chol, ctl.chol)
    np.testing.assert_allclose(
        back.inv_cov @ back.cov, np.broadcast_to(np.eye(DU), ctl.cov.shape), atol=1e-10
    )
