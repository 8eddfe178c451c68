"""Time-varying linear-Gaussian (TVLG) controllers and their exploration noise.

A TVLG controller of horizon T acts as ``u_t = K_t x_t + k_t + chol(Sigma_t) eps_t`` with
``eps_t ~ N(0, I)``: the policy ``p(u_t | x_t) = N(K_t x_t + k_t, Sigma_t)``. Noise is drawn for
the whole rollout in advance (:func:`exploration_noise`) so it can be smoothed over time.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from lowcostdex.errors import ConfigError, check_number

Array = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class LinearGaussianController:
    """p(u_t | x_t) = N(K_t x_t + k_t, cov_t) for t = 0..T-1.

    Attributes:
      K: (T, dU, dX) feedback gains, action units per state unit.
      k: (T, dU) open-loop terms, action units.
      cov: (T, dU, dU) action covariance (symmetric positive definite).
      chol: (T, dU, dU) lower Cholesky factor of ``cov``.
      inv_cov: (T, dU, dU) precision ``cov^-1``.
    """

    K: Array
    k: Array
    cov: Array
    chol: Array
    inv_cov: Array

    @classmethod
    def from_cov(cls, K: Array, k: Array, cov: Array) -> LinearGaussianController:
        """Build a controller, computing the Cholesky factor and precision of ``cov``.

        Raises:
          ConfigError: if shapes disagree or a covariance is not positive definite.
        """
        K = np.asarray(K, dtype=np.float64)
        k = np.asarray(k, dtype=np.float64)
        cov = np.asarray(cov, dtype=np.float64)
        if K.ndim != 3:
            raise ConfigError(f"K of shape {K.shape} must be (T, dU, dX): one gain per step")
        T, dU, _ = K.shape
        if k.shape != (T, dU) or cov.shape != (T, dU, dU):
            raise ConfigError(f"K {K.shape}, k {k.shape}, cov {cov.shape} are inconsistent: "
                              "need (T, dU, dX), (T, dU), (T, dU, dU)")
        for name, a in (("K", K), ("k", k), ("cov", cov)):
            if not np.all(np.isfinite(a)):  # (a NaN gain acted NaN on the robot)
                raise ConfigError(f"controller {name} holds NaN or inf (first at index "
                                  f"{tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0])})")
        cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
        try:
            chol = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError as exc:
            raise ConfigError("controller covariance is not positive definite") from exc
        eye = np.broadcast_to(np.eye(dU), cov.shape)
        inv_chol = np.linalg.solve(chol, eye)
        inv_cov = np.swapaxes(inv_chol, 1, 2) @ inv_chol
        return cls(K, k, cov, chol, inv_cov)

    @property
    def T(self) -> int:
        return self.K.shape[0]

    @property
    def dX(self) -> int:
        return self.K.shape[2]

    @property
    def dU(self) -> int:
        return self.K.shape[1]

    def act(self, t: int, x: Array, noise: Array | None = None) -> Array:
        """Action (dU,) at step t for state x (dX,); ``noise`` (dU,) is standard normal or None."""
        u = self.K[t] @ x + self.k[t]
        if noise is not None:
            u = u + self.chol[t] @ noise
        return u

    def to_arrays(self) -> dict[str, Array]:
        """Plain arrays for NPZ checkpoints."""
        return {"K": self.K, "k": self.k, "cov": self.cov}

    @classmethod
    def from_arrays(cls, arrays: dict[str, Array]) -> LinearGaussianController:
        return cls.from_cov(arrays["K"], arrays["k"], arrays["cov"])


def pd_controller(
    x0: Array,
    u0: Array,
    T: int,
    pos_index: Sequence[int],
    vel_index: Sequence[int] | None,
    pos_gain: float,
    vel_gain: float,
    noise_var: float,
) -> LinearGaussianController:
    """Initial controller holding the start pose: ``u = u0 - kp (q - q0) - kd (qdot - qdot0)``.

    Action i acts on state coordinate ``pos_index[i]`` (and velocity ``vel_index[i]``). With
    ``pos_gain = vel_gain = 0`` it is open-loop ``u0`` plus exploration noise.

    Args:
      x0: (dX,) start state.
      u0: (dU,) action that holds the start pose (0 for torque control; the normalised start
        joint target for position-controlled servos).
      T: horizon (steps).
      pos_index: dU state indices of the positions the actions drive.
      vel_index: dU state indices of the matching velocities, or None.
      pos_gain: kp, action units per position unit.
      vel_gain: kd, action units per velocity unit.
      noise_var: exploration variance of every action (action units squared), > 0.
    """
    x0 = np.asarray(x0, dtype=np.float64)
    u0 = np.asarray(u0, dtype=np.float64)
    for name, a in (("x0", x0), ("u0", u0)):
        if a.ndim != 1 or not len(a) or not np.all(np.isfinite(a)):
            raise ConfigError(f"pd_controller {name}={a!r:.80} must be a 1-D array of finite "
                              "numbers (the start state / the action holding it)")
    dU = u0.shape[0]
    check_number("pd_controller T (horizon, steps)", T, 1, integer=True)
    check_number("pd_controller pos_gain", pos_gain)
    check_number("pd_controller vel_gain", vel_gain)
    if len(pos_index) != dU or (vel_index is not None and len(vel_index) != dU):
        raise ConfigError(f"pos_index/vel_index need one entry per action ({dU})")
    for i in [*pos_index, *(vel_index or ())]:
        check_number("pd_controller state index", i, -x0.shape[0], x0.shape[0] - 1, integer=True)
    check_number("pd_controller noise_var (action units squared)", noise_var, 0, low_open=True)
    gain = np.zeros((dU, x0.shape[0]))
    gain[np.arange(dU), list(pos_index)] = -pos_gain
    if vel_index is not None:
        gain[np.arange(dU), list(vel_index)] = -vel_gain
    K = np.broadcast_to(gain, (T, dU, x0.shape[0])).copy()
    k = np.broadcast_to(u0 - gain @ x0, (T, dU)).copy()
    cov = np.broadcast_to(noise_var * np.eye(dU), (T, dU, dU)).copy()
    return LinearGaussianController.from_cov(K, k, cov)


def exploration_noise(
    rng: np.random.Generator, T: int, dU: int, smooth_sigma: float = 0.0
) -> Array:
    """Standard-normal noise (T, dU), optionally smoothed over time.

    With ``smooth_sigma`` > 0 (in steps) the white noise is filtered with a Gaussian kernel and
    rescaled so each action keeps unit empirical variance. Smoothing makes exploration less jerky
    on hardware but breaks the white-noise assumption of the dynamics fit; keep it small (<= 1).
    """
    check_number("exploration_noise T (steps)", T, 1, integer=True)
    check_number("exploration_noise dU (actions)", dU, 1, integer=True)
    check_number("exploration_noise smooth_sigma (steps)", smooth_sigma, 0)
    noise = rng.standard_normal((T, dU))
    if smooth_sigma > 0:
        from scipy.ndimage import gaussian_filter1d  # imported here: 0.3 s of CLI start-up

        noise = gaussian_filter1d(noise, smooth_sigma, axis=0, mode="nearest")
        noise /= np.maximum(noise.std(axis=0, keepdims=True), 1e-12)
    return noise


def rollout_linear_gaussian(
    controller: LinearGaussianController,
    F: Array,
    f: Array,
    dyn_cov: Array,
    x0: Array,
    rng: np.random.Generator,
) -> tuple[Array, Array]:
    """Sample one trajectory of ``controller`` through linear-Gaussian dynamics.

    Args:
      F: (T-1, dX, dX+dU), f: (T-1, dX), dyn_cov: (T-1, dX, dX) dynamics per transition.
      x0: (dX,) initial state.

    Returns:
      X (T, dX), U (T, dU).
    """
    T, dU, dX = controller.K.shape
    X = np.zeros((T, dX))
    U = np.zeros((T, dU))
    X[0] = x0
    for t in range(T):
        U[t] = controller.act(t, X[t], rng.standard_normal(dU))
        if t + 1 < T:
            mean = F[t] @ np.concatenate([X[t], U[t]]) + f[t]
            X[t + 1] = rng.multivariate_normal(mean, dyn_cov[t])
    return X, U
