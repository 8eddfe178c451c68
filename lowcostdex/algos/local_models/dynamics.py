"""Time-varying linear-Gaussian dynamics fitted from a few rollouts, with a GMM prior.

For every transition t the N rollouts give points y_i = [x_t; u_t; x_t+1]. A joint Gaussian over y
is estimated (maximum a posteriori under a normal-inverse-Wishart prior from a GMM fitted to all
recent transitions, see :mod:`.gmm`) and conditioned on [x_t; u_t]:

    x_t+1 ~ N(F_t [x_t; u_t] + f_t, Sigma_t)

Shapes: X (N, T, dX) states, U (N, T, dU) actions; the fit has T-1 transitions.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos.local_models.gmm import GaussianMixture, NIWPrior, fit_gmm, niw_prior
from lowcostdex.errors import ConfigError, check_fields, keyword_hints

Array = NDArray[np.float64]


@keyword_hints
@dataclass(frozen=True)
class DynamicsConfig:
    """How the per-step dynamics and the GMM prior are fitted.

    Attributes:
      use_prior: fit with the GMM prior (needed when N < dX + dU + 1).
      prior_strength: pseudo-sample count of the prior (1.0 ~ one extra rollout).
      regularization: added to the [x, u] block of every joint covariance before conditioning.
      max_clusters: upper bound on GMM clusters.
      min_samples_per_cluster: K = clip(points // this, 2, max_clusters).
      max_trajectories: rollouts kept in the GMM's data window.
      em_iterations: maximum EM iterations per refit.
      initial_state_var: floor of the fitted initial-state variance (state units squared).
    """

    use_prior: bool = True
    prior_strength: float = 1.0
    regularization: float = 1e-6
    max_clusters: int = 20
    min_samples_per_cluster: int = 40
    max_trajectories: int = 20
    em_iterations: int = 100
    initial_state_var: float = 1e-6

    def __post_init__(self) -> None:
        check_fields(self)  # types, NaN and inf first (a NaN passes every comparison)
        if self.prior_strength < 0:
            raise ConfigError(f"prior_strength={self.prior_strength} must be >= 0")
        if self.regularization < 0 or self.initial_state_var <= 0:
            raise ConfigError("regularization must be >= 0 and initial_state_var > 0")
        if self.max_clusters < 1 or self.min_samples_per_cluster < 1:
            raise ConfigError("max_clusters and min_samples_per_cluster must be >= 1")
        if self.max_trajectories < 1 or self.em_iterations < 1:
            raise ConfigError("max_trajectories and em_iterations must be >= 1")


@dataclass(frozen=True, eq=False)
class LinearGaussianDynamics:
    """x_t+1 ~ N(F_t [x_t; u_t] + f_t, cov_t), x_0 ~ N(x0_mean, x0_cov).

    Attributes:
      F: (T-1, dX, dX+dU) transition matrices.
      f: (T-1, dX) offsets.
      cov: (T-1, dX, dX) process-noise covariances.
      x0_mean: (dX,) initial-state mean.
      x0_cov: (dX, dX) initial-state covariance.
    """

    F: Array
    f: Array
    cov: Array
    x0_mean: Array
    x0_cov: Array

    def to_arrays(self) -> dict[str, Array]:
        return {
            "F": self.F,
            "f": self.f,
            "cov": self.cov,
            "x0_mean": self.x0_mean,
            "x0_cov": self.x0_cov,
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, Array]) -> LinearGaussianDynamics:
        return cls(arrays["F"], arrays["f"], arrays["cov"], arrays["x0_mean"], arrays["x0_cov"])


def check_rollouts(X: object, U: object, min_steps: int = 1) -> tuple[Array, Array]:
    """X (N, T, dX) states and U (N, T, dU) actions of N >= 1 rollouts of T >= ``min_steps``
    steps as float arrays; ConfigError naming the array and the shape it needs, or its first
    NaN/inf (before: numpy's concatenate error, or NaN dynamics from 0 rollouts)."""
    arrays = []
    for name, v, d in (("X", X, "dX states"), ("U", U, "dU actions")):
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            raise ConfigError(f"{name} is not an (N, T, {d[:2]}) array of numbers: "
                              f"{type(v).__name__}") from None
        if a.ndim != 3:
            raise ConfigError(f"{name} of shape {a.shape} must be (N, T, {d[:2]}): N rollouts of "
                              f"T steps of {d} (one rollout: {name}[None])")
        arrays.append(a)
    X, U = arrays
    if X.shape[:2] != U.shape[:2] or X.shape[0] < 1 or X.shape[1] < min_steps:
        raise ConfigError(f"X {X.shape} and U {U.shape} must be (N, T, dX) and (N, T, dU) with "
                          f"the same N >= 1 rollouts and T >= {min_steps} steps")
    for name, a in (("X", X), ("U", U)):
        bad = ~np.isfinite(a)
        if bad.any():
            n, t, i = (int(j) for j in np.argwhere(bad)[0])
            raise ConfigError(f"rollout data contains NaN or inf: {name}[{n}, {t}, {i}] = "
                              f"{a[n, t, i]}; cannot fit dynamics")
    return X, U


def transition_points(X: Array, U: Array) -> Array:
    """Stack rollouts into transitions y = [x_t, u_t, x_t+1]: (N, T-1, 2 dX + dU)."""
    return np.concatenate([X[:, :-1], U[:, :-1], X[:, 1:]], axis=2)


def map_gaussian(points: Array, prior: NIWPrior | None) -> tuple[Array, Array]:
    """Mean (D,) and covariance (D, D) of ``points`` (N, D), MAP under ``prior`` if given.

    ``Sigma = [N S + Phi + N m / (N + m) (mu - mu0)(mu - mu0)'] / (N + n0)`` with S the empirical
    (1/N) covariance. The mean is the empirical mean: the prior shrinks only the covariance.
    """
    N = points.shape[0]
    mu = points.mean(axis=0)
    diff = points - mu
    sigma = diff.T @ diff / N
    if prior is not None:
        dm = mu - prior.mu0
        sigma = (N * sigma + prior.Phi + (N * prior.m / (N + prior.m)) * np.outer(dm, dm)) / (
            N + prior.n0
        )
    return mu, 0.5 * (sigma + sigma.T)


def condition_gaussian(
    mu: Array, sigma: Array, d_in: int, regularization: float
) -> tuple[Array, Array, Array]:
    """Condition a joint Gaussian over [in; out] on its first ``d_in`` coordinates.

    Returns F (d_out, d_in), f (d_out,), cov (d_out, d_out) with out | in ~ N(F in + f, cov).
    ``regularization`` is added to the diagonal of the input block first.
    """
    s_ii = sigma[:d_in, :d_in] + regularization * np.eye(d_in)
    s_oi = sigma[d_in:, :d_in]
    F = np.linalg.solve(s_ii, s_oi.T).T
    f = mu[d_in:] - F @ mu[:d_in]
    cov = sigma[d_in:, d_in:] - F @ s_ii @ F.T
    return F, f, 0.5 * (cov + cov.T)


def fit_dynamics(
    X: Array, U: Array, cfg: DynamicsConfig, gmm: GaussianMixture | None = None
) -> LinearGaussianDynamics:
    """Fit TVLG dynamics to N rollouts X (N, T, dX), U (N, T, dU).

    Uses the GMM prior at each step when ``gmm`` is given and ``cfg.use_prior``; plain Gaussian
    conditioning (least squares) otherwise.

    Raises:
      ConfigError: on arrays of other shapes, fewer than 2 steps, NaN/inf data, or data that
        does not vary at some step with ``regularization`` 0 (a singular fit).
    """
    if not isinstance(cfg, DynamicsConfig):
        raise ConfigError(f"fit_dynamics(X, U, cfg): cfg={cfg!r:.60} must be a DynamicsConfig")
    X, U = check_rollouts(X, U, min_steps=2)
    N, T, dX = X.shape
    dXU = dX + U.shape[2]
    Y = transition_points(X, U)
    F = np.zeros((T - 1, dX, dXU))
    f = np.zeros((T - 1, dX))
    cov = np.zeros((T - 1, dX, dX))
    use_prior = cfg.use_prior and gmm is not None
    for t in range(T - 1):
        prior = niw_prior(gmm, Y[:, t], cfg.prior_strength) if use_prior else None
        mu, sigma = map_gaussian(Y[:, t], prior)
        try:
            F[t], f[t], cov[t] = condition_gaussian(mu, sigma, dXU, cfg.regularization)
        except np.linalg.LinAlgError:
            raise ConfigError(f"fit_dynamics: the {N} rollouts' [x, u] at step {t} span fewer "
                              f"than their {dXU} dimensions (a singular covariance with "
                              "regularization 0): give DynamicsConfig(regularization=1e-6), more "
                              "rollouts or more exploration noise") from None
    x0_mean, x0_cov = fit_initial_state(X[:, 0], cfg.initial_state_var)
    return LinearGaussianDynamics(F, f, cov, x0_mean, x0_cov)


def fit_initial_state(x0: Array, var_floor: float) -> tuple[Array, Array]:
    """Mean (dX,) and diagonal covariance (dX, dX) of initial states x0 (N, dX), floored."""
    return x0.mean(axis=0), np.diag(np.maximum(x0.var(axis=0), var_floor))


@dataclass(frozen=True, eq=False)
class GMMPrior:
    """The data window (last ``max_trajectories`` rollouts) and the GMM fitted on it.

    Attributes:
      X: (M, T, dX) buffered states; U: (M, T, dU) buffered actions.
      gmm: mixture over their transitions, or None before the first update.
    """

    X: Array
    U: Array
    gmm: GaussianMixture | None

    @classmethod
    def empty(cls, T: int, dX: int, dU: int) -> GMMPrior:
        return cls(np.zeros((0, T, dX)), np.zeros((0, T, dU)), None)


def n_clusters_for(n_points: int, cfg: DynamicsConfig) -> int:
    """K = max(2, min(max_clusters, n_points // min_samples_per_cluster)), at most n_points."""
    k = max(2, min(cfg.max_clusters, n_points // cfg.min_samples_per_cluster))
    return min(k, n_points)


def update_gmm_prior(
    prior: GMMPrior, X: Array, U: Array, cfg: DynamicsConfig, rng: np.random.Generator
) -> GMMPrior:
    """Append rollouts X (N, T, dX), U (N, T, dU) to the window and refit the GMM (warm start)."""
    Xb = np.concatenate([prior.X, X])[-cfg.max_trajectories :]
    Ub = np.concatenate([prior.U, U])[-cfg.max_trajectories :]
    points = transition_points(Xb, Ub).reshape(-1, 2 * X.shape[2] + U.shape[2])
    k = n_clusters_for(points.shape[0], cfg)
    gmm = fit_gmm(
        points,
        k,
        rng,
        init=prior.gmm,
        max_iter=cfg.em_iterations,
        reg=max(cfg.regularization, 1e-12),
    )
    return GMMPrior(Xb, Ub, gmm)


def final_sensitivity(F: Array, index: int) -> Array:
    """Open-loop sensitivity d x_T[index] / d u_t of the final state to every action.

    Args:
      F: (T-1, dX, dX+dU) transition matrices of x_t+1 = F_t [x_t; u_t] + f_t.
      index: state coordinate of interest.

    Returns:
      (T, dU); row t is ``e' A_T-2 ... A_t+1 B_t`` with ``A_t = F_t[:, :dX]``, ``B_t =
      F_t[:, dX:]`` (the last row, whose action is not executed, is 0).
    """
    dX = F.shape[1]
    out = np.zeros((F.shape[0] + 1, F.shape[2] - dX))
    v = np.zeros(dX)
    v[index] = 1.0
    for t in range(F.shape[0] - 1, -1, -1):
        out[t] = v @ F[t][:, dX:]
        v = v @ F[t][:, :dX]
    return out
