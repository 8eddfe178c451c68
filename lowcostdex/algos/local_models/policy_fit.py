"""Fit a time-varying linear-Gaussian controller to state-action samples of another policy.

The same estimator as the dynamics fit (:mod:`.dynamics`), applied to y = [x_t; u_t]: per time
step, a Gaussian over the N samples, maximum a posteriori under a normal-inverse-Wishart prior
from a GMM over all (x, u) pairs, conditioned on x_t:

    u_t | x_t ~ N(K_t x_t + k_t, Sigma_t)

Uses: initialise the local-model optimiser from a closed-loop teacher (its feedback is kept, so
the controller copes with start states that differ between resets), and linearise a neural
policy for guided policy search.

Shapes: X (N, T, dX) states, U (N, T, dU) actions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos.local_models.controller import LinearGaussianController
from lowcostdex.algos.local_models.dynamics import (
    DynamicsConfig,
    condition_gaussian,
    map_gaussian,
    n_clusters_for,
)
from lowcostdex.algos.local_models.gmm import fit_gmm, niw_prior
from lowcostdex.errors import ConfigError

Array = NDArray[np.float64]


def fit_policy(
    X: Array,
    U: Array,
    cfg: DynamicsConfig,
    rng: np.random.Generator,
    min_var: float = 1e-6,
) -> LinearGaussianController:
    """Linear-Gaussian controller (T steps) fitted to N samples per step.

    Args:
      X: (N, T, dX) states; U: (N, T, dU) actions taken in them.
      cfg: prior and regularisation settings (``use_prior``, ``prior_strength``,
        ``regularization``, ``max_clusters``, ``min_samples_per_cluster``).
      rng: generator of the GMM's initial assignment.
      min_var: added to every action variance (an exploration floor), action units squared.

    Raises:
      ConfigError: on NaN/inf samples or min_var <= 0.
    """
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(U))):
        raise ConfigError("policy samples contain NaN or inf")
    if min_var <= 0:
        raise ConfigError(f"min_var={min_var} must be > 0")
    N, T, dX = X.shape
    dU = U.shape[2]
    Y = np.concatenate([X, U], axis=2)  # (N, T, dX+dU)
    gmm = None
    if cfg.use_prior:
        points = Y.reshape(-1, dX + dU)
        k = n_clusters_for(points.shape[0], cfg)
        gmm = fit_gmm(
            points, k, rng, max_iter=cfg.em_iterations, reg=max(cfg.regularization, 1e-12)
        )
    K = np.zeros((T, dU, dX))
    k_ff = np.zeros((T, dU))
    cov = np.zeros((T, dU, dU))
    for t in range(T):
        prior = niw_prior(gmm, Y[:, t], cfg.prior_strength) if gmm is not None else None
        mu, sigma = map_gaussian(Y[:, t], prior)
        K[t], k_ff[t], cov[t] = condition_gaussian(mu, sigma, dX, cfg.regularization)
        cov[t] += min_var * np.eye(dU)
    return LinearGaussianController.from_cov(K, k_ff, cov)
