"""``lowcostdex train npg|dapg|ppo``: arguments and their TrainConfig / PPOConfig.

Building the parser imports no torch (the defaults come from :mod:`lowcostdex.algos.configs`),
so ``lowcostdex --help`` and every other subcommand start fast; the handler imports the
trainer (:mod:`lowcostdex.algos.train`) when a run starts.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import re
import shlex
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from lowcostdex.algos.configs import (
    BACKENDS,
    BC_LOG_STD,
    DEMO_WEIGHTS,
    DAPGConfig,
    PPOConfig,
    TrainConfig,
)
from lowcostdex.algos.samplers import SAMPLERS
from lowcostdex.argtypes import width
from lowcostdex.errors import ConfigError
from lowcostdex.options import add_latency_option, env_id, latency_kwargs, robot_selection

GAMMA_HELP = "discount per control step, 0-1 (default %(default)s)"
LAMBDA_HELP = "GAE's lambda, 0-1 (default %(default)s)"
LOG_STD_HELP = ("the policy's initial log standard deviation, in the natural log of action "
                "units (actions span [-1, 1]; default %(default)s)")


def add_train_commands(train_subparsers: argparse._SubParsersAction) -> None:
    """Add ``npg`` and ``dapg`` to the ``lowcostdex train`` group."""
    for algo, help_text in (
        ("npg", "natural policy gradient (truncated NPG)"),
        ("dapg", "demo-augmented policy gradient (BC, then NPG with a decaying demo term)"),
    ):
        p = train_subparsers.add_parser(algo, help=help_text, description=help_text)
        _add_arguments(p, algo)
        p.set_defaults(func=_run_command, algo=algo, parser=p)
    p = train_subparsers.add_parser(
        "ppo", help="PPO on the batched simulator (the massively parallel baseline)",
        description="PPO-clip on many copies of a sim task stepped together by mujoco.batch")
    _add_ppo_arguments(p)
    p.set_defaults(func=_run_ppo, parser=p)


def _add_arguments(p: argparse.ArgumentParser, algo: str) -> None:
    d = TrainConfig()
    p.add_argument("--env", type=env_id, default=d.env_id,
                   help="gymnasium id (default %(default)s; the lowcostdex/ prefix may be left out)")
    p.add_argument("--backend", choices=BACKENDS, default=d.backend,
                   help="where episodes run: MuJoCo, the emulated or the real robot (default %(default)s)")
    p.add_argument("--port", default=None, help="serial port of a real robot (hardware backend)")
    add_latency_option(p)
    p.add_argument(
        "--demos", default=None, required=algo == "dapg",
        help="demonstration dataset (HDF5, lowcostdex.demonstrations.file); its successful episodes are used",
    )
    p.add_argument("--n-demos", type=int, default=None, help="use the first N demo episodes")
    p.add_argument("--seed", type=int, default=d.seed, help="run seed (default %(default)s)")
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument(
        "--resume", action="store_true", help="continue the run in --out from its last checkpoint"
    )
    p.add_argument("--n-iter", type=int, default=d.n_iter, help="training iterations (default %(default)s)")
    p.add_argument("--n-traj", type=int, default=d.n_traj, help="trajectories per iteration")
    p.add_argument("--sampler", choices=SAMPLERS, default=d.sampler,
                   help="how trajectories are collected (--workers processes) (default %(default)s)")
    p.add_argument("--workers", type=int, default=d.n_workers,
                   help="sampling workers (process/vector/ray samplers) (default %(default)s)")
    p.add_argument(
        "--step-size", type=float, default=d.npg.step_size, help="NPG delta (KL ~ delta/2)"
    )
    p.add_argument("--damping", type=float, default=d.npg.damping, help="Fisher damping")
    p.add_argument("--gamma", type=float, default=d.gamma, help=GAMMA_HELP)
    p.add_argument("--gae-lambda", type=float, default=d.gae_lambda, help=LAMBDA_HELP)
    p.add_argument("--hidden", type=width, nargs="*", default=list(d.policy.hidden_sizes),
                   help="widths of the policy's hidden layers (default %(default)s; "
                        "--hidden alone: none, a linear policy)")
    p.add_argument("--init-log-std", type=float, default=d.policy.init_log_std,
                   help=LOG_STD_HELP)
    p.add_argument("--eval-every", type=int, default=d.eval_every,
                   help="evaluate every N iterations (0: after the last only) (default %(default)s)")
    p.add_argument("--eval-episodes", type=int, default=d.eval_episodes,
                   help="episodes per evaluation (default %(default)s)")
    p.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE",
                   help="extra gym.make argument (VALUE parsed as JSON when possible)")  # fmt: skip
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    # behaviour cloning: always for DAPG, with --bc-init for NPG
    p.add_argument("--bc-epochs", type=int, default=None,
                   help=f"behaviour-cloning epochs over the demos (default {d.bc.epochs}; "
                        "dapg, or npg with --bc-init)")
    p.add_argument("--bc-log-std", choices=BC_LOG_STD, default=None,
                   help=f"initial exploration noise after BC (default {d.bc.log_std}; dapg, "
                        "or npg with --bc-init)")
    p.add_argument("--eval-bc", action="store_true",
                   help="evaluate the behaviour clone (--eval-episodes) before RL")
    p.add_argument("--eval-paired", action="store_true",
                   help="run every evaluation (the clone's too) on the same episodes, so the "
                        "run's policy is chosen on paired comparisons")
    if algo == "dapg":
        p.add_argument("--lam0", type=float, default=d.dapg.lam0,
                       help="DAPG's demo weight at iteration 0 (lambda0; dimensionless, default %(default)s)")
        p.add_argument("--lam1", type=float, default=d.dapg.lam1,
                       help="its decay per iteration (lambda1: w_k = lam0 lam1^k; default "
                            "%(default)s)")
        p.add_argument("--demo-weight", choices=DEMO_WEIGHTS, default=d.dapg.demo_weight,
                       help="demo weight w_k (paper: lam0 lam1^k max advantage, the DAPG "
                            "paper's; mjrl: lam0 lam1^k, mjrl's code; default %(default)s)")
    else:
        p.add_argument(
            "--bc-init", action="store_true", help="behaviour-clone the demos first (BCRL)"
        )


def _add_ppo_arguments(p: argparse.ArgumentParser) -> None:
    d = PPOConfig()
    p.add_argument("--env", type=env_id, default=d.env_id,
                   help="gymnasium id (sim; default %(default)s)")
    p.add_argument("--backend", choices=BACKENDS, default="sim",
                   help="sim only: PPO steps many simulated copies together (the other trainers "
                        "take emulated and hardware)")
    p.add_argument("--seed", type=int, default=d.seed, help="run seed (default %(default)s)")
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its last checkpoint")
    p.add_argument("--n-iter", type=int, default=d.n_iter, help="training iterations (default %(default)s)")
    p.add_argument("--num-envs", type=int, default=d.num_envs,
                   help="copies stepped together = episodes per iteration")
    p.add_argument("--lr", type=float, default=d.lr,
                   help="Adam's learning rate (default %(default)s)")
    p.add_argument("--gamma", type=float, default=d.gamma, help=GAMMA_HELP)
    p.add_argument("--gae-lambda", type=float, default=d.gae_lambda, help=LAMBDA_HELP)
    p.add_argument("--update-epochs", type=int, default=d.update_epochs,
                   help="passes over each batch (default %(default)s)")
    p.add_argument("--num-minibatches", type=int, default=d.num_minibatches,
                   help="minibatches per pass (default %(default)s)")
    p.add_argument("--clip-coef", type=float, default=d.clip_coef,
                   help="PPO's clip of the probability ratio, 1 +- this (default %(default)s)")
    p.add_argument("--ent-coef", type=float, default=d.ent_coef,
                   help="weight of the entropy bonus in the loss (default %(default)s)")
    p.add_argument("--hidden", type=width, nargs="*", default=list(d.policy.hidden_sizes),
                   help="widths of the policy's hidden layers (default %(default)s; "
                        "--hidden alone: none, a linear policy)")
    p.add_argument("--init-log-std", type=float, default=d.policy.init_log_std,
                   help=LOG_STD_HELP)
    p.add_argument("--eval-every", type=int, default=d.eval_every,
                   help="evaluate every N iterations (0: after the last only) (default %(default)s)")
    p.add_argument("--eval-episodes", type=int, default=d.eval_episodes,
                   help="episodes per evaluation (default %(default)s)")
    p.add_argument("--threads", type=int, default=d.nthread,
                   help="mujoco.batch threads (0: all CPUs)")
    p.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE",
                   help="extra gym.make argument (VALUE parsed as JSON when possible)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def ppo_config_from_args(args: argparse.Namespace) -> PPOConfig:
    """Build a PPOConfig from parsed ``lowcostdex train ppo`` arguments."""
    if getattr(args, "backend", "sim") != "sim":  # one --backend vocabulary across `train`
        raise ConfigError(f"train ppo runs on the batched simulator only (--backend sim); on "
                          f"the {args.backend} robot train npg or dapg (`lowcostdex train npg "
                          f"--backend {args.backend} ...`)")
    check_resume(args.out, args.resume)
    d = PPOConfig()
    with _settings_as_flags(args):
        return _ppo_config(args, d)


def _ppo_config(args: argparse.Namespace, d: PPOConfig) -> PPOConfig:
    return PPOConfig(
        env_id=args.env, env_kwargs=_parse_env_kwargs(args.env_kwarg), seed=args.seed,
        n_iter=args.n_iter, num_envs=args.num_envs, lr=args.lr, gamma=args.gamma,
        gae_lambda=args.gae_lambda, update_epochs=args.update_epochs,
        num_minibatches=args.num_minibatches, clip_coef=args.clip_coef, ent_coef=args.ent_coef,
        policy=dataclasses.replace(d.policy, hidden_sizes=tuple(args.hidden),
                                   init_log_std=args.init_log_std),
        eval_every=args.eval_every, eval_episodes=args.eval_episodes, nthread=args.threads,
        progress=not args.no_progress)


@contextlib.contextmanager
def _settings_as_flags(args: argparse.Namespace) -> Iterator[None]:
    """A config's refusal of a setting ("n_iter=0 must be ...") led by the flag that gave it
    ("--n-iter: n_iter=0 must be ..."): the user typed the flag, not the field."""
    try:
        yield
    except ConfigError as exc:
        field = re.match(r"(\w+)=", str(exc))
        parser = getattr(args, "parser", None)
        if field is None or parser is None:
            raise
        name = field.group(1)
        flag = next((f for k, f in _FLAG_OF.items() if k.rsplit(".", 1)[-1] == name),
                    "--" + name.replace("_", "-"))
        if flag not in parser._option_string_actions:
            raise
        raise ConfigError(f"{flag}: {exc}") from None


def _parse_env_kwargs(items: Sequence[str]) -> dict[str, Any]:
    import json

    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()  # "success_tol = 0.1": the key 'success_tol '
        if not sep or not key:
            raise ConfigError(f"--env-kwarg {item!r} must be KEY=VALUE")
        if key.strip() in ("backend", "port"):  # the options that also set how it samples
            raise ConfigError(f"--env-kwarg {item}: give --{key.strip()} {value} instead")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def check_resume(out: str, resume: bool) -> None:
    """``--resume`` into a folder that holds no run (a typo in ``--out``) is refused rather than
    started from scratch as if resumed. (``--n-iter`` below the iterations done is refused by
    :meth:`lowcostdex.algos.experiment.Run.check`.)"""
    from lowcostdex.algos.experiment import CONFIG_FILE

    path = Path(out)
    if resume and not (path / CONFIG_FILE).is_file():
        where = "does not exist" if not path.exists() else f"holds no run (no {CONFIG_FILE})"
        raise ConfigError(f"--resume: {path} {where}, so there is nothing to resume; check "
                          "--out, or leave out --resume to start a new run")


def finished_note(args: argparse.Namespace) -> str | None:
    """The note a ``--resume`` of a run that has done its ``--n-iter`` iterations gets (it
    trains nothing; its final outputs are written again), or None. Computed before the run
    (its newest checkpoint must load: else the resume starts from an older one and trains),
    printed after it succeeded."""
    from lowcostdex.algos.experiment import CHECKPOINT_DIR, _checkpoint_iteration, try_load

    if not args.resume:
        return None
    files = [(_checkpoint_iteration(f), f) for f in (Path(args.out) / CHECKPOINT_DIR).glob(
        "ckpt_*.pt")]
    files = sorted((i, f) for i, f in files if i is not None)
    if not files or files[-1][0] + 1 != args.n_iter or try_load(files[-1][1], ())[0] is None:
        return None
    return (f"{args.parser.prog}: note: the run in {args.out} had done its {args.n_iter} "
            f"iterations (--n-iter {args.n_iter}): nothing was trained, its final outputs were "
            f"written again; give --n-iter above {args.n_iter} to train more")


def beside_note(args: argparse.Namespace) -> str | None:
    """The note a new run gets when ``--out`` already holds files of the user's (not a run, not
    a file a run writes: those are refused by ``Run.check``): the run is written beside them,
    and the note names them, so nobody looks for their notes under the run's files. Computed
    before the run, printed after it succeeded; None when there are none or on ``--resume``."""
    from lowcostdex.algos.experiment import CONFIG_FILE

    path = Path(args.out)
    if args.resume or not path.is_dir() or (path / CONFIG_FILE).exists():
        return None
    names = sorted(p.name + ("/" if p.is_dir() else "") for p in path.iterdir())
    if not names:
        return None
    said = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
    return (f"{args.parser.prog}: note: {path} held {said} before this run; the run is written "
            "beside them, and they are left untouched")


def check_demo_options(args: argparse.Namespace) -> None:
    """Demo options that would be ignored: ``--n-demos`` without ``--demos``, ``--demos`` for
    NPG without ``--bc-init``, and ``--bc-epochs``/``--bc-log-std`` for NPG without
    ``--bc-init`` (no clone is made)."""
    if args.n_demos is not None and not args.demos:
        raise ConfigError(f"--n-demos {args.n_demos} counts episodes of a demo file: give it with "
                          "--demos PATH, or leave out --n-demos")
    if args.demos and args.algo == "npg" and not args.bc_init:
        raise ConfigError(f"--demos {args.demos}: npg uses demonstrations only with --bc-init "
                          "(behaviour-clone them first); add --bc-init, or train dapg")
    if args.algo == "npg" and not args.bc_init:
        given = [f for f, v in (("--bc-epochs", args.bc_epochs),
                                ("--bc-log-std", args.bc_log_std)) if v is not None]
        if given:
            raise ConfigError(f"{' and '.join(given)}: settings of the behaviour clone, which "
                              "npg makes only with --demos PATH --bc-init; add those, train "
                              f"dapg, or leave out {' and '.join(given)}")


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """Build a TrainConfig from parsed ``lowcostdex train npg|dapg`` arguments."""
    check_resume(args.out, args.resume)
    check_demo_options(args)
    d = TrainConfig()
    env_kwargs = _parse_env_kwargs(args.env_kwarg)
    hand = "allegro" if "allegro" in str(args.env).lower() else "dclaw"
    backend, robot_kwargs = robot_selection(args.backend, args.port, hand)
    env_kwargs.update(robot_kwargs)
    if args.latency_ms is not None:
        if not args.port:
            raise ConfigError("--latency-ms is the serial adapter's latency timer: it needs "
                              "--backend hardware --port DEVICE")
        env_kwargs.update(latency_kwargs(args.latency_ms))
    with _settings_as_flags(args):
        return _train_config(args, d, backend, env_kwargs)


def _train_config(args: argparse.Namespace, d: TrainConfig, backend: str,
                  env_kwargs: dict[str, Any]) -> TrainConfig:
    return TrainConfig(
        algo=args.algo,
        env_id=args.env,
        backend=backend,
        env_kwargs=env_kwargs,
        seed=args.seed,
        n_iter=args.n_iter,
        n_traj=args.n_traj,
        gamma=args.gamma,
        gae_lambda=args.gae_lambda,
        sampler=args.sampler,
        n_workers=args.workers,
        eval_every=args.eval_every,
        eval_episodes=args.eval_episodes,
        demos=str(Path(args.demos).resolve()) if args.demos else None,
        n_demos=args.n_demos,
        bc_init=bool(getattr(args, "bc_init", False)),
        eval_bc=bool(getattr(args, "eval_bc", False)),
        eval_paired=bool(getattr(args, "eval_paired", False)),
        policy=dataclasses.replace(
            d.policy, hidden_sizes=tuple(args.hidden), init_log_std=args.init_log_std
        ),
        npg=dataclasses.replace(d.npg, step_size=args.step_size, damping=args.damping),
        dapg=DAPGConfig(lam0=args.lam0, lam1=args.lam1, demo_weight=args.demo_weight)
        if args.algo == "dapg"
        else d.dapg,
        bc=dataclasses.replace(
            d.bc, epochs=d.bc.epochs if args.bc_epochs is None else args.bc_epochs,
            log_std=args.bc_log_std or d.bc.log_std),
        progress=not args.no_progress,
    )


def _run_command(args: argparse.Namespace) -> int:
    from lowcostdex.algos.train import train

    config = config_from_args(args)
    if config.uses_demos and config.n_demos is not None:
        from lowcostdex.demonstrations.dataset import load_demos

        held = load_demos(config.demos).n_episodes  # a bad file: the same error train() raises
        if held < config.n_demos:  # not silently fewer than asked
            print(f"{args.parser.prog}: note: --n-demos {config.n_demos}, but {args.demos} "
                  f"holds {held} successful demonstration(s): all {held} are used",
                  file=sys.stderr)
    return _train_and_report(args, train, config)


def _train_and_report(args: argparse.Namespace, train: Any, config: Any) -> int:
    """Run ``train(config, args.out, resume=args.resume)``; print its outcome and the notes on a
    finished or neighbouring run folder; Ctrl-C names the checkpoint to resume from."""
    from lowcostdex.algos.experiment import ResumeMismatch

    notes = (finished_note(args), beside_note(args))
    try:
        run = train(config, args.out, resume=args.resume)
    except KeyboardInterrupt as exc:
        return _interrupted(args, exc)
    except ResumeMismatch as exc:  # name the flags to type, not only the settings that differ
        flags, without = resume_flags(args.parser, exc.stored, exc.keys)
        if not flags and not without:
            raise
        said = ([shlex.join(flags)] if flags else []) + [f"without {f}" for f in without]
        raise ConfigError(f"{exc}. The run's own settings as flags: {'; '.join(said)}"
                          ) from None
    _print_outcome(run)
    for note in notes:
        if note:
            print(note, file=sys.stderr)
    return 0


def _run_ppo(args: argparse.Namespace) -> int:
    from lowcostdex.algos.ppo import train

    config = ppo_config_from_args(args)
    return _train_and_report(args, train, config)


# run settings whose flag is not the setting's name (the others: --name-with-dashes)
_FLAG_OF = {"env_id": "--env", "n_workers": "--workers", "policy.hidden_sizes": "--hidden",
            "nthread": "--threads", "bc.epochs": "--bc-epochs", "bc.log_std": "--bc-log-std",
            "policy.init_log_std": "--init-log-std", "npg.step_size": "--step-size",
            "npg.damping": "--damping", "dapg.lam0": "--lam0", "dapg.lam1": "--lam1",
            "dapg.demo_weight": "--demo-weight"}


def resume_flags(parser: argparse.ArgumentParser, stored: Any, keys: list[str]
                 ) -> tuple[list[str], list[str]]:
    """The flags that give the run's own value of each differing setting ``keys`` (dotted
    paths into the run's config.json ``stored``); settings with no flag are left to the
    message's config.json. Returns the words to type and the options to leave out (a switch or
    an option the run was started without)."""
    options = parser._option_string_actions
    words: list[str] = []
    without: list[str] = []
    for key in keys:
        flag = _FLAG_OF.get(key, "--" + key.replace("_", "-"))
        value: Any = stored
        for part in key.split("."):
            value = value.get(part) if isinstance(value, dict) else None
        action = options.get(flag)
        if action is None or (key == "env_kwargs" or flag in ("--env-kwarg", "--out")):
            continue
        if isinstance(action, argparse._StoreTrueAction):
            (words if value else without).append(flag)
        elif value is None:
            without.append(flag)
        elif isinstance(value, (list, tuple)):
            words += [flag, *map(str, value)]
        else:
            words += [flag, str(value)]
    return words, without


def command_line(parser: argparse.ArgumentParser, args: argparse.Namespace,
                 resume: bool) -> str:
    """The command that runs ``args`` again (shell-quoted): the options that differ from
    their defaults, ``--out`` and ``--demos`` as absolute paths, ``--resume`` if asked."""
    words = parser.prog.split()
    for action in parser._actions:
        if not action.option_strings or action.dest in ("help", "debug", "resume"):
            continue
        value = getattr(args, action.dest, action.default)
        if value is None or value == action.default:
            continue
        flag = max(action.option_strings, key=len)
        if action.dest in ("out", "demos"):
            value = str(Path(value).resolve())
        if isinstance(action, argparse._StoreTrueAction):
            words.append(flag)
        elif isinstance(action, argparse._AppendAction):
            for item in value:
                words += [flag, str(item)]
        elif isinstance(value, (list, tuple)):
            words += [flag, *map(str, value)]
        else:
            words += [flag, str(value)]
    if resume:
        words.append("--resume")
    return shlex.join(words)


def _interrupted(args: argparse.Namespace, exc: KeyboardInterrupt) -> int:
    """Ctrl-C: where the run stands and the exact command that continues it."""
    from lowcostdex.algos.experiment import Interrupted
    from lowcostdex.errors import INTERRUPTED

    prog = args.parser.prog
    checkpoint = exc.checkpoint if isinstance(exc, Interrupted) else None
    if checkpoint is not None:
        print(f"{prog}: interrupted (Ctrl-C); saved the state after iteration "
              f"{exc.iteration} ({checkpoint}). Resume with:\n"  # type: ignore[attr-defined]
              f"  {command_line(args.parser, args, resume=True)}", file=sys.stderr)
    else:  # a new run's start is undone (Run.abandon): no --resume then
        from lowcostdex.algos.experiment import CONFIG_FILE

        again = args.resume and (Path(args.out) / CONFIG_FILE).is_file()
        print(f"{prog}: interrupted (Ctrl-C) before the first checkpoint; nothing to resume. "
              f"Start again with:\n  {command_line(args.parser, args, resume=again)}",
              file=sys.stderr)
    return INTERRUPTED


def _print_outcome(run: Any) -> None:
    """Where the run is, and its final evaluation beside the best one and the first crossing."""
    from lowcostdex.algos import experiment as ex

    print(f"run: {run.path}")
    print(f"curves: {run.path / ex.CURVES_FILE}")
    summary = ex.read_json(run.path / ex.SUMMARY_FILE)
    final, best = summary["final"], summary["best"]
    if "eval_success_rate" in final:
        print(f"final eval success rate: {final['eval_success_rate']:.2f} (iteration "
              f"{final['eval_iteration']:.0f}, {final['samples']:.0f} samples)")
    if best:
        when = ("the behaviour clone, before any RL step" if best["iteration"] < 0 else
                f"iteration {best['iteration']:.0f}, {best['samples']:.0f} samples")
        print(f"best eval success rate: {best['eval_success_rate']:.2f} ({when}): the run's "
              f"policy, {ex.POLICY_FILE}")
    first = summary["first_eval_crossing"]
    target = summary["target"]
    print(f"first eval success >= {target:.0%}: " + (
        f"iteration {first['iteration']:.0f}, {first['samples']:.0f} samples" if first
        else "not reached"))
