"""Gaussian MLP policy with observation normalisation, as used by NPG, DAPG and BC.

The policy is ``a ~ N(mu(s), diag(exp(log_std))^2)`` with

    mu(s) = act_shift + act_scale * MLP((s - obs_mean) / obs_std)

and a state-independent, trainable ``log_std`` vector (one entry per action dimension),
clamped from below at ``min_log_std``. Initialisation follows mjrl: PyTorch's default
``nn.Linear`` initialisation (drawn from the ``torch.Generator`` passed in), then the last
layer's weight and bias scaled by ``last_layer_scale`` (1e-2), so the initial mean is almost
exactly ``act_shift``.

Observation normalisation (:class:`ObsNormalizer`) is either set from demonstration statistics
(BC does this) and frozen, or updated from each batch of samples. A running update changes
``obs_mean``/``obs_std``, so :meth:`GaussianMLPPolicy.update_obs_normalizer` rewrites the first
layer so that ``mu(s)`` is unchanged: normalisation never moves the policy outside the NPG
trust region.

Parameters and buffers are float64 by default: the networks are small, and the natural-gradient
maths (Fisher-vector products, conjugate gradient) benefits from the precision.

Sampling workers do not run (or import) torch: :meth:`GaussianMLPPolicy.snapshot` returns a
picklable numpy copy (:class:`~lowcostdex.algos.snapshot.PolicySnapshot`) that evaluates one
observation at a time, so an action does not depend on how many trajectories a worker batches.
"""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import Any

import numpy as np
import torch
from torch import nn

from lowcostdex.algos.configs import PolicyConfig
from lowcostdex.algos.snapshot import PolicySnapshot
from lowcostdex.errors import ConfigError, check_keys, check_number

# ----------------------------------------------------------------------------------------------
# Diagonal Gaussian maths (pure functions)


def gaussian_log_prob(mean: torch.Tensor, log_std: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Log density of ``x`` under N(mean, diag(exp(log_std))^2), summed over the last axis.

    Args:
      mean: (n, m) means.
      log_std: (m,) or (n, m) log standard deviations.
      x: (n, m) actions.

    Returns:
      (n,) log-likelihoods.
    """
    z = (x - mean) / torch.exp(log_std)
    m = mean.shape[-1]
    return -0.5 * (z**2).sum(-1) - log_std.sum(-1) - 0.5 * m * math.log(2 * math.pi)


def gaussian_kl(
    mean0: torch.Tensor, log_std0: torch.Tensor, mean1: torch.Tensor, log_std1: torch.Tensor
) -> torch.Tensor:
    """Closed-form KL(N0 || N1) between diagonal Gaussians, summed over the last axis.

    Args:
      mean0, mean1: (n, m) means.
      log_std0, log_std1: (m,) or (n, m) log standard deviations.

    Returns:
      (n,) KL divergences [nats].
    """
    var0, var1 = torch.exp(2 * log_std0), torch.exp(2 * log_std1)
    kl = log_std1 - log_std0 + (var0 + (mean0 - mean1) ** 2) / (2 * var1) - 0.5
    return kl.sum(-1)


# ----------------------------------------------------------------------------------------------
# Observation normalisation


# settings that shape how a loaded policy acts (the layers, their non-linearity, the floor of the
# observation std it divides by); the others only set up or clamp training
ACTING_SETTINGS = ("hidden_sizes", "activation", "min_obs_std")


def _saved_config(saved: Any) -> PolicyConfig:
    """The PolicyConfig of a policy file. A file lacking a setting (written by hand or by a
    version without it) loaded with the default silently: refused for a setting that changes how
    the policy acts, a warning naming the default for one that only matters to further training."""
    config = PolicyConfig.from_dict(saved)
    missing = [f for f in asdict(config) if f not in saved]
    acting = [f for f in missing if f in ACTING_SETTINGS]
    if acting:
        raise ConfigError(
            f"policy checkpoint config lacks {', '.join(acting)}, which shape how the policy acts;"
            f" the default ({', '.join(f'{f}={getattr(config, f)!r}' for f in acting)}) may not"
            " be what it was trained with. Add the value it was trained with to the file's "
            "'config' (to_checkpoint() writes every setting)")
    if missing:
        import warnings

        warnings.warn(f"policy checkpoint config lacks {', '.join(missing)}: loaded with the "
                      f"default ({', '.join(f'{f}={getattr(config, f)!r}' for f in missing)}); "
                      "it matters only to further training of this policy", stacklevel=3)
    return config


class ObsNormalizer(nn.Module):
    """Running mean and standard deviation of observations, or fixed statistics.

    Normalises as ``(x - mean) / max(std, min_std)``. Before any data it is the identity.
    Statistics are merged batch by batch (Chan et al.'s parallel variance), so the result
    does not depend on how samples are split into batches, only on the data.

    Buffers (saved in ``state_dict``): ``mean`` (d,), ``var`` (d,), ``count`` (), ``frozen`` ().
    """

    def __init__(self, dim: int, min_std: float = 1e-2, dtype: torch.dtype = torch.float64):
        super().__init__()
        self.min_std = float(min_std)
        self.register_buffer("mean", torch.zeros(dim, dtype=dtype))
        self.register_buffer("var", torch.ones(dim, dtype=dtype))
        self.register_buffer("count", torch.zeros((), dtype=dtype))
        self.register_buffer("frozen", torch.zeros((), dtype=torch.bool))

    @property
    def std(self) -> torch.Tensor:
        """(d,) standard deviation used for normalisation (floored at min_std)."""
        return torch.sqrt(self.var).clamp_min(self.min_std)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) / self.std

    @torch.no_grad()
    def update(self, x: torch.Tensor | np.ndarray) -> None:
        """Merge a batch ``x`` of shape (n, d) into the statistics (no-op when frozen)."""
        if bool(self.frozen):
            return
        x = torch.as_tensor(x, dtype=self.mean.dtype).reshape(-1, self.mean.shape[0])
        n = x.shape[0]
        if n == 0:
            return
        b_mean, b_var = x.mean(0), x.var(0, unbiased=False)
        total = self.count + n
        delta = b_mean - self.mean
        new_mean = self.mean + delta * (n / total)
        m2 = self.var * self.count + b_var * n + delta**2 * (self.count * n / total)
        self.mean.copy_(new_mean)
        self.var.copy_(m2 / total)
        self.count.fill_(total)

    @torch.no_grad()
    def set_stats(self, mean: Any, std: Any, freeze: bool = True, count: float = 1.0) -> None:
        """Set the statistics, e.g. from demonstrations, and optionally freeze them.

        ``count`` is the number of samples they summarise, i.e. their weight when later
        batches are merged in (if not frozen).
        """
        mean_t = torch.as_tensor(np.asarray(mean), dtype=self.mean.dtype)
        std_t = torch.as_tensor(np.asarray(std), dtype=self.mean.dtype)
        self.mean.copy_(mean_t)
        self.var.copy_(std_t**2)
        self.count.fill_(float(count))
        self.frozen.fill_(bool(freeze))


# ----------------------------------------------------------------------------------------------
# The policy


def _activation(name: str) -> nn.Module:
    return nn.Tanh() if name == "tanh" else nn.ReLU()


class GaussianMLPPolicy(nn.Module):
    """Diagonal Gaussian policy with an MLP mean and a state-independent log-std.

    Args:
      obs_dim: observation size.
      act_dim: action size.
      config: architecture and initialisation.
      generator: seeded ``torch.Generator`` for the initial weights. ``None`` leaves the
        weights at zero (only for loading a checkpoint right after).
      dtype: parameter dtype (float64 by default).
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        config: PolicyConfig | None = None,
        generator: torch.Generator | None = None,
        dtype: torch.dtype = torch.float64,
    ):
        super().__init__()
        check_number("obs_dim", obs_dim, 1, integer=True)
        check_number("act_dim", act_dim, 1, integer=True)
        self.config = config or PolicyConfig()
        self.obs_dim, self.act_dim = int(obs_dim), int(act_dim)
        self.obs_norm = ObsNormalizer(obs_dim, self.config.min_obs_std, dtype)
        sizes = (self.obs_dim, *self.config.hidden_sizes, self.act_dim)
        layers: list[nn.Module] = []
        for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
            layers.append(nn.utils.skip_init(nn.Linear, n_in, n_out, dtype=dtype))
            if i < len(sizes) - 2:
                layers.append(_activation(self.config.activation))
        self.mlp = nn.Sequential(*layers)
        self.linears = [m for m in self.mlp if isinstance(m, nn.Linear)]
        self.log_std = nn.Parameter(
            torch.full((self.act_dim,), self.config.init_log_std, dtype=dtype)
        )
        self.register_buffer("act_shift", torch.zeros(self.act_dim, dtype=dtype))
        self.register_buffer("act_scale", torch.ones(self.act_dim, dtype=dtype))
        self._init_weights(generator)
        self.trained_on: str | None = None
        """Gymnasium id of the env the policy was trained on (set by the trainers, saved in its
        checkpoint; None when unknown): a policy of another task with the same sizes would
        otherwise act on an env without a word (``load_policy(path, env=...)`` checks it)."""

    @torch.no_grad()
    def _init_weights(self, generator: torch.Generator | None) -> None:
        for layer in self.linears:
            if generator is None:
                layer.weight.zero_()
                layer.bias.zero_()
                continue
            # nn.Linear.reset_parameters, with the generator passed in.
            nn.init.kaiming_uniform_(layer.weight, a=math.sqrt(5), generator=generator)
            bound = 1 / math.sqrt(layer.in_features)
            nn.init.uniform_(layer.bias, -bound, bound, generator=generator)
        last = self.linears[-1]
        last.weight.mul_(self.config.last_layer_scale)
        last.bias.mul_(self.config.last_layer_scale)

    # -- evaluation ------------------------------------------------------------------------------
    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        """Action mean, (n, act_dim), for observations (n, obs_dim)."""
        return self.mlp(self.obs_norm(obs)) * self.act_scale + self.act_shift

    def log_prob(self, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """(n,) log-likelihood of ``actions`` (n, act_dim) given ``obs`` (n, obs_dim)."""
        return gaussian_log_prob(self(obs), self.log_std, actions)

    @torch.no_grad()
    def act(
        self,
        obs: torch.Tensor | np.ndarray,
        generator: torch.Generator | None = None,
        deterministic: bool = False,
    ) -> torch.Tensor:
        """Actions (n, act_dim) for observations (n, obs_dim).

        ``deterministic=True`` (evaluation mode) returns the mean; otherwise the noise is drawn
        from ``generator``, which is then required.
        """
        obs_t = torch.as_tensor(obs, dtype=self.log_std.dtype)
        if obs_t.ndim not in (1, 2) or obs_t.shape[-1] != self.obs_dim:
            # reshape(-1, obs_dim) would turn an observation of another env with twice the
            # size into two rows of this one's
            raise ValueError(f"observation of shape {tuple(obs_t.shape)}; this policy takes "
                             f"({self.obs_dim},) or (n, {self.obs_dim}) (an env of another "
                             "observation size?)")
        mean = self(obs_t.reshape(-1, self.obs_dim))
        if deterministic:
            return mean
        if not isinstance(generator, torch.Generator):
            raise ValueError("stochastic actions need a seeded torch.Generator, got "
                             f"{generator!r} (or pass deterministic=True)")
        noise = torch.randn(mean.shape, generator=generator, dtype=mean.dtype)
        return mean + torch.exp(self.log_std) * noise

    # -- updates ---------------------------------------------------------------------------------
    @torch.no_grad()
    def clamp_log_std_(self) -> None:
        """Clamp log_std from below at ``config.min_log_std`` (call after every update)."""
        self.log_std.clamp_(min=self.config.min_log_std)

    @torch.no_grad()
    def update_obs_normalizer(self, obs: torch.Tensor | np.ndarray) -> None:
        """Merge ``obs`` (n, obs_dim) into the running statistics, keeping mu(s) unchanged.

        With first-layer weight W and bias b, old statistics (m, s) and new (m', s'):
        ``W' = W diag(s'/s)`` and ``b' = b + W diag(1/s) (m' - m)``, so that
        ``W (x - m)/s + b == W' (x - m')/s' + b'`` for every x. No-op when frozen.
        """
        if bool(self.obs_norm.frozen):
            return
        old_mean, old_std = self.obs_norm.mean.clone(), self.obs_norm.std.clone()
        self.obs_norm.update(obs)
        new_mean, new_std = self.obs_norm.mean, self.obs_norm.std
        first = self.linears[0]
        first.bias.add_(first.weight @ ((new_mean - old_mean) / old_std))
        first.weight.mul_(new_std / old_std)

    # -- persistence ---------------------------------------------------------------------------
    def to_checkpoint(self) -> dict[str, Any]:
        """Everything needed to rebuild the policy: sizes, config and state_dict (safe types)."""
        return {
            "obs_dim": self.obs_dim,
            "act_dim": self.act_dim,
            "config": asdict(self.config),
            "dtype": str(self.log_std.dtype).removeprefix("torch."),
            "state_dict": self.state_dict(),
            "env_id": self.trained_on,  # None: unknown (an env_factory's env without a spec)
        }

    @classmethod
    def from_checkpoint(cls, ckpt: dict[str, Any]) -> GaussianMLPPolicy:
        """Rebuild a policy saved with :meth:`to_checkpoint` (e.g. loaded with weights_only)."""
        if not isinstance(ckpt, dict):
            raise ConfigError(f"a policy checkpoint is a dict (to_checkpoint()), not a "
                              f"{type(ckpt).__name__}")
        check_keys("policy checkpoint entry", ckpt,
                   ("obs_dim", "act_dim", "config", "dtype", "state_dict", "env_id"))
        missing = [k for k in ("obs_dim", "act_dim", "config", "state_dict") if k not in ckpt]
        if missing:
            raise ConfigError(f"policy checkpoint lacks {', '.join(missing)}")
        dtype = getattr(torch, str(ckpt.get("dtype", "float64")), None)
        if dtype not in (torch.float32, torch.float64):
            raise ConfigError(f"policy checkpoint dtype {ckpt.get('dtype')!r}; valid: "
                              "'float32', 'float64'")
        for key in ("obs_dim", "act_dim"):
            check_number(f"policy checkpoint {key}", ckpt[key], 1, integer=True)
        policy = cls(ckpt["obs_dim"], ckpt["act_dim"], _saved_config(ckpt["config"]), None, dtype)
        try:
            policy.load_state_dict(ckpt["state_dict"])
        except (RuntimeError, TypeError, AttributeError) as e:  # sizes or keys of another net
            first = str(e).strip().splitlines()
            detail = " ".join(line.strip() for line in first[1:3]) or first[0]
            raise ConfigError(f"policy checkpoint's weights do not fit its own sizes "
                              f"{ckpt['obs_dim']} -> {tuple(ckpt['config'].get('hidden_sizes', ()))}"
                              f" -> {ckpt['act_dim']}: {detail[:200]}") from None
        if not all(bool(torch.isfinite(t).all()) for t in policy.state_dict().values()
                   if t.is_floating_point()):
            raise ConfigError("policy checkpoint holds NaN/inf weights or statistics")
        env_id = ckpt.get("env_id")
        policy.trained_on = env_id if isinstance(env_id, str) and env_id else None
        return policy

    def snapshot(self) -> PolicySnapshot:
        """A numpy copy for sampling workers (see :class:`PolicySnapshot`)."""
        with torch.no_grad():
            return PolicySnapshot(
                weights=tuple(
                    layer.weight.detach().double().numpy().copy() for layer in self.linears
                ),
                biases=tuple(layer.bias.detach().double().numpy().copy() for layer in self.linears),
                activation=self.config.activation,
                obs_mean=self.obs_norm.mean.double().numpy().copy(),
                obs_std=self.obs_norm.std.double().numpy().copy(),
                act_shift=self.act_shift.double().numpy().copy(),
                act_scale=self.act_scale.double().numpy().copy(),
                std=np.exp(self.log_std.detach().double().numpy()),
            )
