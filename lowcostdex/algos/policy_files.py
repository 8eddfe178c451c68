"""Loading a trained policy from what a user has of a run: the run folder (its ``policy.pt``,
the best evaluated policy), ``final_policy.pt``, a checkpoint of ``train npg|dapg`` or of
``train ppo`` (whose policy is its actor); anything else (a TVLG run, a checkpoint folder, a
bare ``state_dict``, another file) is refused saying what to give instead."""

from __future__ import annotations

import errno
from pathlib import Path

from lowcostdex.algos import experiment as ex
from lowcostdex.algos.policy import GaussianMLPPolicy
from lowcostdex.errors import ConfigError, InputError
from lowcostdex.outdir import user_path


def load_policy(path: str | Path) -> GaussianMLPPolicy:
    """Load the policy of a run directory (``policy.pt``: the best evaluated policy of the run,
    see :class:`~lowcostdex.algos.experiment.BestPolicy`) or of a checkpoint file."""
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
        return GaussianMLPPolicy.from_checkpoint(state[key])
    except ConfigError as e:
        raise InputError(f"{file}: {e}") from None
