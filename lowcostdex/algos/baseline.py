"""Value baseline V(s, t): an MLP on normalised observations plus time features.

As in mjrl's MLPBaseline, the input is the observation plus four time features and the network
is fitted by Adam (with weight decay) to the returns of the latest batch, AFTER the policy step:
advantages at iteration k use the fit on iteration k-1's data. Differences, each for a pitfall
noted in the mjrl reference:

- time features are powers of ``t / horizon`` (not ``t / 1000``, which is ~0 for 40-step
  hardware episodes);
- observations are standardised with running statistics and targets with the latest batch's
  mean and std; when the target statistics change, the last layer is rescaled so the predicted
  values are unchanged (the fit continues from where it was);
- before the first fit it predicts 0 instead of a random network's outputs.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import nn

from lowcostdex.algos.configs import BaselineConfig
from lowcostdex.algos.policy import ObsNormalizer

N_TIME_FEATURES = 4


def time_features(t: np.ndarray | torch.Tensor, horizon: int) -> torch.Tensor:
    """(n, 4) features ``[tau, tau^2, tau^3, tau^4]`` with ``tau = t / horizon``."""
    tau = torch.as_tensor(np.asarray(t), dtype=torch.float64).reshape(-1, 1) / float(horizon)
    return torch.cat([tau**p for p in range(1, N_TIME_FEATURES + 1)], dim=1)


class MLPBaseline(nn.Module):
    """V(s, t) for trajectories of at most ``horizon`` steps.

    Args:
      obs_dim: observation size.
      horizon: episode length used to scale the time features [steps].
      config: architecture and fit settings.
      generator: seeded ``torch.Generator`` for the initial weights.
    """

    def __init__(
        self,
        obs_dim: int,
        horizon: int,
        config: BaselineConfig | None = None,
        generator: torch.Generator | None = None,
    ):
        super().__init__()
        self.config = config or BaselineConfig()
        self.obs_dim, self.horizon = int(obs_dim), int(horizon)
        self.obs_norm = ObsNormalizer(obs_dim, min_std=1e-2)
        sizes = (self.obs_dim + N_TIME_FEATURES, *self.config.hidden_sizes, 1)
        layers: list[nn.Module] = []
        for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
            layers.append(nn.utils.skip_init(nn.Linear, n_in, n_out, dtype=torch.float64))
            if i < len(sizes) - 2:
                layers.append(nn.Tanh() if self.config.activation == "tanh" else nn.ReLU())
        self.net = nn.Sequential(*layers)
        self.register_buffer("target_mean", torch.zeros((), dtype=torch.float64))
        self.register_buffer("target_std", torch.ones((), dtype=torch.float64))
        self.register_buffer("fitted", torch.zeros((), dtype=torch.bool))
        with torch.no_grad():
            for layer in self.net:
                if isinstance(layer, nn.Linear):
                    if generator is None:
                        layer.weight.zero_()
                        layer.bias.zero_()
                    else:
                        nn.init.kaiming_uniform_(layer.weight, a=5**0.5, generator=generator)
                        bound = 1 / layer.in_features**0.5
                        nn.init.uniform_(layer.bias, -bound, bound, generator=generator)
        self.optimizer = torch.optim.Adam(
            self.net.parameters(), lr=self.config.lr, weight_decay=self.config.weight_decay
        )

    def _features(self, obs: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        obs_n = self.obs_norm(obs).clamp(-10.0, 10.0)
        return torch.cat([obs_n, time_features(t, self.horizon)], dim=1)

    @torch.no_grad()
    def predict(self, obs: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Values (n,) for observations (n, obs_dim) at step indices t (n,); 0 before a fit."""
        obs_t = torch.as_tensor(np.asarray(obs), dtype=torch.float64).reshape(-1, self.obs_dim)
        if not bool(self.fitted):
            return np.zeros(obs_t.shape[0])
        out = self.net(self._features(obs_t, torch.as_tensor(np.asarray(t))))[:, 0]
        return (out * self.target_std + self.target_mean).numpy()

    @torch.no_grad()
    def _rescale_targets(self, returns: torch.Tensor) -> None:
        """Move to the new targets' mean/std, rescaling the last layer to keep predictions."""
        new_mean, new_std = returns.mean(), returns.std().clamp_min(1e-6)
        last = [m for m in self.net if isinstance(m, nn.Linear)][-1]
        if bool(self.fitted):
            last.weight.mul_(self.target_std / new_std)
            last.bias.mul_(self.target_std).add_(self.target_mean - new_mean).div_(new_std)
        self.target_mean.copy_(new_mean)
        self.target_std.copy_(new_std)

    def fit(
        self, obs: np.ndarray, t: np.ndarray, returns: np.ndarray, generator: torch.Generator
    ) -> dict[str, float]:
        """Fit V to ``returns`` by minibatch Adam; returns relative errors before and after.

        Args:
          obs: (n, obs_dim) observations.
          t: (n,) step index of each observation within its trajectory.
          returns: (n,) regression targets.
          generator: seeded generator for the minibatch order.

        Returns:
          ``{"vf_error_before", "vf_error_after"}``: sum (R - V)^2 / sum (R - mean R)^2
          (1 = no better than the mean, 0 = perfect).
        """
        obs_t = torch.as_tensor(np.asarray(obs), dtype=torch.float64).reshape(-1, self.obs_dim)
        t_t = torch.as_tensor(np.asarray(t))
        ret = torch.as_tensor(np.asarray(returns), dtype=torch.float64).reshape(-1)
        denom = float(((ret - ret.mean()) ** 2).sum().clamp_min(1e-12))
        before = float(((ret - torch.as_tensor(self.predict(obs, t))) ** 2).sum()) / denom
        self.obs_norm.update(obs_t)
        self._rescale_targets(ret)
        self.fitted.fill_(True)
        x = self._features(obs_t, t_t)
        y = (ret - self.target_mean) / self.target_std
        n, bs = x.shape[0], self.config.batch_size
        for _ in range(self.config.epochs):
            perm = torch.randperm(n, generator=generator)
            for start in range(0, n, bs):
                idx = perm[start : start + bs]
                loss = ((self.net(x[idx])[:, 0] - y[idx]) ** 2).mean()
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()
        after = float(((ret - torch.as_tensor(self.predict(obs, t))) ** 2).sum()) / denom
        return {"vf_error_before": before, "vf_error_after": after}

    def to_checkpoint(self) -> dict[str, Any]:
        """Network, statistics and Adam state (safe types)."""
        return {"state_dict": self.state_dict(), "optimizer": self.optimizer.state_dict()}

    def load_checkpoint(self, ckpt: dict[str, Any]) -> None:
        """Restore what :meth:`to_checkpoint` saved."""
        self.load_state_dict(ckpt["state_dict"])
        self.optimizer.load_state_dict(ckpt["optimizer"])
