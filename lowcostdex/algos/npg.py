"""Natural policy gradient (NPG), truncated as used on the D'Claw.

One update, on a batch of on-policy samples (s_i, a_i) with advantages A_i (i = 1..N):

    g     = grad_theta (1/N) sum_i exp(log pi_theta(a_i|s_i) - log pi_old(a_i|s_i)) A_i
          = (1/N) sum_i grad log pi(a_i|s_i) A_i                     (at theta = theta_old)
    F     = Hessian of (1/N) sum_i KL(pi_old(.|s_i) || pi_theta(.|s_i)) at theta_old
            (the exact Fisher of the Gaussian policy family, from the closed-form KL)
    x     ~ (F + damping I)^-1 g                 conjugate gradient, truncated at cg_iters
    alpha = sqrt(delta / (g^T x))                normalised step size
    theta <- theta + alpha x

To second order the step's KL(old || new) is ``alpha^2 x^T F x / 2 = delta / 2``; ``delta`` is
mjrl's ``normalized_step_size`` (hand_dapg uses 0.05). "Truncated NPG" — the name the D'Claw work
(Zhu et al. 2019) uses, TNPG in Duan et al. 2016 — is exactly this: F^-1 g from a few CG
iterations, no line search. mjrl's defaults are kept: 10 CG iterations from x0 = 0, damping
1e-4, residual tolerance 1e-10. An optional KL check (``max_kl``) backtracks the step
(alpha <- ratio * alpha) until the measured KL is below the bound, as mjrl's TRPO does.

The pieces are small functions that tests and DAPG (:mod:`lowcostdex.algos.dapg`) call:
:func:`conjugate_gradient`, :func:`make_fisher_vector_product`, :func:`normalized_step_size`,
:func:`backtrack_kl`, :func:`surrogate_gradient` and :func:`natural_gradient_step`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from torch.nn.utils import parameters_to_vector, vector_to_parameters

from lowcostdex.algos.configs import NPGConfig
from lowcostdex.algos.policy import GaussianMLPPolicy, gaussian_kl
from lowcostdex.errors import check_rows

MatVec = Callable[[torch.Tensor], torch.Tensor]
"""A symmetric positive-definite operator: (n,) vector -> (n,) vector."""


# ----------------------------------------------------------------------------------------------
# Pure pieces


def flat_grad(
    y: torch.Tensor,
    params: list[torch.nn.Parameter],
    create_graph: bool = False,
    retain_graph: bool | None = None,
) -> torch.Tensor:
    """Gradient of scalar ``y`` w.r.t. ``params``, flattened to one (n_params,) vector."""
    grads = torch.autograd.grad(
        y, params, create_graph=create_graph, retain_graph=retain_graph, allow_unused=True
    )
    return torch.cat(
        [
            (torch.zeros_like(p) if g is None else g).reshape(-1)
            for g, p in zip(grads, params, strict=True)
        ]
    )


def conjugate_gradient(
    matvec: MatVec, b: torch.Tensor, iters: int = 10, residual_tol: float = 1e-10
) -> torch.Tensor:
    """Approximately solve ``A x = b`` for symmetric positive-definite A, starting at x = 0.

    Args:
      matvec: v -> A v.
      b: (n,) right-hand side.
      iters: maximum iterations (exact after n in exact arithmetic).
      residual_tol: stop when the squared residual norm r^T r falls below this.

    Returns:
      (n,) solution estimate.
    """
    x = torch.zeros_like(b)
    r = b.clone()
    p = b.clone()
    rr = torch.dot(r, r)
    for _ in range(iters):
        if rr < residual_tol:
            break
        ap = matvec(p)
        step = rr / torch.dot(p, ap)
        x = x + step * p
        r = r - step * ap
        rr_new = torch.dot(r, r)
        p = r + (rr_new / rr) * p
        rr = rr_new
    return x


def mean_kl(
    policy: GaussianMLPPolicy, obs: torch.Tensor, old_mean: torch.Tensor, old_log_std: torch.Tensor
) -> torch.Tensor:
    """Mean over ``obs`` (n, obs_dim) of KL(pi_old || pi_policy), a scalar [nats]."""
    return gaussian_kl(old_mean, old_log_std, policy(obs), policy.log_std).mean()


def make_fisher_vector_product(
    policy: GaussianMLPPolicy, obs: torch.Tensor, damping: float
) -> MatVec:
    """Return v -> (F + damping I) v at the policy's current parameters.

    F is the Hessian of the mean closed-form KL(pi_current || pi_theta) over ``obs``
    (n, obs_dim) at theta = current, i.e. the analytic Fisher information of the Gaussian
    policy: for each state ``J_mu^T diag(1/sigma^2) J_mu`` for the mean parameters and
    2 per log-std entry, averaged over states. Computed by double back-propagation; the
    parameters must not change while the returned function is in use.
    """
    params = list(policy.parameters())
    with torch.no_grad():
        old_mean, old_log_std = policy(obs), policy.log_std.clone()
    kl = mean_kl(policy, obs, old_mean, old_log_std)
    grad_kl = flat_grad(kl, params, create_graph=True)

    def fvp(v: torch.Tensor) -> torch.Tensor:
        hv = flat_grad(torch.dot(grad_kl, v), params, retain_graph=True)
        return hv + damping * v

    return fvp


def normalized_step_size(grad: torch.Tensor, nat_grad: torch.Tensor, delta: float) -> float:
    """``alpha = sqrt(delta / (g^T F^-1 g))`` with ``nat_grad = F^-1 g`` (both (n,))."""
    g_f_g = float(torch.dot(grad, nat_grad))
    return math.sqrt(delta / (max(g_f_g, 0.0) + 1e-20))


def backtrack_kl(
    kl_at: Callable[[float], float],
    alpha: float,
    max_kl: float,
    ratio: float = 0.8,
    max_backtracks: int = 10,
) -> tuple[float, float, int]:
    """Shrink a step until its KL is within bounds.

    Args:
      kl_at: step length -> measured mean KL(old || new) after a step of that length.
      alpha: initial step length.
      max_kl: largest accepted KL [nats].
      ratio: factor applied to the step length per trial.
      max_backtracks: trials after the first.

    Returns:
      ``(alpha, kl, n_backtracks)``; ``alpha = 0`` and ``kl = 0`` if no trial was accepted.
    """
    for n in range(max_backtracks + 1):
        kl = kl_at(alpha)
        if kl <= max_kl:
            return alpha, kl, n
        alpha *= ratio
    return 0.0, 0.0, max_backtracks + 1


def surrogate_gradient(
    policy: GaussianMLPPolicy,
    obs: torch.Tensor,
    actions: torch.Tensor,
    weights: torch.Tensor,
    normalizer: int | None = None,
) -> torch.Tensor:
    """``grad (1/normalizer) sum_i ratio_i * weights_i`` at the current parameters, flattened.

    With ``ratio_i = exp(log pi(a_i|s_i) - stop_grad(log pi(a_i|s_i)))`` this equals
    ``(1/normalizer) sum_i grad log pi(a_i|s_i) * weights_i`` (the likelihood-ratio form
    mjrl uses). ``normalizer`` defaults to the number of samples.
    """
    params = list(policy.parameters())
    logp = policy.log_prob(obs, actions)
    ratio = torch.exp(logp - logp.detach())
    n = obs.shape[0] if normalizer is None else normalizer
    return flat_grad((ratio * weights).sum() / n, params)


def natural_gradient_step(
    policy: GaussianMLPPolicy,
    grad: torch.Tensor,
    obs: torch.Tensor,
    config: NPGConfig,
    generator: torch.Generator | None = None,
) -> dict[str, float]:
    """Apply one normalised natural-gradient step along F^-1 ``grad`` to ``policy`` in place.

    Args:
      policy: updated in place (log_std clamped afterwards).
      grad: (n_params,) ascent direction, e.g. the NPG or DAPG gradient.
      obs: (N, obs_dim) on-policy observations that define the Fisher and the measured KL.
      config: step settings.
      generator: required when ``config.fvp_sample_frac < 1`` (Fisher subsample).

    Returns:
      Statistics: ``alpha``, ``kl`` (measured mean KL old||new), ``g_f_g`` (g^T F^-1 g),
      ``grad_norm``, ``cg_residual`` (||F x - g|| / ||g||) and ``n_backtracks``.
    """
    params = list(policy.parameters())
    theta_old = parameters_to_vector(params).detach().clone()
    fisher_obs = obs
    if config.fvp_sample_frac < 1:
        if generator is None:
            raise ValueError("fvp_sample_frac < 1 needs a seeded torch.Generator")
        m = max(1, int(round(config.fvp_sample_frac * obs.shape[0])))
        fisher_obs = obs[torch.randperm(obs.shape[0], generator=generator)[:m]]
    fvp = make_fisher_vector_product(policy, fisher_obs, config.damping)
    nat_grad = conjugate_gradient(fvp, grad, config.cg_iters, config.cg_residual_tol)
    residual = float(torch.linalg.norm(fvp(nat_grad) - grad) / (torch.linalg.norm(grad) + 1e-20))
    alpha = normalized_step_size(grad, nat_grad, config.step_size)
    with torch.no_grad():
        old_mean, old_log_std = policy(obs), policy.log_std.clone()

    def kl_at(step: float) -> float:
        with torch.no_grad():
            vector_to_parameters(theta_old + step * nat_grad, params)
            policy.clamp_log_std_()
            return float(mean_kl(policy, obs, old_mean, old_log_std))

    n_backtracks = 0
    if config.max_kl is None:
        kl = kl_at(alpha)
    else:
        alpha, kl, n_backtracks = backtrack_kl(
            kl_at, alpha, config.max_kl, config.backtrack_ratio, config.max_backtracks
        )
        if alpha == 0.0:
            kl = kl_at(0.0)
    return {
        "alpha": alpha,
        "kl": kl,
        "g_f_g": float(torch.dot(grad, nat_grad)),
        "grad_norm": float(torch.linalg.norm(grad)),
        "cg_residual": residual,
        "n_backtracks": float(n_backtracks),
    }


# ----------------------------------------------------------------------------------------------
# The NPG update


def as_tensor(x: Any, dtype: torch.dtype) -> torch.Tensor:
    """Tensor of ``dtype`` from a numpy array or tensor (no copy when possible)."""
    return torch.as_tensor(np.asarray(x) if not isinstance(x, torch.Tensor) else x, dtype=dtype)


def check_samples(policy: GaussianMLPPolicy, obs: Any, actions: Any, advantages: Any = None,
                  prefix: str = "") -> None:
    """A batch for an update: ``obs`` (N, obs_dim), ``actions`` (N, act_dim) and ``advantages``
    (N,) of finite numbers, N >= 1; else ConfigError naming the array and the sizes the policy
    takes (a NaN made the step NaN, a one-column action batch was broadcast, an empty one gave
    NaN statistics, a wrong width failed deep in torch). ``prefix``: "demo_" for demo pairs."""
    n = check_rows(f"{prefix}obs", obs, policy.obs_dim,
                   f"one observation per row, {policy.obs_dim} numbers (the policy's obs_dim)")
    check_rows(f"{prefix}actions", actions, policy.act_dim, f"one action per observation, "
               f"{policy.act_dim} numbers in [-1, 1] (the policy's act_dim)", rows=n)
    if advantages is not None:
        check_rows(f"{prefix}advantages", advantages, None, "one advantage per observation",
                   rows=n)


def prepare_advantages(advantages: Any, config: NPGConfig, dtype: torch.dtype) -> torch.Tensor:
    """(N,) advantages as a tensor, whitened over the batch when the config says so."""
    adv = as_tensor(advantages, dtype).reshape(-1)
    if config.normalize_advantages:
        adv = (adv - adv.mean()) / (adv.std(unbiased=False) + 1e-6)
    return adv


def npg_update(
    policy: GaussianMLPPolicy,
    obs: Any,
    actions: Any,
    advantages: Any,
    config: NPGConfig,
    generator: torch.Generator | None = None,
) -> dict[str, float]:
    """One NPG step on a batch of on-policy samples; updates ``policy`` in place.

    Args:
      policy: the sampling policy (theta_old).
      obs: (N, obs_dim) observations.
      actions: (N, act_dim) actions taken (before any clipping by the env).
      advantages: (N,) advantage estimates (e.g. GAE).
      config: step settings.
      generator: for the Fisher subsample when ``config.fvp_sample_frac < 1``.

    Returns:
      The statistics of :func:`natural_gradient_step` plus ``surr_before``, ``surr_after`` and
      ``surr_improvement`` (mean importance-weighted advantage before and after the step).
    """
    check_samples(policy, obs, actions, advantages)
    dtype = policy.log_std.dtype
    obs_t, act_t = as_tensor(obs, dtype), as_tensor(actions, dtype)
    adv = prepare_advantages(advantages, config, dtype)
    with torch.no_grad():
        logp_old = policy.log_prob(obs_t, act_t)
    grad = surrogate_gradient(policy, obs_t, act_t, adv)
    stats = natural_gradient_step(policy, grad, obs_t, config, generator)
    with torch.no_grad():
        surr_before = float(adv.mean())
        surr_after = float((torch.exp(policy.log_prob(obs_t, act_t) - logp_old) * adv).mean())
    stats.update(
        surr_before=surr_before, surr_after=surr_after, surr_improvement=surr_after - surr_before
    )
    return stats
