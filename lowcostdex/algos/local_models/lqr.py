"""Maximum-entropy LQR on time-varying linear-Gaussian dynamics, with a KL term to an old controller.

Backward pass: with ``Q_t = C_t + F_t' V_t+1 F_t`` and ``q_t = c_t + F_t'(v_t+1 + V_t+1 f_t)``,
``K_t = -Q_uu^-1 Q_ux``, ``k_t = -Q_uu^-1 q_u`` and the maximum-entropy covariance
``Sigma_t = Q_uu^-1``; the value is ``V_t = Q_xx + Q_xu K_t``, ``v_t = q_x + Q_xu k_t``.

KL trust region: minimising ``E[l]/eta - log p_old(u|x) - H(p)`` is the same backward pass on the
augmented cost of :func:`augment_cost`. Forward pass: Gaussian moments of [x_t; u_t] under the
controller and the fitted dynamics (:func:`forward_pass`), from which the expected cost
(:func:`expected_cost`) and the KL to the old controller (:func:`kl_per_step`) follow exactly.

Shapes: T steps, y = [x; u] of size dX + dU; dynamics have T-1 transitions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from lowcostdex.algos.local_models.controller import LinearGaussianController
from lowcostdex.algos.local_models.costs import QuadraticCost
from lowcostdex.algos.local_models.dynamics import LinearGaussianDynamics
from lowcostdex.errors import LowcostdexError

Array = NDArray[np.float64]


class NotPositiveDefiniteError(LowcostdexError, ArithmeticError):
    """Q_uu is not positive definite at step ``t`` (non-convex cost or ill-fitted model)."""

    def __init__(self, t: int) -> None:
        super().__init__(f"Q_uu is not positive definite at time step {t}")
        self.t = t


def _sym(a: Array) -> Array:
    return 0.5 * (a + np.swapaxes(a, -1, -2))


def augment_cost(
    cost: QuadraticCost, prev: LinearGaussianController, eta: float
) -> tuple[Array, Array]:
    """Quadratic coefficients of ``l/eta - log p_prev(u|x)`` (constants dropped).

    With P = Sigma_prev^-1: ``C~ = C/eta + [[K'PK, -K'P], [-PK, P]]`` and
    ``c~ = c/eta + [K'Pk; -Pk]``.

    Returns:
      (C~ (T, dXU, dXU), c~ (T, dXU)).
    """
    K, k, P = prev.K, prev.k, prev.inv_cov
    PK = P @ K  # (T, dU, dX)
    Kt = np.swapaxes(K, 1, 2)
    kl_C = np.block([[Kt @ PK, -np.swapaxes(PK, 1, 2)], [-PK, P]])
    Pk = np.einsum("tij,tj->ti", P, k)
    kl_c = np.concatenate([np.einsum("tji,tj->ti", K, Pk), -Pk], axis=1)
    return cost.C / eta + kl_C, cost.c / eta + kl_c


def lqr_backward(F: Array, f: Array, C: Array, c: Array) -> LinearGaussianController:
    """Time-varying LQR on x_t+1 = F_t [x_t; u_t] + f_t with cost 1/2 y'C_t y + c_t'y.

    Args:
      F: (T-1, dX, dXU) dynamics; f: (T-1, dX) offsets.
      C: (T, dXU, dXU) cost Hessians; c: (T, dXU) linear cost terms.

    Returns:
      The maximum-entropy controller with K, k and cov = Q_uu^-1 per step.

    Raises:
      NotPositiveDefiniteError: if some Q_uu is not positive definite.
    """
    T, dXU, _ = C.shape
    dX = F.shape[1]
    dU = dXU - dX
    K = np.zeros((T, dU, dX))
    k = np.zeros((T, dU))
    cov = np.zeros((T, dU, dU))
    V = np.zeros((dX, dX))
    v = np.zeros(dX)
    for t in range(T - 1, -1, -1):
        Q = C[t].copy()
        q = c[t].copy()
        if t < T - 1:
            Q += F[t].T @ V @ F[t]
            q += F[t].T @ (v + V @ f[t])
        Q = _sym(Q)
        Quu, Qux = Q[dX:, dX:], Q[dX:, :dX]
        try:
            L = np.linalg.cholesky(Quu)
        except np.linalg.LinAlgError:
            raise NotPositiveDefiniteError(t) from None
        inv_L = np.linalg.solve(L, np.eye(dU))
        Quu_inv = inv_L.T @ inv_L
        K[t] = -Quu_inv @ Qux
        k[t] = -Quu_inv @ q[dX:]
        cov[t] = Quu_inv
        V = _sym(Q[:dX, :dX] + Qux.T @ K[t])
        v = q[:dX] + Qux.T @ k[t]
    return LinearGaussianController.from_cov(K, k, cov)


def forward_pass(
    dyn: LinearGaussianDynamics, controller: LinearGaussianController
) -> tuple[Array, Array]:
    """Gaussian moments of y_t = [x_t; u_t] under the controller and linear-Gaussian dynamics.

    Returns:
      mu (T, dXU) means and sigma (T, dXU, dXU) covariances.
    """
    T, dU, dX = controller.K.shape
    mu = np.zeros((T, dX + dU))
    sigma = np.zeros((T, dX + dU, dX + dU))
    mx, Sx = dyn.x0_mean, dyn.x0_cov
    for t in range(T):
        K = controller.K[t]
        mu[t] = np.concatenate([mx, K @ mx + controller.k[t]])
        SxKt = Sx @ K.T
        sigma[t] = np.block([[Sx, SxKt], [SxKt.T, K @ SxKt + controller.cov[t]]])
        if t < T - 1:
            mx = dyn.F[t] @ mu[t] + dyn.f[t]
            Sx = _sym(dyn.F[t] @ sigma[t] @ dyn.F[t].T + dyn.cov[t])
    return mu, sigma


def expected_cost(cost: QuadraticCost, mu: Array, sigma: Array) -> Array:
    """Exact expected quadratic cost per step (T,) under y_t ~ N(mu_t, sigma_t).

    ``E[l_t] = cc_t + 1/2 tr(sigma_t C_t) + 1/2 mu_t'C_t mu_t + mu_t'c_t`` (the Laplace estimate).
    """
    return (
        cost.cc
        + 0.5 * np.einsum("tij,tji->t", sigma, cost.C)
        + 0.5 * np.einsum("ti,tij,tj->t", mu, cost.C, mu)
        + np.einsum("ti,ti->t", mu, cost.c)
    )


def kl_per_step(
    new: LinearGaussianController, old: LinearGaussianController, mu: Array, sigma: Array
) -> Array:
    """E_x[KL(new(.|x) || old(.|x))] per step (T,), x ~ N(mu_x, sigma_x) of the *new* marginals.

    ``1/2 [log|S_old| - log|S_new| - dU + tr(S_old^-1 S_new) + m'S_old^-1 m
    + tr(dK' S_old^-1 dK Sx)]`` with ``dK = K_new - K_old`` and ``m = dK mu_x + k_new - k_old``;
    clamped at 0 against round-off.
    """
    dX = new.dX
    mx = mu[:, :dX]
    Sx = sigma[:, :dX, :dX]
    P = old.inv_cov
    dK = new.K - old.K
    m = np.einsum("tij,tj->ti", dK, mx) + new.k - old.k
    logdet_old = 2 * np.sum(np.log(np.diagonal(old.chol, axis1=1, axis2=2)), axis=1)
    logdet_new = 2 * np.sum(np.log(np.diagonal(new.chol, axis1=1, axis2=2)), axis=1)
    kl = 0.5 * (
        logdet_old
        - logdet_new
        - new.dU
        + np.einsum("tij,tji->t", P, new.cov)
        + np.einsum("ti,tij,tj->t", m, P, m)
        + np.einsum("tji,tjk,tkl,tli->t", dK, P, dK, Sx)
    )
    return np.maximum(kl, 0.0)
