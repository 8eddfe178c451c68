"""The demonstration dataset: HDF5, one group per episode, appended episode by episode.

This is lowcostdex's only demonstration format. Every source writes it: kinesthetic recordings on
a robot and the emulator's virtual teacher (``lowcostdex.demonstrations.kinesthetic``), scripted teachers and
trained policies run in simulation (``lowcostdex.demonstrations.dataset.teacher_episodes`` and
``save_demos``); BC and DAPG read it with ``lowcostdex.demonstrations.dataset.load_demos``. It lives at the
package top level because the hardware and the learning layers both use it.

Layout (Minari's per-episode layout, plus the raw robot readings), no pickle anywhere::

    /                              attrs: format="lowcostdex-demos", format_version=2,
                                          env_id, task, hand (hand spec JSON), source,
                                          control_period [s], obs_dim, act_dim,
                                          action_joints (JSON list), total_episodes, total_steps
    /episode_<k>/                  attrs: id, total_steps, success, seed, reset_time [s],
                                          reset_attempts, source, label,
                                          label_model (JSON; servo_goal episodes only)
        observations   (T+1, obs_dim) float64   o_0 .. o_T (the last one follows the last action)
        actions        (T, act_dim)   float64   a_t in the env's action space [-1, 1]
        rewards        (T,)           float64   the task's reward for (o_t, a_t)
        terminations   (T,)           bool
        truncations    (T,)           bool      True at the last step (time limit)
        infos/qpos     (T+1, nq)      float64   the env model's qpos (encoders on a robot)
        infos/qvel     (T+1, nv)      float64
        infos/time     (T+1,)         float64   robot clock or env time [s]
        infos/success  (T,)           bool
        goal/<key>     task goal arrays at step 0 (e.g. goal/angle [rad])

``source`` (one of ``SOURCES``) says who chose the actions: ``kinesthetic`` (a person moved the
fingers), ``virtual_teacher`` (the emulator's scripted hand did), ``playback`` (the robot's own
servos replayed a recorded demonstration's goals, ``lowcostdex.demonstrations.kinesthetic``),
``scripted_teacher`` (a scripted controller's action, e.g. ``lowcostdex.teachers.valve``),
``policy`` (a trained policy's mean action). The file's ``source`` is the recording's; an
episode's own ``source`` attribute may differ (the playbacks in a kinesthetic recording).

``label`` (one of ``LABELS``) says what an episode's ``actions`` are:

- ``commanded``: the goals the robot or env was actually sent. An episode may have been executed
  with noise added to them; ``actions`` are then the clean labels and ``infos/qpos`` the states
  actually visited (DART).
- ``next_position``: a kinesthetic recording labelled with the next measured joint positions,
  a_t = goal_to_action(q_{t+1}) (format version 1's only kinesthetic label).
- ``servo_goal``: a kinesthetic recording labelled with the goals a position servo would need
  to produce the recorded motion, from the measured positions and velocities through the servo
  response model in the episode's attribute ``label_model`` (``lowcostdex.demonstrations.kinesthetic.ServoResponse``;
  per episode: sessions appended to one file may each identify their own).

Versions: 2 added the per-episode ``label`` and ``label_model`` attributes and the
``playback`` source. Version-1 files read as ``next_position`` for kinesthetic and virtual-teacher
episodes and ``commanded`` otherwise, which is what their actions were.

Crash safety: the file is opened, one finished episode is written and flushed, the totals are
updated, and the file is closed again, so between episodes (and during recording) it is a
complete, consistent HDF5 file; a crash loses at most the episode being recorded.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from lowcostdex.errors import ConfigError, InputError, check_choice
from lowcostdex.outdir import user_path

FORMAT = "lowcostdex-demos"
FORMAT_VERSION = 2
SOURCES = ("kinesthetic", "virtual_teacher", "playback", "scripted_teacher", "policy")
LABELS = ("commanded", "next_position", "servo_goal")


def default_label(source: str) -> str:
    """The label of an episode that does not name one (format version 1): kinesthetic and
    virtual-teacher recordings were labelled with the next position, everything else with the
    commanded action."""
    return "next_position" if source in ("kinesthetic", "virtual_teacher") else "commanded"


@dataclass(frozen=True)
class DatasetInfo:
    """File-level metadata; must match when appending to an existing file.

    Attributes:
      env_id: gymnasium id the demos are for.
      task: task class name.
      hand: hand spec JSON.
      source: one of SOURCES (see the module docstring).
      control_period: [s].
      obs_dim, act_dim: observation and action lengths.
      action_joints: joint names in action order.
    """

    env_id: str
    task: str
    hand: str
    source: str
    control_period: float
    obs_dim: int
    act_dim: int
    action_joints: tuple[str, ...]

    def __post_init__(self) -> None:
        check_choice("demonstration source", self.source, SOURCES)

    @classmethod
    def from_env(cls, env: Any, source: str, env_id: str | None = None) -> DatasetInfo:
        """The metadata of demos recorded in a lowcostdex hand env (``HandEnv``, wrapped or not).

        Args:
          env: the env; its (outer) observation and action spaces give obs_dim and act_dim.
          source: one of SOURCES.
          env_id: default ``env.spec.id``.

        Raises:
          ConfigError: the env is not a lowcostdex hand env, or has no id.
        """
        base = env.unwrapped
        task = getattr(base, "task", None)
        if task is None or not hasattr(base, "control_period"):
            raise ConfigError(f"{type(base).__name__} is not a lowcostdex hand env; build its "
                              "DatasetInfo by hand")
        env_id = env_id or (env.spec.id if env.spec is not None else None)
        if not env_id:
            raise ConfigError("the env has no gymnasium id; pass env_id")
        return cls(env_id=env_id, task=type(task).__name__, hand=task.hand.to_json(),
                   source=source, control_period=float(base.control_period),
                   obs_dim=int(np.prod(env.observation_space.shape)),
                   act_dim=int(np.prod(env.action_space.shape)),
                   action_joints=tuple(task.hand.joint_names))

    def attrs(self) -> dict:
        return {"env_id": self.env_id, "task": self.task, "hand": self.hand,
                "source": self.source, "control_period": self.control_period,
                "obs_dim": self.obs_dim, "act_dim": self.act_dim,
                "action_joints": json.dumps(list(self.action_joints))}

    @classmethod
    def from_attrs(cls, a) -> DatasetInfo:
        return cls(str(a["env_id"]), str(a["task"]), str(a["hand"]), str(a["source"]),
                   float(a["control_period"]), int(a["obs_dim"]), int(a["act_dim"]),
                   tuple(json.loads(a["action_joints"])))


@dataclass
class Episode:
    """One recorded episode (arrays as in the module docstring).

    Attributes:
      observations: (T+1, obs_dim).
      actions: (T, act_dim).
      rewards: (T,).
      qpos: (T+1, nq); qvel: (T+1, nv); time: (T+1,).
      success: (T,) bool.
      goal: task goal arrays.
      seed: reset seed; reset_time [s]; reset_attempts.
      terminated: the last step ended the episode by a terminal state (not the time limit).
      source: who chose the actions (one of SOURCES); None: the file's source.
      label: what the actions are (one of LABELS); None: ``default_label(source)``.
    """

    observations: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    time: np.ndarray
    success: np.ndarray
    goal: dict[str, np.ndarray] = field(default_factory=dict)
    seed: int = -1
    reset_time: float = float("nan")
    reset_attempts: int = 0
    terminated: bool = False
    source: str | None = None
    label: str | None = None

    def __post_init__(self) -> None:
        if self.source is not None:
            check_choice("demonstration source", self.source, SOURCES)
        if self.label is not None:
            check_choice("demonstration label", self.label, LABELS)
        t = len(self.actions)
        shapes = {"observations": len(self.observations), "qpos": len(self.qpos),
                  "qvel": len(self.qvel), "time": len(self.time)}
        bad = {k: n for k, n in shapes.items() if n != t + 1}
        if bad or len(self.rewards) != t or len(self.success) != t:
            raise ConfigError(f"episode arrays inconsistent with {t} actions: {bad}, rewards "
                              f"{len(self.rewards)}, success {len(self.success)}")

    @property
    def length(self) -> int:
        return len(self.actions)


# how long an append waits for another process's hold on the file (HDF5 locks a file while it
# is open: another record-demos appending to it, or a reader); an append holds it for ms
APPEND_WAIT = 30.0


def _open_to_append(path: Path) -> h5py.File:
    """``h5py.File(path, "a")``, waiting while another process has the file open. Two
    record-demos into one file at once: an append meeting the other's append failed with HDF5's
    'unable to lock file' (BlockingIOError) and the episode just recorded was lost; now they
    take turns (each episode gets its own id: the count is read under the lock)."""
    import time

    deadline = time.monotonic() + APPEND_WAIT
    while True:
        try:
            return h5py.File(path, "a")
        except BlockingIOError:
            if time.monotonic() > deadline:
                raise InputError(f"{path} has been held open by another process for "
                                 f"{APPEND_WAIT:g} s (a program reading it, or writing it); "
                                 "close it, then record again") from None
            time.sleep(0.05)


class DemoWriter:
    """Appends episodes to an HDF5 demo file (created on the first append).

    Args:
      path: the file.
      info: its metadata; an existing file must carry the same.
      label_model: JSON-serializable description of how ``servo_goal`` labels were computed
        (``ServoResponse.to_dict()``), stored with every ``servo_goal`` episode.
    """

    def __init__(self, path: str | Path, info: DatasetInfo, label_model: dict | None = None):
        self.path = user_path(path)
        self.info = info
        self.label_model = label_model
        if self.path.exists():
            with open_dataset(self.path) as f:
                old = DatasetInfo.from_attrs(f.attrs)
            if (old.obs_dim, old.act_dim, old.action_joints, old.env_id) != (
                    info.obs_dim, info.act_dim, info.action_joints, info.env_id):
                raise ConfigError(f"{self.path} holds demos for {old.env_id} (obs {old.obs_dim},"
                                  f" act {old.act_dim}); cannot append {info.env_id} (obs "
                                  f"{info.obs_dim}, act {info.act_dim})")

    def append(self, ep: Episode) -> int:
        """Write one finished episode; returns its id."""
        if ep.observations.shape[1] != self.info.obs_dim or \
                ep.actions.shape[1] != self.info.act_dim:
            raise ConfigError(f"episode shapes {ep.observations.shape}, {ep.actions.shape} do "
                              f"not match obs_dim {self.info.obs_dim}, act_dim "
                              f"{self.info.act_dim}")
        for key in ("observations", "actions"):  # load_demos refuses the whole file after
            bad = np.argwhere(~np.isfinite(np.asarray(getattr(ep, key), np.float64)))
            if bad.size:
                t, j = (int(i) for i in bad[0])
                value = float(np.asarray(getattr(ep, key), np.float64)[t, j])
                raise ConfigError(f"episode {key}[{t}, {j}] = {value!r} is not finite: the "
                                  "episode is not written (a demo file holding it cannot be "
                                  "trained on)")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with _open_to_append(self.path) as f:
            if "format" not in f.attrs:
                f.attrs.update({"format": FORMAT, "format_version": FORMAT_VERSION,
                                "total_episodes": 0, "total_steps": 0, **self.info.attrs()})
            elif int(f.attrs.get("format_version", 1)) < FORMAT_VERSION:
                f.attrs["format_version"] = FORMAT_VERSION  # v1 episodes read the same in v2
            k = int(f.attrs["total_episodes"])
            name = f"episode_{k}"
            if name in f:  # an episode a crash left half-written: replace it
                del f[name]
            g = f.create_group(name)
            g.create_dataset("observations", data=np.asarray(ep.observations, np.float64))
            g.create_dataset("actions", data=np.asarray(ep.actions, np.float64))
            g.create_dataset("rewards", data=np.asarray(ep.rewards, np.float64))
            term = np.zeros(ep.length, bool)
            trunc = np.zeros(ep.length, bool)
            if ep.length:
                term[-1] = ep.terminated
                trunc[-1] = not ep.terminated
            g.create_dataset("terminations", data=term)
            g.create_dataset("truncations", data=trunc)
            infos = g.create_group("infos")
            for key in ("qpos", "qvel", "time"):
                infos.create_dataset(key, data=np.asarray(getattr(ep, key), np.float64))
            infos.create_dataset("success", data=np.asarray(ep.success, bool))
            goal = g.create_group("goal")
            for key, value in ep.goal.items():
                goal.create_dataset(key, data=np.asarray(value, np.float64))
            source = ep.source or self.info.source
            g.attrs.update({"id": k, "total_steps": ep.length,
                            "success": bool(ep.success[-1]) if ep.length else False,
                            "seed": int(ep.seed), "reset_time": float(ep.reset_time),
                            "reset_attempts": int(ep.reset_attempts),
                            "source": source, "label": ep.label or default_label(source)})
            if g.attrs["label"] == "servo_goal":
                if self.label_model is None:
                    raise ConfigError("a servo_goal episode needs the writer's label_model (the "
                                      "servo response its labels came from)")
                g.attrs["label_model"] = json.dumps(self.label_model)
            f.flush()
            f.attrs["total_episodes"] = k + 1
            f.attrs["total_steps"] = int(f.attrs["total_steps"]) + ep.length
            f.flush()
        return k


_EXPECTED = (f"an HDF5 demonstration dataset (format {FORMAT!r}, lowcostdex.demonstrations.file), as "
             "written by `lowcostdex record-demos` or lowcostdex.demonstrations.dataset.save_demos")


def _check_format(f: h5py.File, path: Path) -> None:
    fmt = f.attrs.get("format")
    if fmt != FORMAT:
        raise ConfigError(f"{path} is not {_EXPECTED}: its format attribute is {fmt!r}")
    version = int(f.attrs.get("format_version", -1))
    if version > FORMAT_VERSION:
        raise ConfigError(f"{path} has format version {version}; this lowcostdex reads up to "
                          f"{FORMAT_VERSION}")


def open_dataset(path: str | Path) -> h5py.File:
    """Open a demo file read-only, after checking it is one.

    Raises:
      InputError: the file is missing, unreadable, not HDF5 (e.g. an old NPZ demo file), cut
        short or corrupt, not of this format, or of a newer format version.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(f"a demonstration file is given by its path (.h5), not "
                         f"{type(path).__name__}")
    path = user_path(path)
    if not path.exists():
        raise InputError(f"demonstration file {path} does not exist")
    if path.is_dir():
        raise InputError(f"demonstration file {path} is a folder; give the .h5 file")
    try:
        if not h5py.is_hdf5(path):
            raise InputError(f"{path} is not {_EXPECTED}; it is not an HDF5 file")
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(f"{path} cannot be read as HDF5 (cut short or corrupt?): "
                         f"{_first_line(exc)}") from None
    try:
        _check_format(f, path)
    except ConfigError:
        f.close()
        raise
    return f


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0][:160] if text else type(exc).__name__


MAX_FIELD_VALUES = 10**8
"""Numbers per dataset of a demo file (800 MB as float64; an hour-long episode at 50 Hz with 100
observations holds 1.8e7): a gzip-compressed field of zeros takes almost nothing on disk, and
reading it first would fill the memory."""


def _read(group: h5py.Group, key: str, path: Path, kind: type | None = None) -> Any:
    """``group[key]`` (a dataset's array, or an attribute with ``kind`` given), or an
    InputError naming the file and the field."""
    where = f"{group.name.strip('/')}/{key}".strip("/")
    try:
        if kind is None:
            data = group[key]
            if isinstance(data, h5py.Dataset) and data.size > MAX_FIELD_VALUES:
                raise InputError(f"{path}: {where} has shape {data.shape}, {data.size} values; "
                                 f"a demo field holds at most {MAX_FIELD_VALUES:.0e}")
            return data[()]
        return kind(group.attrs[key])
    except KeyError:
        raise InputError(f"{path}: {where} is missing") from None
    except InputError:
        raise
    except (OSError, RuntimeError) as exc:  # h5py: data cut short or corrupt
        raise InputError(f"{path}: {where} cannot be read (cut short or corrupt?): "
                         f"{_first_line(exc)}") from None
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: {where} is not a {kind.__name__ if kind else 'dataset'}: "
                         f"{_first_line(exc)}") from None


def read_info(path: str | Path) -> tuple[DatasetInfo, int, int]:
    """(metadata, total episodes, total steps) of a demo file (InputError naming a missing or
    unreadable attribute: was a bare KeyError from h5py)."""
    with open_dataset(path) as f:
        path = user_path(path)
        kinds = {"env_id": str, "task": str, "hand": str, "source": str, "control_period": float,
                 "obs_dim": int, "act_dim": int, "action_joints": str, "total_episodes": int,
                 "total_steps": int}
        a = {key: _read(f, key, path, kind) for key, kind in kinds.items()}
        try:
            joints = json.loads(a["action_joints"])
        except ValueError:
            joints = None
        if not isinstance(joints, list):
            raise InputError(f"{path}: action_joints is not a JSON list of joint names: "
                             f"{a['action_joints'][:60]!r}")
        a["action_joints"] = json.dumps(joints)
        return DatasetInfo.from_attrs(a), a["total_episodes"], a["total_steps"]


def read_label_model(path: str | Path, episode: int | None = None) -> dict | None:
    """How an episode's ``servo_goal`` labels were computed (``label_model``): of episode
    ``episode``, or of the file's first such episode; None if it has none."""
    with open_dataset(path) as f:
        path = user_path(path)
        total = _read(f, "total_episodes", path, int)
        if episode is not None and not (isinstance(episode, int) and 0 <= episode < total):
            raise InputError(f"{path}: no episode {episode!r}; it holds episodes 0 to "
                             f"{total - 1} (total_episodes {total})")
        for k in range(total) if episode is None else [episode]:
            group = f.get(f"episode_{k}")
            if group is None:
                raise InputError(f"{path}: episode_{k} is missing (total_episodes is {total})")
            text = group.attrs.get("label_model")
            if text is not None:
                return json.loads(text)
    return None


def read_episodes(path: str | Path, only_successful: bool = False) -> list[Episode]:
    """Every complete episode in the file (those counted in ``total_episodes``).

    Raises:
      InputError: see :func:`open_dataset`; or a field missing, unreadable, or of a shape
        that does not match the file's ``obs_dim``/``act_dim`` and the episode's length (the
        message names the file and the field).
    """
    return [ep for _, ep in read_numbered_episodes(path, only_successful)]


def read_numbered_episodes(path: str | Path, only_successful: bool = False
                           ) -> list[tuple[int, Episode]]:
    """:func:`read_episodes` with each episode's number k (its group ``episode_<k>``)."""
    out = []
    with open_dataset(path) as f:  # refuses what is not a path first
        path = user_path(path)
        file_source = _read(f, "source", path, str)
        dims = {"observations": _read(f, "obs_dim", path, int),
                "actions": _read(f, "act_dim", path, int)}
        for k in range(_read(f, "total_episodes", path, int)):
            try:
                g = f.get(f"episode_{k}")
            except (OSError, RuntimeError) as exc:
                raise InputError(f"{path}: episode_{k} cannot be read (cut short or "
                                 f"corrupt?): {_first_line(exc)}") from None
            if not isinstance(g, h5py.Group):
                raise InputError(f"{path}: episode_{k} is missing (total_episodes is "
                                 f"{int(f.attrs['total_episodes'])})")
            if only_successful and not _read(g, "success", path, bool):
                continue
            out.append((k, _read_episode(g, path, file_source, dims)))
    return out


def _read_episode(g: h5py.Group, path: Path, file_source: str, dims: dict[str, int]
                  ) -> Episode:
    arrays = {key: np.asarray(_read(g, key, path)) for key in
              ("observations", "actions", "rewards", "terminations")}
    infos = {key: np.asarray(_read(g, f"infos/{key}", path))
             for key in ("qpos", "qvel", "time", "success")}
    for key, width in dims.items():
        shape = arrays[key].shape
        if len(shape) != 2 or shape[1] != width:
            raise InputError(f"{path}: {g.name.strip('/')}/{key} has shape {shape}; the file's "
                             f"{'obs_dim' if key == 'observations' else 'act_dim'} is {width}")
    goal = g.get("goal")
    source = str(g.attrs.get("source", file_source))
    try:
        return Episode(
            observations=arrays["observations"], actions=arrays["actions"],
            rewards=arrays["rewards"], qpos=infos["qpos"], qvel=infos["qvel"],
            time=infos["time"], success=infos["success"],
            goal={key: _read(goal, key, path) for key in goal} if goal is not None else {},
            seed=_read(g, "seed", path, int), reset_time=_read(g, "reset_time", path, float),
            reset_attempts=_read(g, "reset_attempts", path, int),
            terminated=bool(arrays["terminations"][-1]) if len(arrays["actions"]) else False,
            source=source, label=str(g.attrs.get("label", default_label(source))))
    except ConfigError as exc:  # inconsistent lengths, unknown source or label
        raise InputError(f"{path}: {g.name.strip('/')}: {exc}") from None


def read_demo_pairs(path: str | Path, only_successful: bool = False
                    ) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(observations (T, obs_dim), actions (T, act_dim)), ...] for BC/DAPG.

    The observation paired with ``a_t`` is ``o_t``; the final observation ``o_T`` is dropped.
    """
    return [(ep.observations[:-1], ep.actions) for ep in read_episodes(path, only_successful)]
