"""Behaviour cloning: supervised pre-training of the Gaussian policy on demonstrations.

As in mjrl/hand_dapg, before fitting BC sets from the demonstrations:

- the observation normalisation to the demo mean/std (frozen by default),
- the output scaling ``act_shift``/``act_scale`` to the demo action mean/std (the scale is
  floored at ``min_action_scale`` so a joint the teacher barely moved stays learnable by RL),
- the exploration noise ``log_std = log(std of demo actions)`` (clamped at the policy's
  ``min_log_std``), so RL starts exploring with the teacher's spread instead of std 1 —
  with std 1 over a [-1, 1] action range a hardware claw would jerk between random targets.

The demo spread measures how much the teacher's actions vary over the whole task, not how
precise they are: for a precise (scripted or virtual) teacher it is large, and the cloned policy
with that noise fails a task that its mean solves. ``log_std="residual"`` instead sets, after
fitting, the noise to the per-dimension standard deviation of what the clone does not explain
(demo action minus policy mean), clamped at ``min_log_std``; ``"keep"`` leaves the policy's own
``init_log_std``.

Then it minimises the mean-squared error between the policy mean and the demo actions ('mse',
mjrl's default) or the Gaussian negative log-likelihood ('mle', which also trains log_std) with
Adam over shuffled minibatches. The DAPG authors' users report DAPG "cannot learn" without this
initialisation (hand_dapg#10).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from lowcostdex.algos.configs import BCConfig
from lowcostdex.algos.npg import check_samples
from lowcostdex.algos.policy import GaussianMLPPolicy
from lowcostdex.errors import ConfigError


def demo_statistics(obs: np.ndarray, actions: np.ndarray) -> dict[str, np.ndarray]:
    """Per-dimension mean and std of demo observations (n, obs_dim) and actions (n, act_dim)."""
    obs, actions = np.asarray(obs, dtype=np.float64), np.asarray(actions, dtype=np.float64)
    return {
        "obs_mean": obs.mean(0),
        "obs_std": obs.std(0),
        "act_mean": actions.mean(0),
        "act_std": actions.std(0),
    }


@torch.no_grad()
def set_from_demos(
    policy: GaussianMLPPolicy, obs: np.ndarray, actions: np.ndarray, config: BCConfig
) -> None:
    """Set normalisation, output scaling and log_std of ``policy`` from demo statistics."""
    stats = demo_statistics(obs, actions)
    dtype = policy.log_std.dtype
    if config.set_obs_normalization:
        policy.obs_norm.set_stats(
            stats["obs_mean"],
            stats["obs_std"],
            freeze=config.freeze_obs_normalization,
            count=len(obs),
        )
    if config.set_action_scaling:
        policy.act_shift.copy_(torch.as_tensor(stats["act_mean"], dtype=dtype))
        scale = np.maximum(stats["act_std"], config.min_action_scale)
        policy.act_scale.copy_(torch.as_tensor(scale, dtype=dtype))
    if config.log_std == "demo_spread":
        policy.log_std.copy_(torch.as_tensor(np.log(stats["act_std"] + 1e-12), dtype=dtype))
        policy.clamp_log_std_()


def bc_loss(
    policy: GaussianMLPPolicy, obs: torch.Tensor, actions: torch.Tensor, loss: str
) -> torch.Tensor:
    """Mean BC loss on a batch: squared error of the mean ('mse') or negative log-likelihood."""
    if loss == "mse":
        return ((policy(obs) - actions) ** 2).sum(-1).mean()
    return -policy.log_prob(obs, actions).mean()


def behavior_clone(
    policy: GaussianMLPPolicy,
    obs: Any,
    actions: Any,
    config: BCConfig,
    generator: torch.Generator,
) -> dict[str, float]:
    """Pre-train ``policy`` in place on demonstration pairs.

    Args:
      policy: the policy to initialise.
      obs: (n, obs_dim) demo observations.
      actions: (n, act_dim) demo actions in the env's action space ([-1, 1]).
      config: BC settings.
      generator: seeded generator for the minibatch order.

    Returns:
      ``{"bc_loss_before", "bc_loss_after", "bc_steps"}`` (MSE of the mean, summed over action
      dimensions, averaged over samples, whatever the training loss).
    """
    check_samples(policy, obs, actions)  # (an empty, mismatched or NaN set: ConfigError)
    if not isinstance(generator, torch.Generator):
        raise ConfigError(f"generator={generator!r} must be a seeded torch.Generator "
                          "(torch.Generator().manual_seed(0)): it orders the minibatches")
    obs_np, act_np = np.asarray(obs, dtype=np.float64), np.asarray(actions, dtype=np.float64)
    set_from_demos(policy, obs_np, act_np, config)
    dtype = policy.log_std.dtype
    obs_t, act_t = torch.as_tensor(obs_np, dtype=dtype), torch.as_tensor(act_np, dtype=dtype)
    with torch.no_grad():
        before = float(bc_loss(policy, obs_t, act_t, "mse"))
    params = [
        p for name, p in policy.named_parameters() if config.loss == "mle" or name != "log_std"
    ]
    optimizer = torch.optim.Adam(params, lr=config.lr)
    n, bs, steps = obs_t.shape[0], config.batch_size, 0
    for _ in range(config.epochs):
        perm = torch.randperm(n, generator=generator)
        for start in range(0, n, bs):
            idx = perm[start : start + bs]
            loss = bc_loss(policy, obs_t[idx], act_t[idx], config.loss)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            policy.clamp_log_std_()
            steps += 1
    with torch.no_grad():
        after = float(bc_loss(policy, obs_t, act_t, "mse"))
        if config.log_std == "residual":
            residual = (act_t - policy(obs_t)).std(0, unbiased=False)
            policy.log_std.copy_(torch.log(residual + 1e-12))
            policy.clamp_log_std_()
    return {"bc_loss_before": before, "bc_loss_after": after, "bc_steps": float(steps)}
