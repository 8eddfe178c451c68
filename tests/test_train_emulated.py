"""NPG and DAPG end to end on the emulated D'Claw (Dynamixel bus, auto-reset, virtual clock),
with demonstrations recorded by the virtual teacher through the kinesthetic recorder."""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.dapg import DAPGConfig
from lowcostdex.algos.policy import PolicyConfig
from lowcostdex.algos.train import TrainConfig, train
from lowcostdex.demonstrations.dataset import load_demos
from lowcostdex.hardware.robot import backend  # noqa: F401  (an import error fails, never skips)

ENV_ID = "lowcostdex/DClawTurnValve-v0"


def _config(**kw):
    base = dict(env_id=ENV_ID, backend="emulated", n_iter=2, n_traj=2, eval_every=1, eval_episodes=1,
                progress=False, policy=PolicyConfig(hidden_sizes=(16, 16), init_log_std=-1.0))  # fmt: skip
    base.update(kw)
    return TrainConfig(**base)


def test_npg_on_the_emulated_robot_counts_resets_in_robot_time(tmp_path):
    run = train(_config(), tmp_path / "npg")
    m = run.read_metrics()
    assert m["samples"].tolist() == [80, 160]
    # 3 episodes per iteration (2 training + 1 evaluation) of 40 x 0.1 s each, plus auto-resets
    control_hours = 3 * 40 * 0.1 / 3600
    assert m["robot_hours"][0] > control_hours * 1.2
    assert np.all(np.diff(m["robot_hours"]) > control_hours)
    assert m["robot_resets"].tolist() == [3, 6] and m["robot_reset_success_rate"][-1] == 1.0
    assert m["robot_max_temperature"][-1] > 20.0
    assert np.isfinite(m["eval_success_rate"]).all()


def test_dapg_with_virtual_teacher_demos_on_the_emulated_robot(tmp_path):
    from lowcostdex.demonstrations.kinesthetic import KinestheticRecorder, VirtualTeacher

    env = gym.make(ENV_ID, backend="emulated")
    teacher = VirtualTeacher(env.unwrapped.backend.chain, env.unwrapped.task)
    recorder = KinestheticRecorder(env, tmp_path / "demos.h5", ENV_ID, teacher=teacher)
    for seed in range(2):
        recorder.record_episode(seed)
    env.close()
    demos = load_demos(tmp_path / "demos.h5")
    assert demos.n_episodes == 2 and demos.observations.shape == (80, 30)
    cfg = _config(
        algo="dapg", demos=str(tmp_path / "demos.h5"), n_iter=1, dapg=DAPGConfig(lam0=0.1),
        eval_bc=True, eval_episodes=2,
    )
    run = train(cfg, tmp_path / "dapg")
    bc = ex.read_json(run.path / "bc.json")
    assert bc["n_episodes"] == 2 and bc["eval_episodes"] == 2
    assert 0.0 <= bc["eval_success_rate"] <= 1.0 and np.isfinite(bc["eval_return_mean"])
    m = run.read_metrics()
    # robot time: 2 BC evaluation + 2 training + 2 final evaluation episodes of 4 s, + resets
    assert m["robot_hours"][0] > 6 * 40 * 0.1 / 3600 and m["robot_resets"][0] == 6
    assert m["demo_weight"][0] > 0 and np.isfinite(m["demo_log_lik"][0])
