"""TVLG dynamics fit and GMM prior: recovery of known linear systems (reference 03, section 8.1)."""

import numpy as np
import pytest

from lowcostdex.algos.local_models.dynamics import (
    DynamicsConfig,
    GMMPrior,
    condition_gaussian,
    final_sensitivity,
    fit_dynamics,
    map_gaussian,
    update_gmm_prior,
)
from lowcostdex.algos.local_models.gmm import fit_gmm, niw_prior, responsibilities
from lowcostdex.algos.local_models.policy_fit import fit_policy
from lowcostdex.errors import ConfigError

DT, T, DX, DU = 0.05, 50, 4, 2
NOISE = 1e-3  # process-noise std


def _point_mass(t_varying: bool) -> tuple[np.ndarray, np.ndarray]:
    """[A_t B_t] (T-1, 4, 6) and offsets c_t (T-1, 4) of a 2-D double integrator."""
    A = np.eye(DX)
    A[:2, 2:] = DT * np.eye(2)
    B = np.zeros((DX, DU))
    B[2:] = DT * np.eye(2)
    AB = np.broadcast_to(np.hstack([A, B]), (T - 1, DX, DX + DU)).copy()
    if t_varying:  # damping and gain that change along the horizon
        s = np.linspace(0.0, 1.0, T - 1)
        AB[:, 2, 2] -= 0.2 * s
        AB[:, 3, 5] *= 1.0 + s
    c = 0.01 * np.sin(np.arange(T - 1))[:, None] * np.array([0.0, 0.0, 1.0, -1.0])
    return AB, c


def _rollouts(AB, c, N: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    X = np.zeros((N, T, DX))
    U = rng.normal(size=(N, T, DU))
    X[:, 0] = rng.normal(scale=0.1, size=(N, DX))
    for t in range(T - 1):
        xu = np.concatenate([X[:, t], U[:, t]], axis=1)
        X[:, t + 1] = xu @ AB[t].T + c[t] + NOISE * rng.normal(size=(N, DX))
    return X, U


def _mean_max_error(F, AB) -> float:
    return float(np.mean(np.max(np.abs(F - AB), axis=(1, 2))))


def test_plain_regression_recovers_time_varying_system_and_improves_with_n() -> None:
    AB, c = _point_mass(t_varying=True)
    rng = np.random.default_rng(0)
    errors = {}
    for N in (10, 20, 100):
        X, U = _rollouts(AB, c, N, rng)
        dyn = fit_dynamics(X, U, DynamicsConfig(use_prior=False))
        errors[N] = _mean_max_error(dyn.F, AB)
        assert errors[N] < 0.05
        np.testing.assert_allclose(dyn.f, c, atol=0.01)
        noise_var = np.diagonal(dyn.cov, axis1=1, axis2=2)
        ratio = np.median(noise_var) / NOISE**2
        if N >= 20:
            assert 0.5 < ratio < 2.0
    assert errors[100] < errors[10] / 3  # ~ 1/sqrt(N)


def test_plain_regression_fails_below_dx_plus_du_plus_one_samples() -> None:
    AB, c = _point_mass(t_varying=False)
    X, U = _rollouts(AB, c, 5, np.random.default_rng(1))
    dyn = fit_dynamics(X, U, DynamicsConfig(use_prior=False))
    assert _mean_max_error(dyn.F, AB) > 0.3  # rank-deficient: the case the prior exists for


def test_gmm_prior_recovers_system_from_five_rollouts() -> None:
    AB, c = _point_mass(t_varying=False)
    rng = np.random.default_rng(2)
    cfg = DynamicsConfig()
    prior = GMMPrior.empty(T, DX, DU)
    Xp, Up = _rollouts(AB, c, 20, rng)  # earlier iterations' data
    prior = update_gmm_prior(prior, Xp, Up, cfg, rng)
    X, U = _rollouts(AB, c, 5, rng)
    prior = update_gmm_prior(prior, X, U, cfg, rng)
    assert prior.X.shape[0] == cfg.max_trajectories
    dyn = fit_dynamics(X, U, cfg, prior.gmm)
    assert _mean_max_error(dyn.F, AB) < 0.05
    np.testing.assert_allclose(dyn.f, c, atol=0.05)


def test_zero_prior_strength_is_plain_regression_and_large_n_makes_prior_irrelevant() -> None:
    AB, c = _point_mass(t_varying=False)
    rng = np.random.default_rng(3)
    X, U = _rollouts(AB, c, 30, rng)
    cfg = DynamicsConfig(max_trajectories=30)
    gmm = update_gmm_prior(GMMPrior.empty(T, DX, DU), X, U, cfg, rng).gmm
    plain = fit_dynamics(X[:10], U[:10], DynamicsConfig(use_prior=False))
    zero = fit_dynamics(X[:10], U[:10], DynamicsConfig(prior_strength=0.0), gmm)
    np.testing.assert_allclose(zero.F, plain.F, atol=1e-10)
    np.testing.assert_allclose(zero.cov, plain.cov, atol=1e-14)
    Xb, Ub = _rollouts(AB, c, 3000, rng)
    with_prior = fit_dynamics(Xb, Ub, DynamicsConfig(), gmm)
    without = fit_dynamics(Xb, Ub, DynamicsConfig(use_prior=False))
    assert np.max(np.abs(with_prior.F - without.F)) < 1e-3


def test_map_gaussian_and_conditioning_formulas() -> None:
    rng = np.random.default_rng(4)
    pts = rng.normal(size=(7, 3))
    mu, sigma = map_gaussian(pts, None)
    np.testing.assert_allclose(sigma, np.cov(pts.T, bias=True), atol=1e-14)
    # Conditioning a known joint Gaussian: out = 2 in + 1 + noise(var 0.5).
    joint_cov = np.array([[1.0, 2.0], [2.0, 4.5]])
    F, f, cov = condition_gaussian(np.array([0.0, 1.0]), joint_cov, 1, 0.0)
    np.testing.assert_allclose(F, [[2.0]])
    np.testing.assert_allclose(f, [1.0])
    np.testing.assert_allclose(cov, [[0.5]])


def test_gmm_finds_separated_clusters_and_prior_follows_query_points() -> None:
    rng = np.random.default_rng(5)
    a = rng.normal(loc=[-5.0, 0.0], scale=0.5, size=(300, 2))
    b = rng.normal(loc=[5.0, 1.0], scale=1.0, size=(700, 2))
    data = np.concatenate([a, b])
    gmm = fit_gmm(data, 2, np.random.default_rng(0))
    order = np.argsort(gmm.means[:, 0])
    np.testing.assert_allclose(gmm.weights[order], [0.3, 0.7], atol=0.01)
    np.testing.assert_allclose(gmm.means[order], [[-5.0, 0.0], [5.0, 1.0]], atol=0.15)
    np.testing.assert_allclose(gmm.covs[order[1]], np.eye(2), atol=0.15)
    resp, _ = responsibilities(gmm, a[:10])
    assert np.all(resp[:, order[0]] > 0.99)
    prior = niw_prior(gmm, a[:10], strength=2.0)
    np.testing.assert_allclose(prior.mu0, gmm.means[order[0]], atol=1e-6)
    np.testing.assert_allclose(prior.Phi, 2.0 * gmm.covs[order[0]], atol=1e-4)
    assert prior.m == 2.0
    # Same seed, same fit.
    again = fit_gmm(data, 2, np.random.default_rng(0))
    np.testing.assert_array_equal(again.means, gmm.means)


def test_fit_rejects_nan_and_bad_config() -> None:
    X = np.zeros((3, 4, 2))
    X[1, 2, 0] = np.nan
    with pytest.raises(ConfigError, match="NaN"):
        fit_dynamics(X, np.zeros((3, 4, 1)), DynamicsConfig(use_prior=False))
    with pytest.raises(ConfigError):
        DynamicsConfig(prior_strength=-1.0)


def test_policy_fit_recovers_a_known_linear_gaussian_controller() -> None:
    """u_t = K_t x_t + k_t + noise observed on varied states: K_t, k_t and the noise come back."""
    rng = np.random.default_rng(6)
    T, N = 10, 200
    K = rng.normal(size=(T, DU, DX))
    k = rng.normal(size=(T, DU))
    X = rng.normal(size=(N, T, DX))
    U = np.einsum("tij,ntj->nti", K, X) + k + 0.01 * rng.normal(size=(N, T, DU))
    ctl = fit_policy(X, U, DynamicsConfig(use_prior=False), rng)
    np.testing.assert_allclose(ctl.K, K, atol=0.01)
    np.testing.assert_allclose(ctl.k, k, atol=0.01)
    np.testing.assert_allclose(np.diagonal(ctl.cov, axis1=1, axis2=2), 1e-4, rtol=0.5)
    with_prior = fit_policy(X[:5], U[:5], DynamicsConfig(), rng)  # N < dX + 1: still defined
    assert np.all(np.isfinite(with_prior.K))


def test_final_sensitivity_equals_finite_differences_of_the_linear_rollout() -> None:
    AB, c = _point_mass(t_varying=True)
    rng = np.random.default_rng(5)
    U = rng.normal(size=(T, DU))

    def final(U: np.ndarray) -> np.ndarray:
        x = np.zeros(DX)
        for t in range(T - 1):
            x = AB[t] @ np.concatenate([x, U[t]]) + c[t]
        return x

    S = final_sensitivity(AB, 3)
    assert S.shape == (T, DU) and np.all(S[-1] == 0)
    fd = np.zeros((T, DU))
    for t in range(T):
        for j in range(DU):
            e = np.zeros((T, DU))
            e[t, j] = 1e-3
            fd[t, j] = (final(U + e)[3] - final(U - e)[3]) / 2e-3
    np.testing.assert_allclose(S, fd, atol=1e-9)
    assert np.abs(S[:-1, 1]).min() > 0.01  # velocity 3 is driven by action 1 at every step
