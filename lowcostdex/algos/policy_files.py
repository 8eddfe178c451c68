"""Loading a trained policy from what a user has of a run: the run folder (its ``policy.pt``,
the best evaluated policy), ``final_policy.pt``, a checkpoint of ``train npg|dapg`` or of
``train ppo`` (whose policy is its actor); anything else (a TVLG run, a checkpoint folder, a
bare ``state_dict``, another file) is refused saying what to give instead."""

from __future__ import annotations

import errno
import json
from pathlib import Path
from typing import Any

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.policy import GaussianMLPPolicy
from lowcostdex.errors import ConfigError, InputError
from lowcostdex.outdir import user_path


def load_policy(path: str | Path, env: str | Any | None = None) -> GaussianMLPPolicy:
    """Load the policy of a run directory (``policy.pt``: the best evaluated policy of the run,
    see :class:`~lowcostdex.algos.experiment.BestPolicy`) or of a checkpoint file.

    Args:
      path: the run folder or a policy/checkpoint file.
      env: the env the policy is about to act on (a gymnasium id or an env): a policy trained on
        another env (its ``trained_on``: saved in the file, or for files saved before that, the
        run's ``config.json``) or of other observation/action sizes is refused naming both.
        None loads it for any env (run it across tasks on purpose).
    """
    path = user_path(path)
    file = path / "policy.pt" if path.is_dir() else path
    controller = path / "controller.npz" if path.is_dir() else path
    if controller.is_file() and (controller.suffix == ".npz" or not file.is_file()):
        raise InputError(f"{controller} is a TVLG run's controller (time-varying linear, not a "
                         "neural policy): load it with lowcostdex.algos.local_models.train."
                         f"load_controller({str(controller.parent)!r})")
    saved = sorted(path.glob("ckpt_*.pt")) if path.is_dir() and not file.is_file() else []
    if saved:  # a run's checkpoints/ folder
        raise InputError(f"{path} is a run's checkpoint folder: give the run folder "
                         f"{str(path.parent)!r} (its policy.pt, the best evaluated policy) or "
                         f"one checkpoint file, e.g. {str(saved[-1])!r} (the newest)")
    if not file.is_file():
        raise FileNotFoundError(errno.ENOENT, "no policy here (a run directory holds policy.pt)"
                                if path.is_dir() else "no such policy file", str(file))
    state, why = ex.try_load(file, ())
    if state is None:
        raise InputError(f"{file}: {why}")
    key = "policy" if "policy" in state else "actor"  # a `train ppo` checkpoint: its actor
    if key not in state:
        keys = sorted(map(str, state))
        bare = bool(keys) and all(hasattr(v, "shape") for v in state.values())
        raise InputError(
            f"{file}: lacks policy (its keys: {', '.join(keys[:5])}"
            f"{', ...' if len(keys) > 5 else ''}); "
            + ("a bare state_dict has no sizes or settings to build the policy from: save "
               "{'policy': policy.to_checkpoint()} instead" if bare else
               "a policy file (policy.pt, a run's checkpoints) holds 'policy'"))
    try:
        policy = GaussianMLPPolicy.from_checkpoint(state[key])
    except ConfigError as e:
        raise InputError(f"{file}: {e}") from None
    if "env_id" not in state[key]:  # a file saved before policies recorded their env
        policy.trained_on = _run_env_id(file)
    if env is not None:
        check_policy_env(policy, file, env)
    return policy


def _run_env_id(file: Path) -> str | None:
    """The ``env_id`` of the run ``file`` belongs to (its ``config.json``, beside it or one
    folder up for ``checkpoints/``), or None."""
    for folder in (file.parent, file.parent.parent):
        try:
            config = json.loads((folder / ex.CONFIG_FILE).read_text())
        except (OSError, ValueError):
            continue
        env_id = config.get("env_id") if isinstance(config, dict) else None
        if isinstance(env_id, str) and env_id:
            return env_id
    return None


def check_policy_env(policy: GaussianMLPPolicy, file: str | Path, env: str | Any) -> None:
    """Refuse ``policy`` (read from ``file``) for ``env`` (a gymnasium id or an env) when it was
    trained on another env or its sizes differ; the message says what to load instead."""
    import numpy as np

    spec = getattr(getattr(env, "unwrapped", env), "spec", None) or getattr(env, "spec", None)
    ours = env if isinstance(env, str) else getattr(spec, "id", None)
    theirs = policy.trained_on
    if theirs and ours and theirs != ours:
        raise InputError(f"{file}: a policy trained on {theirs}, not on {ours} (the env it "
                         f"would act on): load a run trained on {ours} (lowcostdex train ... "
                         f"--env {ours}), or give env={theirs!r}; env=None runs it on any env "
                         "on purpose")
    if not isinstance(env, str):
        sizes = tuple(int(np.prod(getattr(env, space).shape))
                      for space in ("observation_space", "action_space"))
        if sizes != (policy.obs_dim, policy.act_dim):
            raise InputError(f"{file}: a policy of observation/action sizes {policy.obs_dim}/"
                             f"{policy.act_dim}; {ours or 'the env'} has {sizes[0]}/{sizes[1]}: "
                             f"load a policy trained on {ours or 'this env'}")
