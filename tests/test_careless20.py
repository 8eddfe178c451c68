"""Careless calls, session 23: a policy trained for another task handed to the main job or to
``lowcostdex transfer`` (policy files carry their env since 287f516, but these two loaded them
without asking, and ran the valve with a screw policy, or crashed on a shape, mid-run)."""

from __future__ import annotations

import pytest

from lowcostdex.errors import InputError

VALVE, SCREW = "lowcostdex/DClawTurnValve-v0", "lowcostdex/DClawScrew-v0"


def _screw_policy(path, obs_dim=30, act_dim=9):  # the valve's sizes: it would run silently
    import torch

    from lowcostdex.algos.policy import GaussianMLPPolicy
    from lowcostdex.algos.run_files import save_state

    policy = GaussianMLPPolicy(obs_dim, act_dim, generator=torch.Generator().manual_seed(0))
    policy.trained_on = SCREW
    path.parent.mkdir(parents=True, exist_ok=True)
    save_state(path, {"policy": policy.to_checkpoint()})
    return path


def test_transfer_evaluation_refuses_a_run_whose_policy_was_trained_on_another_task(tmp_path):
    # before: evaluate() loaded it for any env and rolled it out on the valve
    from lowcostdex.transfer.config import TASKS
    from lowcostdex.transfer.training import evaluate

    run = tmp_path / "nominal_A_seed0"
    _screw_policy(run / "policy.pt")
    with pytest.raises(InputError, match=rf"trained on {SCREW}, not on {VALVE}"):
        evaluate(run, TASKS["valve"], {}, episodes=1)


def test_main_job_held_out_stage_refuses_policies_trained_on_another_task(tmp_path):
    # before: the held-out stage loaded train_dapg/train_npg's files for any env
    from lowcostdex.main_job.setup import Context
    from lowcostdex.main_job.stages import _heldout

    ctx = Context(out=tmp_path)
    assert ctx.setup.env_id == VALVE
    dapg = _screw_policy(tmp_path / "train_dapg" / "policy.pt")
    _screw_policy(tmp_path / "train_npg" / "policy.pt")
    from lowcostdex.algos import experiment as ex
    _screw_policy(tmp_path / "train_dapg" / ex.BC_POLICY_FILE)
    with pytest.raises(InputError, match=rf"trained on {SCREW}, not on {VALVE}"):
        _heldout(ctx, 1, dapg)
