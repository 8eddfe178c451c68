"""Proximal policy optimisation (PPO-clip, Schulman et al. 2017) on the batched simulator.

The massively parallel baseline: many copies of a task stepped together by ``mujoco.batch``
(:class:`~lowcostdex.sim.vector.HandVectorEnv`), a clipped surrogate optimised by minibatch Adam.
Implementation choices follow cleanrl's ``ppo_continuous_action`` (orthogonal initialisation,
separate actor and critic MLPs, state-independent log-std, GAE, per-minibatch advantage
normalisation, clipped value loss, global gradient-norm clipping, linearly annealed learning rate,
Adam eps 1e-5, running observation normalisation, reward scaling by a running std of the
discounted return); differences, each for this project:

- one iteration = ``num_envs`` whole episodes, every copy reset at the start with a seed derived
  from (seed, iteration, copy): no episode spans two iterations, so a run resumed from its last
  checkpoint reproduces the uninterrupted one, and truncated episodes are bootstrapped with
  V(s_T) of their final observation (terminated ones with 0; :func:`~lowcostdex.algos.returns.gae`);
- the actor is a :class:`~lowcostdex.algos.policy.GaussianMLPPolicy` (float32) whose own
  observation normaliser is the running one, so ``policy.pt`` loads with
  :func:`lowcostdex.algos.train.load_policy` and runs wherever NPG/DAPG policies run (robots, the
  main job, evaluations); the critic reads the same normalised observations;
- the learning rate is 1e-3, not 3e-4: on the valve's 40-step episodes it reaches 80 % training
  success in less than half the samples (:class:`~lowcostdex.algos.configs.PPOConfig`);
- the initial exploration noise is a config value (-1.0 log-std by default, as for NPG: see
  :class:`~lowcostdex.algos.configs.TrainConfig`), not cleanrl's std 1;
- the run directory, metrics, best-policy tracking and summary are the other trainers'
  (:mod:`lowcostdex.algos.experiment`).

Samples count the env steps of training episodes; evaluation episodes (mean action, a separate
batched env) are not counted.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.configs import PPOConfig
from lowcostdex.algos.policy import GaussianMLPPolicy, ObsNormalizer, gaussian_log_prob
from lowcostdex.algos.returns import gae
from lowcostdex.algos.train import check_env_id, seed_generator

__all__ = ["PPOConfig", "Critic", "RewardScaler", "make_actor", "ppo_losses", "train"]

MUTABLE_ON_RESUME = ("n_iter", "progress", "torch_threads", "nthread")
# Seed-sequence purposes (first spawn-key entry).
_INIT, _ROLLOUT, _EVAL, _UPDATE = 20, 21, 22, 23


# ----------------------------------------------------------------------------------------------
# Pure pieces


def ppo_losses(new_logp: torch.Tensor, old_logp: torch.Tensor, adv: torch.Tensor,
               new_v: torch.Tensor, old_v: torch.Tensor, returns: torch.Tensor,
               clip_coef: float, clip_vloss: bool) -> dict[str, torch.Tensor]:
    """The PPO-clip losses of one minibatch (all tensors (n,)).

    ``pg = mean(max(-A r, -A clip(r, 1 - eps, 1 + eps)))`` with ``r = exp(new_logp - old_logp)``
    (the clipped surrogate, to minimise); ``v = 0.5 mean(max((V - R)^2, (V_clip - R)^2))`` with
    ``V_clip = V_old + clip(V - V_old, -eps, eps)`` when ``clip_vloss`` (else the plain squared
    error); diagnostics ``approx_kl = mean((r - 1) - log r)`` (an unbiased KL(old || new)
    estimate) and ``clipfrac`` (share of samples with |r - 1| > eps).
    """
    log_ratio = new_logp - old_logp
    ratio = torch.exp(log_ratio)
    pg = torch.max(-adv * ratio, -adv * torch.clamp(ratio, 1 - clip_coef, 1 + clip_coef)).mean()
    if clip_vloss:
        v_clipped = old_v + torch.clamp(new_v - old_v, -clip_coef, clip_coef)
        v_loss = 0.5 * torch.max((new_v - returns) ** 2, (v_clipped - returns) ** 2).mean()
    else:
        v_loss = 0.5 * ((new_v - returns) ** 2).mean()
    with torch.no_grad():
        approx_kl = ((ratio - 1) - log_ratio).mean()
        clipfrac = ((ratio - 1.0).abs() > clip_coef).float().mean()
    return {"pg": pg, "v": v_loss, "approx_kl": approx_kl, "clipfrac": clipfrac}


class RewardScaler:
    """Scales rewards by a running std of each copy's discounted return (cleanrl's
    NormalizeReward): the critic's targets stay O(1) whatever the task's reward scale.

    The statistics are an :class:`~lowcostdex.algos.policy.ObsNormalizer` of dimension 1
    (saved in the checkpoint); ``returns`` (n,) is the per-copy discounted return of the
    current episodes, reset at each iteration.
    """

    def __init__(self, gamma: float):
        self.gamma = gamma
        self.stats = ObsNormalizer(1, min_std=1e-4)

    def __call__(self, rewards: np.ndarray, alive: np.ndarray, returns: np.ndarray) -> np.ndarray:
        """Update with one step of ``rewards`` (n,) of the copies still ``alive`` and return the
        scaled rewards; ``returns`` is updated in place."""
        returns[:] = returns * self.gamma + rewards
        if alive.any():
            self.stats.update(returns[alive, None])
        return rewards / float(self.stats.std[0])


def _orthogonal_(layer: nn.Linear, gain: float, generator: torch.Generator) -> None:
    """Orthogonal weights scaled by ``gain`` (drawn from ``generator``), zero bias."""
    with torch.no_grad():
        rows, cols = layer.weight.shape
        a = torch.randn(max(rows, cols), min(rows, cols), generator=generator,
                        dtype=layer.weight.dtype)
        q, r = torch.linalg.qr(a)
        q = q * torch.sign(torch.diagonal(r))
        layer.weight.copy_(gain * (q if rows >= cols else q.T))
        layer.bias.zero_()


def make_actor(obs_dim: int, act_dim: int, config: PPOConfig, generator: torch.Generator
               ) -> GaussianMLPPolicy:
    """The actor: a float32 GaussianMLPPolicy, hidden layers orthogonal with gain sqrt(2), the
    output layer with gain 0.01 (cleanrl), log-std ``config.policy.init_log_std``."""
    actor = GaussianMLPPolicy(obs_dim, act_dim, config.policy, generator, dtype=torch.float32)
    for i, layer in enumerate(actor.linears):
        _orthogonal_(layer, 0.01 if i == len(actor.linears) - 1 else math.sqrt(2), generator)
    return actor


class Critic(nn.Module):
    """V(s): a tanh MLP on normalised observations, orthogonally initialised (output gain 1)."""

    def __init__(self, obs_dim: int, hidden: tuple[int, ...], generator: torch.Generator):
        super().__init__()
        sizes = (obs_dim, *hidden, 1)
        layers: list[nn.Module] = []
        for i, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
            layer = nn.Linear(n_in, n_out)
            _orthogonal_(layer, math.sqrt(2) if i < len(sizes) - 2 else 1.0, generator)
            layers.append(layer)
            if i < len(sizes) - 2:
                layers.append(nn.Tanh())
        self.net = nn.Sequential(*layers)

    def forward(self, obs_normalized: torch.Tensor) -> torch.Tensor:
        """(n,) values for normalised observations (n, obs_dim)."""
        return self.net(obs_normalized)[:, 0]


# ----------------------------------------------------------------------------------------------
# The agent


class _Agent:
    def __init__(self, config: PPOConfig, obs_dim: int, act_dim: int):
        self.config = c = config
        gen = seed_generator(c.seed, _INIT)
        self.actor = make_actor(obs_dim, act_dim, c, gen)
        self.actor.trained_on = c.env_id  # saved with it: load_policy(path, env=...) checks it
        self.critic = Critic(obs_dim, c.critic_hidden, gen)
        self.params = [*self.actor.parameters(), *self.critic.parameters()]
        # fused: one kernel per step for all 14 tensors instead of ~10 small ops per tensor
        # (the update's CPU time -20 % on the valve's 80 minibatch steps; same algorithm,
        # different rounding)
        self.optimizer = torch.optim.Adam(self.params, lr=c.lr, eps=1e-5, fused=True)
        self.rewards = RewardScaler(c.gamma)
        self.samples = 0
        self.wall_seconds = 0.0

    def state(self, best: ex.BestPolicy) -> dict[str, Any]:
        return {"actor": self.actor.to_checkpoint(), "critic": self.critic.state_dict(),
                "optimizer": self.optimizer.state_dict(),
                "reward_stats": self.rewards.stats.state_dict(),
                "counters": {"samples": self.samples, "wall_seconds": self.wall_seconds},
                "best": best.state()}

    def load(self, state: Mapping[str, Any], best: ex.BestPolicy) -> None:
        self.actor.load_state_dict(state["actor"]["state_dict"])
        self.critic.load_state_dict(state["critic"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.rewards.stats.load_state_dict(state["reward_stats"])
        self.samples = int(state["counters"]["samples"])
        self.wall_seconds = float(state["counters"]["wall_seconds"])
        best.load_state(state.get("best"))

    def values(self, obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self.critic(self.actor.obs_norm(torch.as_tensor(obs))).numpy()

    @torch.no_grad()
    def rollout(self, env: Any, k: int) -> dict[str, Any]:
        """``num_envs`` whole episodes of the stochastic policy (iteration ``k``'s seeds)."""
        c = self.config
        n, horizon = c.num_envs, env.episode_steps
        seeds = np.random.SeedSequence(c.seed, spawn_key=(_ROLLOUT, k)).generate_state(n)
        obs, _ = env.reset(seed=[int(s) for s in seeds])
        gen = seed_generator(c.seed, _ROLLOUT, k)
        obs_dim, act_dim = obs.shape[1], self.actor.act_dim
        out = {"obs": np.zeros((horizon, n, obs_dim), np.float32),
               "act": np.zeros((horizon, n, act_dim), np.float32),
               "logp": np.zeros((horizon, n), np.float32), "rew": np.zeros((horizon, n)),
               "raw": np.zeros((horizon, n)), "lengths": np.full(n, horizon),
               "terminated": np.zeros(n, bool), "success": np.zeros(n, bool),
               "final_obs": np.zeros((n, obs_dim), np.float32)}
        alive, returns = np.ones(n, bool), np.zeros(n)
        std = torch.exp(self.actor.log_std)
        for t in range(horizon):
            o = torch.as_tensor(obs, dtype=torch.float32)
            mean = self.actor(o)
            a = mean + std * torch.randn(mean.shape, generator=gen)
            out["obs"][t], out["act"][t] = obs, a.numpy()
            out["logp"][t] = gaussian_log_prob(mean, self.actor.log_std, a).numpy()
            obs, r, term, trunc, info = env.step(np.clip(a.numpy(), -1.0, 1.0))
            r = np.where(alive, r, 0.0)
            out["raw"][t] = r
            out["rew"][t] = self.rewards(r, alive, returns) if c.reward_norm else r
            ended = alive & (term | trunc)
            out["lengths"][ended] = t + 1
            out["terminated"][ended] = term[ended]
            out["success"][ended] = np.asarray(info["success"])[ended]
            out["final_obs"][ended] = obs[ended]
            alive &= ~ended
            if not alive.any():
                break
        return out

    def update(self, roll: Mapping[str, Any], k: int) -> dict[str, float]:
        """Advantages, then ``update_epochs`` passes of minibatch Adam on the PPO loss."""
        c = self.config
        horizon, n = roll["rew"].shape
        lengths = roll["lengths"]
        valid = np.arange(horizon)[:, None] < lengths[None, :]
        self.actor.update_obs_normalizer(roll["obs"][valid])
        values = self.values(roll["obs"].reshape(horizon * n, -1)).reshape(horizon, n)
        last = np.where(roll["terminated"], 0.0, self.values(roll["final_obs"]))
        adv = np.zeros((horizon, n))
        for i in range(n):  # one GAE per episode (whole episodes, t = 0 .. length - 1)
            steps = int(lengths[i])
            adv[:steps, i] = gae(roll["rew"][:steps, i], values[:steps, i], float(last[i]),
                                 c.gamma, c.gae_lambda)
        b_obs = torch.as_tensor(roll["obs"][valid])
        with torch.no_grad():  # the statistics are fixed during the update: normalise once
            b_norm = self.actor.obs_norm(b_obs)
        b_act = torch.as_tensor(roll["act"][valid])
        b_logp = torch.as_tensor(roll["logp"][valid])
        b_adv = torch.as_tensor(adv[valid], dtype=torch.float32)
        b_val = torch.as_tensor(values[valid], dtype=torch.float32)
        b_ret = b_adv + b_val
        size = b_norm.shape[0]
        batch = max(1, size // c.num_minibatches)
        if c.anneal_lr:
            for group in self.optimizer.param_groups:
                group["lr"] = c.lr * (1.0 - k / c.n_iter)
        gen = seed_generator(c.seed, _UPDATE, k)
        logs: dict[str, list[torch.Tensor]] = {"pg": [], "v": [], "approx_kl": [], "clipfrac": []}
        actor = self.actor
        for _ in range(c.update_epochs):
            perm = torch.randperm(size, generator=gen)
            for start in range(0, size, batch):
                idx = perm[start:start + batch]
                x = b_norm[idx]
                mean = actor.mlp(x) * actor.act_scale + actor.act_shift  # actor(b_obs[idx])
                new_logp = gaussian_log_prob(mean, actor.log_std, b_act[idx])
                a = b_adv[idx]
                if c.norm_adv and a.numel() > 1:
                    a = (a - a.mean()) / (a.std() + 1e-8)
                new_v = self.critic(x)
                losses = ppo_losses(new_logp, b_logp[idx], a, new_v, b_val[idx], b_ret[idx],
                                    c.clip_coef, c.clip_vloss)
                loss = losses["pg"] + c.vf_coef * losses["v"]
                if c.ent_coef:
                    entropy = (actor.log_std + 0.5 * math.log(2 * math.pi * math.e)).sum()
                    loss = loss - c.ent_coef * entropy
                self.optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(self.params, c.max_grad_norm)
                self.optimizer.step()
                actor.clamp_log_std_()
                for key in logs:
                    logs[key].append(losses[key].detach())
            if c.target_kl is not None and float(logs["approx_kl"][-1]) > c.target_kl:
                break
        means = {key: float(torch.stack(v).double().mean()) for key, v in logs.items()}
        y, y_hat = (b_ret.numpy(), b_val.numpy())
        return {"pg_loss": means["pg"], "v_loss": means["v"], "approx_kl": means["approx_kl"],
                "clipfrac": means["clipfrac"],
                "explained_variance": float(1.0 - np.var(y - y_hat) / (np.var(y) + 1e-12))}

    @torch.no_grad()
    def evaluate(self, env: Any, k: int) -> dict[str, float]:
        """Mean-action episodes, one per copy of ``env`` (seeds from iteration ``k``)."""
        c = self.config
        seeds = np.random.SeedSequence(c.seed, spawn_key=(_EVAL, k)).generate_state(env.num_envs)
        obs, _ = env.reset(seed=[int(s) for s in seeds])
        alive = np.ones(env.num_envs, bool)
        success, total = np.zeros(env.num_envs, bool), np.zeros(env.num_envs)
        for _ in range(env.episode_steps):
            a = self.actor(torch.as_tensor(obs, dtype=torch.float32)).numpy()
            obs, r, term, trunc, info = env.step(np.clip(a, -1.0, 1.0))
            total += np.where(alive, r, 0.0)
            ended = alive & (term | trunc)
            success[ended] = np.asarray(info["success"])[ended]
            alive &= ~ended
            if not alive.any():
                break
        return {ex.EVAL_SUCCESS_RATE: float(success.mean()),
                ex.EVAL_RETURN_MEAN: float(total.mean())}


# ----------------------------------------------------------------------------------------------
# Training run


def train(config: PPOConfig, out_dir: str | Path, resume: bool = False,
          stop_after: int | None = None,
          until: Callable[[Mapping[str, float]], bool] | None = None) -> ex.Run:
    """Train PPO, writing the run directory ``out_dir``; returns the (closed) Run.

    Args:
      config: the run.
      out_dir: run directory (:mod:`lowcostdex.algos.experiment`).
      resume: continue from the last checkpoint in ``out_dir``.
      stop_after: stop after this iteration as if killed (tests of resume).
      until: called with each iteration's metrics; True makes it the last iteration.
    """
    from lowcostdex.progress import bar as progress_bar
    from lowcostdex.sim.vector import make_vec

    c = config
    ex.Run.check(out_dir, dataclasses.asdict(c), resume=resume, mutable_keys=MUTABLE_ON_RESUME)
    check_env_id(c.env_id)
    run: ex.Run | None = None
    env = eval_env = None
    threads = torch.get_num_threads()
    try:
        # everything is validated before the run directory is written
        env = make_vec(c.env_id, c.num_envs, nthread=c.nthread, **dict(c.env_kwargs))
        eval_env = make_vec(c.env_id, c.eval_episodes, nthread=c.nthread, **dict(c.env_kwargs))
        run = ex.Run.open(out_dir, dataclasses.asdict(c), resume=resume,
                          mutable_keys=MUTABLE_ON_RESUME)
        torch.set_num_threads(c.torch_threads)
        agent = _Agent(c, env.single_observation_space.shape[0],
                       env.single_action_space.shape[0])
        best = ex.BestPolicy(run)
        period = float(env.control_period)
        start = 0
        ckpt = (run.load_latest(required=("actor", "critic", "optimizer", "reward_stats",
                                          "counters")) if resume else None)
        if ckpt is not None:
            agent.load(ckpt.state, best)
            start = ckpt.iteration + 1
        bar = progress_bar(total=c.n_iter, initial=start, disable=not c.progress,
                           desc=f"ppo {c.env_id}", unit="it")
        for k in range(start, c.n_iter):
            t0 = time.perf_counter()
            roll = agent.rollout(env, k)
            t1 = time.perf_counter()
            stats = agent.update(roll, k)
            t2 = time.perf_counter()
            agent.samples += int(roll["lengths"].sum())
            row: dict[str, Any] = {
                ex.ITERATION: k, ex.SAMPLES: agent.samples,
                ex.ROBOT_HOURS: agent.samples * period / 3600,
                ex.SUCCESS_RATE: float(roll["success"].mean()),
                ex.RETURN_MEAN: float(roll["raw"].sum(0).mean()),
                "policy_std_mean": float(torch.exp(agent.actor.log_std.detach()).mean()), **stats}
            final = k == c.n_iter - 1 or (until is not None and until(dict(row)))
            row.update({ex.EVAL_SUCCESS_RATE: math.nan, ex.EVAL_RETURN_MEAN: math.nan})
            if final or (c.eval_every > 0 and (k + 1) % c.eval_every == 0):
                row.update(agent.evaluate(eval_env, k))
                best.consider(k, row, {"policy": agent.actor.to_checkpoint()})
            agent.wall_seconds += time.perf_counter() - t0
            row.update({"time_sampling": t1 - t0, "time_update": t2 - t1,
                        "time_eval": time.perf_counter() - t2,
                        ex.WALL_SECONDS: agent.wall_seconds})
            run.log(row)
            if final or (k + 1) % c.checkpoint_every == 0 or k == stop_after:
                run.save_checkpoint(k, agent.state(best))
            else:  # saved if Ctrl-C comes before the next checkpoint
                run.keep_for_interrupt(k, agent.state(best))
            bar.update(1)
            bar.set_postfix(samples=agent.samples, success=f"{row[ex.SUCCESS_RATE]:.2f}")
            if final or k == stop_after:
                break
        bar.close()
        run.plot_learning_curves(f"PPO on {c.env_id} (seed {c.seed})")
        best.finish({"policy": agent.actor.to_checkpoint()})
        run.write_json(ex.SUMMARY_FILE, ex.run_summary(run.read_metrics(), best.record,
                                                       wall_seconds=agent.wall_seconds))
    except BaseException as exc:  # Ctrl-C saves; a start without checkpoint is undone
        stopped = ex.stopped(run, exc, resume)
        if stopped is exc:
            raise
        raise stopped from None
    finally:
        torch.set_num_threads(threads)
        for e in (env, eval_env):
            if e is not None:
                e.close()
        if run is not None:
            run.close()
    return run
