"""Run directories shared by every trainer (NPG, DAPG, local models).

A run directory holds everything one training run produces, written so that a run killed at
any moment can be resumed and a checkpoint received from someone else can be opened safely::

    <out>/
      config.json           resolved configuration; checked against the new one on resume
      metrics.csv           one row per iteration, fixed columns, "nan" where a key was absent
      tb/                   TensorBoard events (only when the `tensorboard` package is installed)
      checkpoints/
        ckpt_000010.pt      torch.save of tensors, state dicts and plain Python values only
        latest.json         {"iteration": 10, "file": "ckpt_000010.pt"}, replaced last
      learning_curves.png   success rate and return vs samples and vs robot hours

Every file is written atomically (temporary file, fsync, ``os.replace``), so a kill leaves
either the old or the new version, never half of one. Checkpoints load with
``torch.load(..., weights_only=True)``: no pickled classes, numpy arrays are stored as tensors.
torch is imported only to save or load a checkpoint, so a trainer without torch code (local
models) and the command line do not pay for it.

Faults: :meth:`Run.check` refuses a directory before anything is written (trainers call it, then
validate their inputs, then :meth:`Run.open`); a start that fails before its first checkpoint is
undone (:meth:`Run.abandon`) and a ``config.json`` without checkpoint never blocks a new start;
:meth:`Run.load_latest` resumes from the newest checkpoint that loads and says which; after Ctrl-C
:func:`stopped` saves the state after the last completed iteration and returns an
:class:`Interrupted` naming it.

Typical use by a trainer::

    run = Run.open(out_dir, config=dataclasses.asdict(cfg), resume=resume)
    ckpt = run.load_latest() if resume else None       # also drops metric rows after it
    start = 0 if ckpt is None else ckpt.iteration + 1
    for it in range(start, n_iter):
        ...
        run.log({"iteration": it, "samples": n, "robot_hours": h, "success_rate": s, ...})
        run.save_checkpoint(it, {"policy": policy.state_dict(), "rng": rng.bit_generator.state})
    run.plot_learning_curves()
    run.close()

Column names every trainer should use (so plots and reports work across trainers) are the
module constants ITERATION, SAMPLES, ROBOT_HOURS, SUCCESS_RATE, RETURN_MEAN, EVAL_SUCCESS_RATE
and EVAL_RETURN_MEAN.

Where the parts live (all importable from here too): atomic files, JSON and safe checkpoint state
in ``run_files``; the column names, the metrics CSV and the learning curves in ``metrics``; the
best/final policy and the run summary in ``best_policy``. This module keeps ``Run``.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

# The run directory's public names live in these modules; they are imported here so that
# ``experiment.X`` keeps naming them (trainers use ``from lowcostdex.algos import experiment as ex``).
from lowcostdex.algos.best_policy import (  # noqa: F401
    BC_POLICY_FILE,
    BEST_POLICY_FILE,
    FINAL_POLICY_FILE,
    POLICY_FILE,
    SUMMARY_FILE,
    BestPolicy,
    evaluation_score,
    first_crossing,
    run_summary,
)
from lowcostdex.algos.metrics import (  # noqa: F401
    EVAL_RETURN_MEAN,
    EVAL_SUCCESS_RATE,
    ITERATION,
    RETURN_MEAN,
    ROBOT_HOURS,
    SAMPLES,
    SUCCESS_RATE,
    WALL_SECONDS,
    MetricsLog,
    plot_learning_curves,
    read_metrics,
)
from lowcostdex.algos.run_files import (  # noqa: F401
    json_scalar,
    load_state,
    read_json,
    save_state,
    to_safe,
    write_json,
)
from lowcostdex.errors import ConfigError
from lowcostdex.outdir import user_path, write_bytes_atomic, write_text_atomic  # noqa: F401

CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.csv"
CURVES_FILE = "learning_curves.png"
CHECKPOINT_DIR = "checkpoints"
LATEST_FILE = "latest.json"
_RUN_NAMES = (METRICS_FILE, CURVES_FILE, CHECKPOINT_DIR, "tb", BEST_POLICY_FILE,
              FINAL_POLICY_FILE, POLICY_FILE, SUMMARY_FILE, BC_POLICY_FILE)
"""What a run writes besides its config (and its trainer's own JSON files)."""


# ----------------------------------------------------------------------------------------------
# The run directory


class ResumeMismatch(ConfigError):
    """A resume whose configuration differs from the run's; ``stored`` is the run's own
    (config.json) and ``keys`` the differing settings as dotted paths (the CLI turns them
    into the flags to type)."""

    def __init__(self, message: str, stored: Mapping[str, Any], keys: list[str]):
        super().__init__(message)
        self.stored, self.keys = stored, keys


class Interrupted(KeyboardInterrupt):
    """Ctrl-C stopped a run; the state after its last completed iteration is saved.

    Attributes:
      path: the run directory.
      iteration: the iteration the saved checkpoint follows (None: the run had none and its
        start was undone, see :meth:`Run.abandon`).
      checkpoint: the checkpoint file (None with ``iteration``).
    """

    def __init__(self, path: Path, iteration: int | None, checkpoint: Path | None):
        saved = (f"checkpoint after iteration {iteration}: {checkpoint}" if checkpoint
                 else "no checkpoint yet")
        super().__init__(f"training in {path} interrupted; {saved}")
        self.path, self.iteration, self.checkpoint = path, iteration, checkpoint


@dataclass(frozen=True)
class Checkpoint:
    """A loaded checkpoint.

    Attributes:
      iteration: the last iteration completed before it was written; resume at iteration + 1.
      state: the dict given to :meth:`Run.save_checkpoint` (arrays come back as tensors).
      path: the file it was read from.
    """

    iteration: int
    state: dict[str, Any]
    path: Path


def _config_differences(
    old: Mapping[str, Any], new: Mapping[str, Any], prefix: str = ""
) -> list[str]:
    diffs = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key, "<absent>"), new.get(key, "<absent>")
        if isinstance(a, Mapping) and isinstance(b, Mapping):
            diffs += _config_differences(a, b, f"{prefix}{key}.")
        elif a != b:
            diffs.append(f"{prefix}{key}: {a!r} -> {b!r}")
    return diffs


def _last_checkpoint_iteration(checkpoint_dir: Path) -> int | None:
    """The iteration of the newest checkpoint file in ``checkpoint_dir`` (None: none)."""
    its = [_checkpoint_iteration(f) for f in checkpoint_dir.glob("ckpt_*.pt")]
    its = [i for i in its if i is not None]
    return max(its) if its else None


def _checkpoint_iteration(file: Path) -> int | None:
    """The iteration in a checkpoint file name ``ckpt_<iteration>.pt`` (None: another name)."""
    digits = file.stem.removeprefix("ckpt_")
    return int(digits) if digits.isdigit() else None


def try_load(file: Path, required: tuple[str, ...]) -> tuple[dict[str, Any] | None, str]:
    """(the checkpoint's state, "") or (None, why it cannot be resumed from)."""
    import pickle

    try:
        state = load_state(file)
    except pickle.UnpicklingError:  # what weights_only refuses, or not a torch file at all
        return None, "does not load with weights_only=True: not a lowcostdex checkpoint"
    except Exception as exc:  # RuntimeError (zip archive cut or corrupt), EOFError, OSError
        return None, f"does not load: corrupt or cut short ({type(exc).__name__})"
    if not isinstance(state, dict):
        return None, f"holds a {type(state).__name__}, not a checkpoint dict"
    missing = [k for k in required if k not in state]
    return (None, f"lacks {', '.join(missing)}") if missing else (state, "")


def _jsonable(config: Mapping[str, Any]) -> dict[str, Any]:
    """Round-trip through JSON so tuples compare equal to the lists read back (and a numpy
    scalar to the number it holds)."""
    return json.loads(json.dumps(dict(config), default=json_scalar))


class Run:
    """One run directory: resolved config, metrics, checkpoints, TensorBoard, learning curves.

    Create with :meth:`open`. Not thread-safe; one trainer process writes a run directory.
    """

    def __init__(self, path: Path, config: dict[str, Any], *, keep_last: int, tensorboard: bool):
        self.path = path
        self.config = config
        self.keep_last = keep_last
        self.metrics = MetricsLog(path / METRICS_FILE)
        self._tensorboard = tensorboard
        self._tb: Any = None
        self._created = False
        self._json_written: set[str] = set()
        self.last_saved: tuple[int, Path] | None = None
        """(iteration, file) of the checkpoint saved or resumed from last in this process."""
        self._pending: tuple[int, dict[str, Any]] | None = None

    @classmethod
    def check(
        cls,
        path: str | os.PathLike[str],
        config: Mapping[str, Any],
        *,
        resume: bool = False,
        mutable_keys: Iterable[str] = (),
    ) -> None:
        """Raise the error :meth:`open` would raise, without writing anything.

        Trainers call it first, then validate their inputs (demonstrations, the env), and
        only then :meth:`open` the run, so that a start refused for any reason leaves the
        directory as it was.

        A directory holding ``config.json`` but no checkpoint is a start that never completed
        a checkpointed iteration (refused late, or killed during its first iterations): it
        does not block a new start of the same trainer (same config keys), which replaces it.

        Raises:
          ConfigError: a new run into a directory that already holds one (a checkpoint), or
            a ``config.json`` that is not a run configuration of this trainer; a resume whose
            config differs in a key not listed in ``mutable_keys``; a resume whose ``n_iter``
            is below the iterations the run has done (it would train nothing and leave a
            config.json that contradicts its checkpoints).
        """
        if not isinstance(path, (str, os.PathLike)) or not str(path).strip():
            # before: None gave os.fspath's TypeError, and "" (an unset variable) was the
            # current folder, where the run was written beside the user's files
            raise ConfigError(f"run directory {path!r} is no folder path; give one, e.g. "
                              "'runs/npg'")
        path = user_path(path)
        config = _jsonable(config)
        if path.exists() and not path.is_dir():
            raise ConfigError(f"run directory {path} is a file; choose a directory")
        from lowcostdex.outdir import check_writable

        check_writable(path, "run directory")  # under a file, or no permission: before the work
        config_file = path / CONFIG_FILE
        if not config_file.exists():
            from lowcostdex.outdir import read_marker

            other = read_marker(path)
            if other is not None:  # another command's output folder (a report, a transfer run)
                raise ConfigError(f"{path} holds the output of 'lowcostdex "
                                  f"{other.get('command', '?')}', not a training run; it is left "
                                  "untouched. Give an empty or new directory")
            clash = sorted(n for n in _RUN_NAMES if (path / n).exists())
            if clash:  # a user's folder (inputs beside a run are fine, e.g. its demos)
                raise ConfigError(f"{path} is not a training run but holds {', '.join(clash)}, "
                                  "which a run would overwrite; they are left untouched. "
                                  "Give an empty or new directory")
            return
        try:
            stored = read_json(config_file)
        except (OSError, ValueError) as exc:
            raise ConfigError(f"{config_file} is not a run configuration ({exc}); choose "
                              "a new directory") from None
        if not isinstance(stored, dict):
            raise ConfigError(f"{config_file} is not a run configuration; choose a new "
                              "directory")
        last = _last_checkpoint_iteration(path / CHECKPOINT_DIR)
        if last is None:  # a start that saved no checkpoint: nothing to resume or keep
            if set(stored) != set(config):
                raise ConfigError(f"{config_file} is not a configuration of this trainer; "
                                  "choose a new directory")
            return
        if not resume:
            raise ConfigError(f"{path} already holds a run (checkpoint after iteration {last}); "
                              "resume it (--resume) or choose a new directory")
        if _trainer_of(stored) != _trainer_of(config):  # not a diff: another trainer's run
            raise ConfigError(
                f"cannot resume {path}: it is a run of {_trainer_of(stored)}, not of "
                f"{_trainer_of(config)}; resume it with the trainer that started it (see "
                f"{config_file}), or choose a new directory")
        mutable = set(mutable_keys)
        fixed_old = {k: v for k, v in stored.items() if k not in mutable}
        fixed_new = {k: v for k, v in config.items() if k not in mutable}
        diffs = _config_differences(fixed_old, fixed_new)
        if diffs:
            raise ResumeMismatch(
                f"cannot resume {path}: configuration differs ({'; '.join(diffs)}); "
                f"only {sorted(mutable) or 'no keys'} may change. Give the settings the run "
                f"was started with (they are in {config_file}; a stopped run printed the "
                "command that resumes it)",
                stored, [d.split(": ", 1)[0] for d in diffs])
        n_iter = config.get("n_iter")
        if isinstance(n_iter, int) and n_iter < last + 1:  # resumed, it would do nothing
            raise ConfigError(
                f"cannot resume {path} with n_iter={n_iter} (--n-iter): the run has done "
                f"{last + 1} iterations already (checkpoint after iteration {last}); give "
                f"--n-iter above {last + 1} to train more. The run is left as it is")

    @classmethod
    def open(
        cls,
        path: str | os.PathLike[str],
        config: Mapping[str, Any],
        *,
        resume: bool = False,
        mutable_keys: Iterable[str] = (),
        keep_last: int = 3,
        tensorboard: bool = True,
    ) -> Run:
        """Create a new run directory, or reopen one to resume it.

        Args:
          path: the run directory.
          config: the resolved configuration (JSON-serialisable, e.g. ``dataclasses.asdict``).
          resume: reopen an existing run. Its stored config must equal ``config`` except for
            the top-level ``mutable_keys`` (e.g. the iteration budget); the stored file is
            updated with the new values of those keys.
          mutable_keys: top-level config keys allowed to change on resume.
          keep_last: number of most recent checkpoints kept on disk (>= 1).
          tensorboard: also write TensorBoard events when the package is installed.

        Raises:
          ConfigError: see :meth:`check`.
        """
        if keep_last < 1:
            raise ConfigError(f"keep_last={keep_last} must be >= 1")
        cls.check(path, config, resume=resume, mutable_keys=mutable_keys)
        path = user_path(path)
        created = not path.exists()
        path.mkdir(parents=True, exist_ok=True)
        from lowcostdex.outdir import claim

        claim(path, "a training run",  # one writer: not the same run started twice
              " (Ctrl-C saves the run's state; then --resume)")
        write_json(path / CONFIG_FILE, _jsonable(config))
        run = cls(path, _jsonable(config), keep_last=keep_last, tensorboard=tensorboard)
        run._created = created
        if not resume:  # rows of a start that saved no checkpoint
            run.metrics.truncate(None)
        return run

    def abandon(self) -> bool:
        """Undo a start that failed before its first checkpoint; True if it did.

        Removes what the run wrote (config, metrics, TensorBoard events, JSON files written
        with :meth:`write_json`, the best policy) and the directory if :meth:`open` created
        it and nothing else is in it. A run with a checkpoint is left as it is (resumable).
        """
        if _last_checkpoint_iteration(self.checkpoint_dir) is not None:
            return False
        self.close()
        names = {CONFIG_FILE, METRICS_FILE, BEST_POLICY_FILE, BC_POLICY_FILE, CURVES_FILE,
                 *self._json_written}
        for name in names:
            (self.path / name).unlink(missing_ok=True)
        for folder in (self.path / "tb", self.checkpoint_dir):
            if folder.is_dir():
                shutil.rmtree(folder)
        if self._created and self.path.is_dir() and not any(self.path.iterdir()):
            self.path.rmdir()
        return True

    # -- metrics -------------------------------------------------------------------------------
    def log(self, row: Mapping[str, Any]) -> None:
        """Append one iteration's metrics (must include ITERATION) to CSV and TensorBoard."""
        if ITERATION not in row:
            raise ValueError(f"a metrics row needs the {ITERATION!r} key")
        self.metrics.append(row)
        writer = self._tb_writer(int(row[ITERATION]))
        if writer is not None:
            step = int(row[ITERATION])
            for key, value in row.items():
                if key != ITERATION and isinstance(value, (int, float, np.number)):
                    writer.add_scalar(key, float(value), step)
            writer.flush()

    def _tb_writer(self, first_step: int) -> Any:
        if not self._tensorboard or self._tb is not None:
            return self._tb
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:  # tensorboard is optional
            self._tensorboard = False
            return None
        # purge_step drops events a killed run wrote after its last checkpoint.
        self._tb = SummaryWriter(str(self.path / "tb"), purge_step=first_step)
        return self._tb

    def read_metrics(self) -> dict[str, np.ndarray]:
        """The metrics written so far, ``{column: (rows,) array}``."""
        return read_metrics(self.metrics.path)

    # -- checkpoints ---------------------------------------------------------------------------
    @property
    def checkpoint_dir(self) -> Path:
        return self.path / CHECKPOINT_DIR

    def save_checkpoint(self, iteration: int, state: Mapping[str, Any]) -> Path:
        """Save the state after ``iteration`` completed; becomes the one resume starts from.

        Args:
          iteration: the completed iteration (>= 0).
          state: see :func:`save_state`. Include every RNG state and optimizer state the next
            iterations depend on, so that a resumed run equals an uninterrupted one.

        Returns:
          The checkpoint file.
        """
        name = f"ckpt_{iteration:06d}.pt"
        file = self.checkpoint_dir / name
        save_state(file, state)
        write_json(self.checkpoint_dir / LATEST_FILE, {"iteration": int(iteration), "file": name})
        self._prune(iteration)
        self.last_saved, self._pending = (int(iteration), file), None
        return file

    def keep_for_interrupt(self, iteration: int, state: Mapping[str, Any]) -> None:
        """Hold a copy of the state after ``iteration`` (one that was not checkpointed, e.g.
        between ``checkpoint_every`` periods) for :meth:`interrupted` to save."""
        self._pending = (int(iteration), to_safe(dict(state), "state"))

    def interrupted(self) -> Interrupted:
        """After Ctrl-C: save the state held by :meth:`keep_for_interrupt` if it is newer than
        the last checkpoint, and return the :class:`Interrupted` naming the checkpoint to
        resume from (the trainer raises it)."""
        if self._pending is not None and (self.last_saved is None
                                          or self._pending[0] > self.last_saved[0]):
            self.save_checkpoint(*self._pending)
        iteration, file = self.last_saved or (None, None)
        return Interrupted(self.path, iteration, file)

    def _prune(self, current: int) -> None:
        """Keep the ``keep_last`` newest checkpoints up to ``current``; later ones are of a
        run resumed from an earlier checkpoint (e.g. one skipped because it did not load)."""
        files = sorted((i, f) for f in self.checkpoint_dir.glob("ckpt_*.pt")
                       if (i := _checkpoint_iteration(f)) is not None)
        stale = [f for i, f in files if i > current]
        kept = [f for i, f in files if i <= current]
        for old in stale + kept[: -self.keep_last]:
            old.unlink(missing_ok=True)

    def load_latest(self, required: Iterable[str] = (),
                    log: Callable[[str], None] | None = print) -> Checkpoint | None:
        """Load the newest checkpoint that loads and drop metric rows logged after it.

        Checkpoints are tried newest first; one that does not load with ``weights_only=True``
        (cut short, corrupt, holding pickled objects) or lacks a ``required`` key is skipped,
        and the next older one is used.

        Args:
          required: top-level keys the trainer's state needs.
          log: called with one line naming the checkpoint used and one per skipped file
            (None: silent).

        Returns:
          The checkpoint, or None when the run has none (metrics are then cleared, so the run
          restarts from iteration 0 with a consistent CSV; ``log`` says so).

        Raises:
          ConfigError: checkpoint files exist but none of them loads (nothing is changed).
        """
        files = sorted(((_checkpoint_iteration(f), f) for f in self.checkpoint_dir.glob("ckpt_*.pt")
                        if _checkpoint_iteration(f) is not None), reverse=True)
        if not files:
            self.metrics.truncate(None)
            if log is not None:  # before: silent, so a misspelt --out with --resume started over
                log(f"nothing to resume in {self.path} (no checkpoint saved there): a new run "
                    "starts at iteration 0; stop it (Ctrl-C) if you meant another folder")
            return None
        skipped = []
        for iteration, file in files:
            state, reason = try_load(file, tuple(required))
            if state is not None:
                ckpt = Checkpoint(int(iteration), state, file)
                break
            skipped.append(f"{file.name} ({reason})")
        else:
            raise ConfigError(f"cannot resume {self.path}: no checkpoint loads: "
                              f"{'; '.join(skipped)}")
        self.metrics.truncate(ckpt.iteration)
        self.last_saved = (ckpt.iteration, file)
        if log is not None:
            rel = file.relative_to(self.path)
            log(f"resuming {self.path} from {rel} (after iteration {ckpt.iteration})"
                + (f"; skipped {', '.join(skipped)}" if skipped else ""))
        return ckpt

    # -- outputs -------------------------------------------------------------------------------
    def plot_learning_curves(self, title: str | None = None) -> Path:
        """Write ``learning_curves.png`` from the metrics so far."""
        return plot_learning_curves(
            self.read_metrics(),
            self.path / CURVES_FILE,
            title if title is not None else self.path.name,
        )

    def write_json(self, name: str, obj: Any) -> Path:
        """Atomically write a JSON file (e.g. an evaluation summary) into the run directory."""
        file = self.path / name
        write_json(file, obj)
        self._json_written.add(name)
        return file

    def close(self) -> None:
        """Flush and close the TensorBoard writer (the CSV is always flushed); let go of the
        run directory's writer lock."""
        from lowcostdex.outdir import release

        if self._tb is not None:
            self._tb.close()
            self._tb = None
        release(self.path)

    def __enter__(self) -> Run:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _trainer_of(config: Mapping[str, Any]) -> str:
    """Which trainer wrote a run's configuration, in words ('train ppo'); npg and dapg share
    one (their runs differ in ``algo``, which the settings' diff names)."""
    algo = config.get("algo")
    name = ("tvlg" if "n_rollouts" in config else "ppo" if "num_envs" in config
            else "npg/dapg" if isinstance(algo, str) else None)
    return f"'train {name}'" if name else "another trainer"


def stopped(run: Run | None, exc: BaseException, resume: bool) -> BaseException:
    """What a trainer raises when ``exc`` stops its run (``run``: None if not opened yet).

    After Ctrl-C the state after the last completed iteration is saved and an
    :class:`Interrupted` naming it is returned; a new run (not ``resume``) that saved no
    checkpoint is undone (:meth:`Run.abandon`), so it does not block the next start.
    Otherwise ``exc`` itself.
    """
    interrupted = None
    if run is not None and isinstance(exc, KeyboardInterrupt):
        interrupted = exc if isinstance(exc, Interrupted) else run.interrupted()
    if run is not None and not resume and run.abandon() and interrupted is not None:
        interrupted = Interrupted(run.path, None, None)
    return interrupted or exc
