"""Demo-augmented policy gradient (DAPG; Rajeswaran et al., RSS 2018).

DAPG = behaviour cloning (:mod:`lowcostdex.algos.bc`), then NPG steps along an augmented
gradient that also pushes up the likelihood of the demonstrations:

    g_aug = (1/N) [ sum_{(s,a) in rho_pi} grad log pi(a|s) A(s,a)
                  + sum_{(s,a) in rho_D}  grad log pi(a|s) w_k ]

followed by the same normalised natural-gradient step as NPG (:func:`npg.natural_gradient_step`):
x = F^-1 g_aug by truncated CG, alpha = sqrt(delta / g_aug^T x). The Fisher F and the measured
KL use the on-policy samples only; demonstrations enter the gradient, not the geometry.
N is the number of on-policy samples. This module calls the NPG pieces; it does not subclass.

Demo weight w_k at DAPG iteration k = 0, 1, ... (k counts RL iterations after BC), two forms:

- ``"paper"`` (default): ``w_k = lam0 * lam1**k * max_i A_i``, the heuristic of the paper
  (section IV-C2), with A the (whitened) on-policy advantages of this batch; the paper uses
  lam0 = 0.1, lam1 = 0.95 and reports low sensitivity to both. Because w scales with the largest
  advantage, the demo term keeps the same weight relative to the RL term whatever the reward
  scale.
- ``"mjrl"``: ``w_k = lam0 * lam1**k``, a constant on whitened advantages — what mjrl's
  ``dapg.py`` does (it drops the max-advantage factor; hand_dapg's released config uses
  lam0 = 0.01, lam1 = 0.95). mjrl also multiplies all advantages by 1e-2, which has no effect
  under the normalised step and is left out here.

In both forms w_k -> 0 as k grows (pure NPG); w = 0 from the start is NPG after BC ("BCRL");
a very large w approaches BC. k must advance every iteration: in hand_dapg it once did not
(hand_dapg#4), so :func:`dapg_update` takes k explicitly and tests check the decay.
"""

from __future__ import annotations

from typing import Any

import torch

from lowcostdex.algos.configs import DEMO_WEIGHTS, DAPGConfig, NPGConfig
from lowcostdex.algos.npg import (
    as_tensor,
    check_samples,
    natural_gradient_step,
    prepare_advantages,
    surrogate_gradient,
)
from lowcostdex.algos.policy import GaussianMLPPolicy
from lowcostdex.errors import check_choice


def demo_weight(k: int, lam0: float, lam1: float, advantages: Any, mode: str = "paper") -> float:
    """The demo-term weight w_k at DAPG iteration ``k`` (>= 0).

    Args:
      k: RL iteration index after BC.
      lam0, lam1: initial factor and decay.
      advantages: (N,) on-policy advantages of this batch (used by ``"paper"`` only).
      mode: one of DEMO_WEIGHTS.

    Returns:
      ``lam0 * lam1**k * max(max(advantages), 0)`` ("paper") or ``lam0 * lam1**k`` ("mjrl").
    """
    check_choice("DAPG demo weight", mode, DEMO_WEIGHTS)
    if k < 0:
        raise ValueError(f"iteration k={k} must be >= 0")
    base = lam0 * lam1**k
    if mode == "mjrl":
        return float(base)
    adv = torch.as_tensor(advantages)
    return float(base * max(float(adv.max()), 0.0)) if adv.numel() else 0.0


def dapg_update(
    policy: GaussianMLPPolicy,
    obs: Any,
    actions: Any,
    advantages: Any,
    demo_obs: Any,
    demo_actions: Any,
    k: int,
    config: DAPGConfig,
    npg_config: NPGConfig,
    generator: torch.Generator | None = None,
) -> dict[str, float]:
    """One DAPG step on on-policy samples plus all demonstration pairs; updates ``policy``.

    Args:
      policy: the sampling policy.
      obs, actions, advantages: on-policy batch, (N, obs_dim), (N, act_dim), (N,).
      demo_obs, demo_actions: demonstration pairs, (M, obs_dim), (M, act_dim).
      k: DAPG iteration index (0 for the first RL iteration after BC).
      config: DAPG settings.
      npg_config: the natural-gradient step settings.
      generator: for the Fisher subsample when ``npg_config.fvp_sample_frac < 1``.

    Returns:
      NPG step statistics plus ``demo_weight`` and ``demo_log_lik`` (mean log-likelihood of
      the demo actions after the step).
    """
    check_samples(policy, obs, actions, advantages)
    check_samples(policy, demo_obs, demo_actions, prefix="demo_")  # (none: use npg_update)
    dtype = policy.log_std.dtype
    obs_t, act_t = as_tensor(obs, dtype), as_tensor(actions, dtype)
    d_obs, d_act = as_tensor(demo_obs, dtype), as_tensor(demo_actions, dtype)
    adv = prepare_advantages(advantages, npg_config, dtype)
    w = demo_weight(k, config.lam0, config.lam1, adv, config.demo_weight)
    all_obs = torch.cat([obs_t, d_obs])
    all_act = torch.cat([act_t, d_act])
    weights = torch.cat([adv, torch.full((d_obs.shape[0],), w, dtype=dtype)])
    grad = surrogate_gradient(policy, all_obs, all_act, weights, normalizer=obs_t.shape[0])
    stats = natural_gradient_step(policy, grad, obs_t, npg_config, generator)
    with torch.no_grad():
        stats["demo_log_lik"] = float(policy.log_prob(d_obs, d_act).mean())
    stats["demo_weight"] = w
    return stats
