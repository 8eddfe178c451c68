"""A numpy copy of the Gaussian policy, for sampling workers (no torch import needed).

:meth:`lowcostdex.algos.policy.GaussianMLPPolicy.snapshot` builds it. Worker processes of the
samplers import only this module, numpy and the env, so they start fast.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PolicySnapshot:
    """Picklable float64 numpy copy of a :class:`GaussianMLPPolicy` for rollouts.

    Evaluates ONE observation at a time (matrix-vector products), so every sampler — serial,
    process pool, vector env, Ray — computes bit-identical actions for the same observation and
    noise, whatever the number of workers.
    """

    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    activation: str
    obs_mean: np.ndarray
    obs_std: np.ndarray
    act_shift: np.ndarray
    act_scale: np.ndarray
    std: np.ndarray

    @property
    def act_dim(self) -> int:
        return int(self.std.shape[0])

    def mean(self, obs: np.ndarray) -> np.ndarray:
        """Action mean (act_dim,) for one observation (obs_dim,)."""
        x = np.asarray(obs, dtype=np.float64)
        if x.size != self.obs_mean.shape[0] or x.ndim > 1 and x.shape[-1] != x.size:
            # a bare numpy broadcast error otherwise, naming neither size
            raise ValueError(f"observation of shape {x.shape}; this policy takes "
                             f"({self.obs_mean.shape[0]},) (an env of another observation "
                             "size? build the policy for this env, or load its own checkpoint)")
        h = (x.reshape(-1) - self.obs_mean) / self.obs_std
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = w @ h + b
            if i < last:
                h = np.tanh(h) if self.activation == "tanh" else np.maximum(h, 0.0)
        return h * self.act_scale + self.act_shift

    def act(self, obs: np.ndarray, noise: np.ndarray | None) -> np.ndarray:
        """Mean plus ``std * noise`` for one observation; ``noise=None`` gives the mean.

        Args:
          obs: (obs_dim,) observation.
          noise: (act_dim,) standard-normal draw, or None for the deterministic action.
        """
        mean = self.mean(obs)
        if noise is None:
            return mean
        if np.shape(noise) != self.std.shape:  # a scalar or (1,) noise was broadcast
            raise ValueError(f"noise of shape {np.shape(noise)}; this policy draws "
                             f"{self.std.shape} (one standard-normal number per action), or "
                             "None for the mean action")
        return mean + self.std * noise
