"""careless14: a sampler's numpy policy copy fed an observation of the wrong size."""

import numpy as np
import pytest

from lowcostdex.algos.snapshot import PolicySnapshot


def _snapshot(obs_dim: int = 3, act_dim: int = 2) -> PolicySnapshot:
    # a one-layer linear policy written out here: mean = W (x - m) / s + b
    return PolicySnapshot(
        weights=(np.ones((act_dim, obs_dim)),), biases=(np.zeros(act_dim),), activation="tanh",
        obs_mean=np.zeros(obs_dim), obs_std=np.ones(obs_dim), act_shift=np.zeros(act_dim),
        act_scale=np.ones(act_dim), std=np.ones(act_dim))


@pytest.mark.parametrize("obs", [np.zeros(5), np.zeros(1), np.zeros((2, 3))])
def test_wrong_size_observation_names_both_sizes(obs):
    with pytest.raises(ValueError, match=r"this policy takes \(3,\)"):
        _snapshot().act(obs, None)


def test_right_size_still_works():
    np.testing.assert_allclose(_snapshot().act([1.0, 2.0, 3.0], None), [6.0, 6.0])
    np.testing.assert_allclose(_snapshot().act(np.ones((1, 3)), np.ones(2)), [4.0, 4.0])
