"""DAPG's validation at every late iterate (``TrainConfig.eval_dense_from``, the main job's
``SimTraining.dense_from``). The truth for "evaluating more does not change what is learned" is
a second run of the same config without the dense evaluations; for "the run's policy is the
best evaluated one" it is the metrics file's own evaluations, ranked here by hand."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from pointmass import make_pointmass

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.npg import NPGConfig
from lowcostdex.algos.policy import PolicyConfig
from lowcostdex.algos.train import TrainConfig, train
from lowcostdex.errors import ConfigError
from lowcostdex.main_job.setup import BUDGETS


def _config(**kw):
    base = dict(env_id="test/PointMass", n_iter=8, n_traj=8, gamma=0.98, gae_lambda=0.95,
                eval_every=4, eval_episodes=6, progress=False,
                policy=PolicyConfig(hidden_sizes=(16,), init_log_std=-0.5),
                npg=NPGConfig(step_size=0.05, damping=1e-2))
    base.update(kw)
    return TrainConfig(**base)


def test_dense_evaluations_from_an_iteration_on_and_the_same_learning(tmp_path):
    sparse = train(_config(), tmp_path / "sparse", env_factory=make_pointmass).read_metrics()
    dense_run = train(_config(eval_dense_from=5), tmp_path / "dense", env_factory=make_pointmass)
    dense = dense_run.read_metrics()
    evaluated = [int(k) for k, v in zip(dense["iteration"], dense["eval_success_rate"],
                                        strict=True) if math.isfinite(v)]
    assert evaluated == [3, 5, 6, 7]
    assert [int(k) for k, v in zip(sparse["iteration"], sparse["eval_success_rate"],
                                   strict=True) if math.isfinite(v)] == [3, 7]
    # the training samples, returns and updates do not depend on the extra evaluations
    for key in ("return_mean", "success_rate", "samples", "kl", "grad_norm"):
        np.testing.assert_array_equal(sparse[key], dense[key], err_msg=key)
    # the same evaluations where both evaluated (the same episodes: eval_paired is off, so
    # each evaluation draws its iteration's episodes, identical in both runs)
    for k in (3, 7):
        assert sparse["eval_success_rate"][k] == dense["eval_success_rate"][k]
        assert sparse["eval_return_mean"][k] == dense["eval_return_mean"][k]
    # the run's policy: the best of the evaluated iterates (success, then return), by hand
    rows = [(dense["eval_success_rate"][k], dense["eval_return_mean"][k], -k) for k in evaluated]
    best = max(rows)
    summary = ex.read_json(dense_run.path / ex.SUMMARY_FILE)
    assert summary["best"]["iteration"] == -best[2]
    assert summary["evaluations"] == 4


@pytest.mark.parametrize("value", [-1, 1.5])
def test_bad_dense_from_is_refused(value):
    with pytest.raises(ConfigError, match="eval_dense_from"):
        _config(eval_dense_from=value)


def test_the_main_jobs_budgets_validate_late_iterates_densely():
    sim = BUDGETS["default"].dapg_sim
    assert sim is not None and sim.dense_from is not None
    assert 0 < sim.dense_from < sim.iters
    with pytest.raises(ConfigError, match="dense_from"):
        dataclasses.replace(sim, dense_from=sim.iters)
