"""PPO on the batched simulator: the clipped losses against hand-computed values, the reward
scaling against numpy, and a tiny run on the valve (run directory, reproducibility, resume)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.configs import PolicyConfig, PPOConfig
from lowcostdex.algos.ppo import RewardScaler, ppo_losses, train
from lowcostdex.algos.train import load_policy
from lowcostdex.errors import ConfigError


def test_clipped_surrogate_and_value_loss_by_hand():
    old = torch.zeros(2)
    new = torch.log(torch.tensor([1.5, 0.5]))  # ratios 1.5 and 0.5
    adv = torch.tensor([1.0, -1.0])
    out = ppo_losses(new, old, adv, new_v=torch.tensor([1.0, -0.1]), old_v=torch.zeros(2),
                     returns=torch.tensor([2.0, 0.0]), clip_coef=0.2, clip_vloss=True)
    # A = +1, r = 1.5: max(-1.5, -1.2) = -1.2; A = -1, r = 0.5: max(0.5, 0.8) = 0.8
    assert float(out["pg"]) == pytest.approx((-1.2 + 0.8) / 2)
    # V clipped to [-0.2, 0.2] of V_old: max((1-2)^2, (0.2-2)^2) = 3.24; max(0.01, 0.01)
    assert float(out["v"]) == pytest.approx(0.5 * (3.24 + 0.01) / 2)
    kl = ((0.5 - math.log(1.5)) + (-0.5 - math.log(0.5))) / 2
    assert float(out["approx_kl"]) == pytest.approx(kl)
    assert float(out["clipfrac"]) == 1.0
    plain = ppo_losses(new, old, adv, torch.tensor([1.0, -0.1]), torch.zeros(2),
                       torch.tensor([2.0, 0.0]), 0.2, clip_vloss=False)
    assert float(plain["v"]) == pytest.approx(0.5 * (1.0 + 0.01) / 2)


def test_reward_scaler_divides_by_the_std_of_the_discounted_returns():
    rng = np.random.default_rng(0)
    gamma, n, steps = 0.9, 3, 25
    scaler = RewardScaler(gamma)
    returns = np.zeros(n)
    seen, running = [], np.zeros(n)
    for t in range(steps):
        r = rng.normal(size=n)
        alive = np.array([True, True, t < 10])  # the third copy's episode ended early
        scaled = scaler(np.where(alive, r, 0.0), alive, returns)
        running = running * gamma + np.where(alive, r, 0.0)
        seen.extend(running[alive])
        np.testing.assert_allclose(scaled, np.where(alive, r, 0.0) / np.std(seen), rtol=1e-9)


def test_one_update_is_the_ppo_step_written_out():
    """A one-minibatch, one-epoch update equals the PPO step written out here with the public
    pieces: the running normaliser, GAE on the critic's values, the actor's and critic's own
    forward passes, the clipped losses, the global-norm clip and plain Adam (lr, eps 1e-5,
    torch's reference loop); the update normalises once and steps a fused Adam."""
    import copy

    from lowcostdex.algos.ppo import _Agent
    from lowcostdex.algos.returns import gae

    cfg = PPOConfig(num_envs=3, update_epochs=1, num_minibatches=1, n_iter=10, anneal_lr=False,
                    policy=PolicyConfig(hidden_sizes=(8,), init_log_std=-1.0),
                    critic_hidden=(8,), ent_coef=0.5)
    g = torch.Generator().manual_seed(3)
    horizon, n, obs_dim, act_dim = 5, 3, 4, 2
    agent = _Agent(cfg, obs_dim, act_dim)
    obs = torch.randn(horizon, n, obs_dim, generator=g)
    act = torch.randn(horizon, n, act_dim, generator=g)
    with torch.no_grad():
        logp = agent.actor.log_prob(obs.reshape(-1, obs_dim), act.reshape(-1, act_dim))
    roll = {"obs": obs.numpy(), "act": act.numpy(), "logp": logp.reshape(horizon, n).numpy(),
            "rew": torch.randn(horizon, n, generator=g, dtype=torch.float64).numpy(),
            "lengths": np.full(n, horizon), "terminated": np.array([True, False, False]),
            "final_obs": torch.randn(n, obs_dim, generator=g).numpy()}
    ref = copy.deepcopy(agent)
    agent.update(roll, 0)

    actor, critic = ref.actor, ref.critic
    flat_obs = obs.permute(1, 0, 2).reshape(-1, obs_dim)  # episode by episode
    flat_act = act.permute(1, 0, 2).reshape(-1, act_dim)
    actor.update_obs_normalizer(flat_obs)
    with torch.no_grad():
        v = critic(actor.obs_norm(flat_obs)).reshape(n, horizon).double().numpy()
        last = critic(actor.obs_norm(torch.as_tensor(roll["final_obs"]))).double().numpy()
    last[0] = 0.0  # terminated
    adv = np.concatenate([gae(roll["rew"][:, i], v[i], last[i], cfg.gamma, cfg.gae_lambda)
                          for i in range(n)])
    adv_t = torch.as_tensor(adv, dtype=torch.float32)
    v_t = torch.as_tensor(v.reshape(-1), dtype=torch.float32)
    old_logp = logp.reshape(horizon, n).T.reshape(-1)
    params = [*actor.parameters(), *critic.parameters()]
    adam = torch.optim.Adam(params, lr=cfg.lr, eps=1e-5, foreach=False, fused=False)
    losses = ppo_losses(actor.log_prob(flat_obs, flat_act), old_logp,
                        (adv_t - adv_t.mean()) / (adv_t.std() + 1e-8),
                        critic(actor.obs_norm(flat_obs)), v_t, adv_t + v_t, cfg.clip_coef,
                        cfg.clip_vloss)
    entropy = (actor.log_std + 0.5 * math.log(2 * math.pi * math.e)).sum()
    loss = losses["pg"] - cfg.ent_coef * entropy + cfg.vf_coef * losses["v"]
    adam.zero_grad()
    loss.backward()
    torch.nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
    adam.step()
    actor.clamp_log_std_()
    got = torch.nn.utils.parameters_to_vector([*agent.actor.parameters(),
                                               *agent.critic.parameters()]).detach()
    want = torch.nn.utils.parameters_to_vector(params).detach()
    before = torch.nn.utils.parameters_to_vector(
        [*_Agent(cfg, obs_dim, act_dim).actor.parameters(),
         *_Agent(cfg, obs_dim, act_dim).critic.parameters()]).detach()
    assert float((want - before).abs().max()) > 1e-4  # the step moved the parameters
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)


def _config(**kw) -> PPOConfig:
    base = dict(env_id="lowcostdex/DClawTurnValve-v0", n_iter=3, num_envs=4, num_minibatches=2,
                update_epochs=2, eval_every=1, eval_episodes=2, nthread=1, progress=False,
                policy=PolicyConfig(hidden_sizes=(16,), init_log_std=-1.0), critic_hidden=(16,))
    return PPOConfig(**{**base, **kw})


def _metrics(path: Path) -> dict[str, np.ndarray]:
    m = ex.read_metrics(path / ex.METRICS_FILE)
    return {k: v for k, v in m.items() if not k.startswith("time_")}


def test_ppo_run_directory_policy_and_resume(tmp_path):
    cfg = _config()
    run = train(cfg, tmp_path / "full")
    m = run.read_metrics()
    np.testing.assert_array_equal(m[ex.SAMPLES], 4 * 40 * np.arange(1, 4))  # whole episodes
    assert np.all(np.isfinite(m[ex.EVAL_SUCCESS_RATE])) and np.all(m["approx_kl"] >= 0)
    for name in (ex.POLICY_FILE, ex.FINAL_POLICY_FILE, ex.SUMMARY_FILE, ex.CURVES_FILE):
        assert (run.path / name).exists(), name
    policy = load_policy(run.path)  # the NPG/DAPG loader reads a PPO policy
    assert policy.obs_dim == 30 and policy.act_dim == 9
    final = load_policy(run.path / ex.FINAL_POLICY_FILE)
    assert float(final.obs_norm.count) == 3 * 4 * 40  # running statistics of every sample
    best = ex.read_json(run.path / ex.SUMMARY_FILE)["best"]  # policy.pt is the best evaluation
    assert float(policy.obs_norm.count) == (best[ex.ITERATION] + 1) * 4 * 40
    # killed after iteration 1, resumed: the same run as without the interruption
    train(cfg, tmp_path / "cut", stop_after=1)
    assert ex.read_metrics(tmp_path / "cut" / ex.METRICS_FILE)[ex.ITERATION][-1] == 1
    train(cfg, tmp_path / "cut", resume=True)
    a, b = _metrics(tmp_path / "full"), _metrics(tmp_path / "cut")
    assert list(a) == list(b)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    pa = load_policy(tmp_path / "full" / ex.FINAL_POLICY_FILE)
    pb = load_policy(tmp_path / "cut" / ex.FINAL_POLICY_FILE)
    assert torch.equal(torch.nn.utils.parameters_to_vector(pa.parameters()),
                       torch.nn.utils.parameters_to_vector(pb.parameters()))
    # another seed samples other episodes
    train(_config(seed=1), tmp_path / "other")
    assert not np.array_equal(_metrics(tmp_path / "other")[ex.RETURN_MEAN], a[ex.RETURN_MEAN])


def test_ppo_config_validation():
    with pytest.raises(ConfigError, match="num_envs"):
        PPOConfig(num_envs=0)
    with pytest.raises(ConfigError, match="gae_lambda"):
        PPOConfig(gae_lambda=1.5)
    with pytest.raises(ConfigError, match="target_kl"):
        PPOConfig(target_kl=0.0)


@pytest.mark.slow
def test_ppo_learns_the_valve():
    """~4 min: the default PPO turns the valve in most training episodes within 300k samples."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        cfg = PPOConfig(n_iter=240, progress=False, eval_every=10)
        m = train(cfg, tmp).read_metrics()
    assert m[ex.SUCCESS_RATE][-20:].mean() >= 0.6
    assert np.nanmax(m[ex.EVAL_SUCCESS_RATE]) == 1.0
