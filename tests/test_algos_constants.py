"""NPG/DAPG defaults no other test pinned (``bench/mutate_constants.py --only NPGConfig.
--only DAPGConfig.`` on lowcostdex/algos/configs.py, +1 each, tests/test_npg.py and
tests/test_dapg.py, main 50cb29d): ``NPGConfig.max_backtracks`` 10 -> 11 and ``DAPGConfig.lam0``
0.1 -> 1.1 went unnoticed (the functions' own defaults were pinned, the configs' were not).

Sources: the DAPG paper (Rajeswaran et al. 2018, sec. 4: "For all the experiments, lambda_0 =
0.1 and lambda_1 = 0.95"; hand_dapg's released mjrl config uses 0.01, the "mjrl" mode); the
KL line search of sb3-contrib's TRPO (``line_search_shrinking_factor=0.8``,
``line_search_max_iter=10``) and skrl's TRPO (10 backtracks), /work/shared/reference 02-npg-dapg.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lowcostdex.algos import npg
from lowcostdex.algos.dapg import DAPGConfig, dapg_update
from lowcostdex.algos.policy import GaussianMLPPolicy, PolicyConfig

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _setup(seed=0, n=200, m=50):
    policy = GaussianMLPPolicy(3, 2, PolicyConfig(hidden_sizes=(8,)),
                               torch.Generator().manual_seed(seed))
    g = torch.Generator().manual_seed(seed + 1)
    obs = torch.randn(n, 3, generator=g, dtype=torch.float64)
    actions = policy.act(obs, generator=g)
    adv = torch.randn(n, generator=g, dtype=torch.float64)
    d_obs = torch.randn(m, 3, generator=g, dtype=torch.float64)
    return policy, obs, actions, adv, d_obs, 0.5 * torch.tanh(d_obs[:, :2])


def test_the_default_line_search_tries_the_full_step_then_ten_shrunk_ones():
    # a KL bound nothing meets: 1 + 10 trials at 0.8^j of the step (TRPO's line search), then
    # no step at all
    policy, obs, actions, adv, *_ = _setup()
    before = torch.nn.utils.parameters_to_vector(policy.parameters()).detach().clone()
    stats = npg.npg_update(policy, obs, actions, adv, npg.NPGConfig(max_kl=1e-15))
    assert stats["n_backtracks"] == 11.0 and stats["alpha"] == 0.0
    assert torch.equal(torch.nn.utils.parameters_to_vector(policy.parameters()), before)
    c = npg.NPGConfig()
    assert (c.backtrack_ratio, c.max_backtracks) == (0.8, 10)


def test_the_default_demo_weight_is_the_papers_lambda0_and_lambda1():
    # w_k = 0.1 * 0.95^k * max(whitened advantages) (paper mode, the default)
    weights = []
    for k in (0, 1, 5):
        policy, obs, actions, adv, d_obs, d_act = _setup()
        stats = dapg_update(policy, obs, actions, adv, d_obs, d_act, k, DAPGConfig(),
                            npg.NPGConfig())
        weights.append(stats["demo_weight"])
    white = (adv - adv.mean()) / (adv.std(unbiased=False) + 1e-6)
    np.testing.assert_allclose(weights, [0.1 * 0.95**k * float(white.max()) for k in (0, 1, 5)],
                               rtol=1e-12)
