"""Careless calls on the Python API (issue 13), session 15.

- A seed sweep written the numpy way, ``for seed in np.arange(3): train(TrainConfig(seed=seed),
  ...)``, or a discount read from a float32 array: before session 15 the config passed validation
  (a numpy integer is an integer) and ``train`` died in ``json.dumps`` with "Object of type int64
  is not JSON serializable". The run now writes the number the scalar holds, and resumes.
- A count given as a float (``n_iter=2.0``, a JSON config's ``1e3``): validation said "must be an
  integer" yet let 2.0 through, and the run died in ``range()`` after its folder was written. Now
  it is refused at construction, in one line naming the field.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from lowcostdex.algos.configs import BCConfig, NPGConfig, TrainConfig
from lowcostdex.algos.local_models.train_config import TVLGTrainConfig
from lowcostdex.algos.train import train
from lowcostdex.errors import ConfigError
from lowcostdex.gap import GapConfig
from lowcostdex.sim.vector import make_vec

POINTMASS = "lowcostdex_test/PointMass-v0"


@pytest.fixture(scope="module", autouse=True)
def _pointmass():
    sys.path.insert(0, str(Path(__file__).parent))
    if POINTMASS not in gym.registry:
        gym.register(POINTMASS, entry_point="pointmass:PointMass", max_episode_steps=30)


def _tiny(**kwargs) -> TrainConfig:
    return TrainConfig(algo="npg", env_id=POINTMASS, n_traj=2, eval_every=1, eval_episodes=1,
                       progress=False, **kwargs)


def test_a_seed_sweep_over_np_arange_writes_plain_numbers_and_resumes(tmp_path):
    for seed in np.arange(2):  # numpy.int64 seeds, as a sweep is often written
        out = tmp_path / f"seed{seed}"
        train(_tiny(seed=seed, n_iter=1, gamma=np.float32(0.99)), out)
        config = json.loads((out / "config.json").read_text())
        assert config["seed"] == int(seed) and isinstance(config["seed"], int)
        assert config["gamma"] == pytest.approx(0.99, abs=1e-7)
    # the same numpy config resumes its run (the file's numbers compare equal to the scalars)
    run = train(_tiny(seed=np.int64(1), n_iter=2, gamma=np.float32(0.99)), tmp_path / "seed1",
                resume=True)
    assert list(run.read_metrics()["iteration"]) == [0, 1]


@pytest.mark.parametrize("make, message", [
    (lambda: TrainConfig(algo="npg", n_iter=2.0), "n_iter=2.0 must be an integer in [1, inf)"),
    (lambda: TrainConfig(algo="npg", n_traj=1e3), "n_traj=1000.0 must be an integer"),
    (lambda: TrainConfig(algo="npg", seed=0.0), "seed=0.0 must be an integer in [0, inf)"),
    (lambda: NPGConfig(cg_iters=10.0), "cg_iters=10.0 must be an integer"),
    (lambda: BCConfig(epochs=5.0), "BC epochs=5.0 must be an integer"),
    (lambda: TVLGTrainConfig(n_iter=3.0), "n_iter=3.0 must be an integer"),
    (lambda: GapConfig(max_effects=3.0), "max_effects=3.0 must be an integer"),
    (lambda: make_vec("lowcostdex/DClawTurnValve-v0", num_envs=2.0),
     "num_envs=2.0 must be an integer"),
], ids=["n_iter", "n_traj", "seed", "cg_iters", "bc_epochs", "tvlg_n_iter", "gap_max_effects",
        "num_envs"])
def test_a_count_given_as_a_float_is_refused_at_construction(make, message):
    with pytest.raises(ConfigError) as exc:
        make()
    assert message in str(exc.value)


def test_a_float_iteration_count_writes_no_run_folder(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(ConfigError, match="n_iter=2.0 must be an integer"):
        train(_tiny(n_iter=2.0), out)
    assert not out.exists()


def test_counts_as_numpy_integers_still_work(tmp_path):
    config = _tiny(n_iter=np.int64(1), seed=np.int32(0))
    assert train(config, tmp_path / "run").read_metrics()["iteration"].tolist() == [0]
