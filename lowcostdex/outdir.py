"""Output folders that never destroy what the tool did not write.

Every command with ``--out`` goes through this module:

* a folder the tool writes carries a marker file (``.lowcostdex.json``: the command that wrote it
  and, optionally, the settings it was written with);
* an existing non-empty folder without the marker, or with another command's marker, is refused
  (the user's files stay where they are) and the message proposes a fresh sub-folder;
* :func:`staged_output` writes a whole output into a temporary sibling folder and moves it into
  place at the end; a previous output of the same command is not deleted but moved into
  ``previous/<UTC time>/`` inside the new one, so an interrupted or failed run leaves the old
  output untouched and a finished one keeps the old one for comparison;
* :func:`archive` does the same for single files of a folder that is written stage by stage
  (the main job).

Nothing here ever calls ``rmtree`` on a path it did not create in the same call.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import tempfile
import time
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from lowcostdex.errors import LowcostdexError, PathTypeError

MARKER = ".lowcostdex.json"
PREVIOUS = "previous"


def user_path(path: str | os.PathLike[str]) -> Path:
    """``path`` as a :class:`~pathlib.Path`, a leading ``~`` or ``~user`` read as that home folder,
    as the shell and the CLI read it. Every Python entry point that takes a path from a user
    (``train(out_dir=...)``, ``write_report``, ``save_demos``, ``load_demos``, ``load_policy``, log
    readers) goes through it: pathlib leaves ``"~/runs"`` alone, so a run went to a folder named
    ``~`` in the working folder, and a file under ``"~/..."`` was "not found"."""
    text = os.fspath(path) if isinstance(path, (str, os.PathLike)) else None
    if not isinstance(text, str):  # before: os.fspath's "expected str, bytes or os.PathLike"
        raise PathTypeError(f"a file or folder path (a str or pathlib.Path) is needed here, not "
                            f"{type(path).__name__}"
                            + (": no path was given" if path is None else f" {path!r:.40}"))
    if text.startswith("~"):
        return Path(os.path.expanduser(text))
    return Path(text)


class OutputRefused(LowcostdexError):
    """An ``--out`` folder holds files the tool did not write, or another run's settings."""


def read_marker(path: str | Path) -> dict[str, Any] | None:
    """The marker of an output folder, or None when there is none (or it is unreadable)."""
    marker = user_path(path) / MARKER
    try:
        data = json.loads(marker.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _is_empty(path: Path) -> bool:
    return not any(path.iterdir())


def check_out(path: str | Path, command: str, settings: Mapping[str, Any] | None = None,
              *, must_match: Iterable[str] = (),
              absent: Mapping[str, Any] | None = None) -> bool:
    """Check that ``path`` may receive ``command``'s output; True when it holds a previous one.

    Args:
      path: the ``--out`` folder.
      command: the command's name as a user types it, e.g. ``"gap analyze"``.
      settings: this run's settings (JSON-able); only the keys in ``must_match`` are compared.
      must_match: settings that must equal the previous output's (e.g. the seed of a run whose
        stages build on each other).
      absent: the value a ``must_match`` key stands for when a settings dict leaves it out (a
        setting written only when set); without it a key the previous output lacks is not
        compared (folders made before the setting existed).

    Raises:
      OutputRefused: ``path`` is a file, or a non-empty folder not written by ``command``, or a
        previous output whose ``must_match`` settings differ.
    """
    out = user_path(path)
    if out.exists() and not out.is_dir():
        raise OutputRefused(f"--out {out} is a file, not a folder; give a folder path")
    check_writable(out)
    if not out.exists() or _is_empty(out):
        return False
    marker = read_marker(out)
    fresh = out / f"{command.split()[-1]}-{time.strftime('%Y%m%d-%H%M%S')}"
    if marker is None:
        raise OutputRefused(
            f"--out {out} already holds files that lowcostdex did not write "
            f"({_listing(out)}); they are left untouched. Give an empty or new folder, "
            f"e.g. --out {shlex.quote(str(fresh))}")
    if marker.get("command") != command:
        raise OutputRefused(
            f"--out {out} holds the output of 'lowcostdex {marker.get('command')}', not of "
            f"'lowcostdex {command}'; it is left untouched. Give another folder, e.g. "
            f"--out {shlex.quote(str(fresh))}")
    old = marker.get("settings") or {}
    absent = absent or {}
    for key in must_match:
        if key not in old and key not in absent:
            continue
        was, now = old.get(key, absent.get(key)), (settings or {}).get(key, absent.get(key))
        if was != now:
            raise OutputRefused(
                f"--out {out} holds a run with {_difference(key, was, now)} and its stages "
                f"cannot build on that one. Use the same {key} or another folder, e.g. --out "
                f"{shlex.quote(str(fresh))}")
    return True


def _difference(key: str, was: object, now: object) -> str:
    """``key=was; this run has key=now``, or for two dicts only the entries that differ (a
    whole budget dict hides the one setting a user changed)."""
    if isinstance(was, dict) and isinstance(now, dict):
        parts = [f"{k}={was[k]!r} (this run: {now[k]!r})" if k in was and k in now else
                 f"{k}={was[k]!r} (this run: not set)" if k in was else
                 f"no {k} (this run: {k}={now[k]!r})"
                 for k in sorted(set(was) | set(now), key=str) if was.get(k) != now.get(k)
                 or (k in was) != (k in now)]
        return f"{key} differing in " + "; ".join(parts)
    return f"{key}={was!r}; this run has {key}={now!r}"


def check_writable(out: Path, option: str = "--out") -> None:
    """Refuse, before any work, an output that could not be written at the end: the folder
    when it exists, else the nearest existing path above it (where it will be made), which
    must be a folder (a path under a file cannot be made)."""
    where = out.resolve()
    while not where.exists() and where != where.parent:
        where = where.parent
    if where != out.resolve() and not where.is_dir():
        raise OutputRefused(f"{option} {out}: {where} is a file, not a folder, so nothing can "
                            "be written under it; give a path in a folder")
    if not os.access(where, os.W_OK | os.X_OK):
        raise OutputRefused(f"{option} {out}: no permission to write in {where}; give a folder "
                            "you can write to")


def check_file_folder(out: Path, option: str = "--out") -> None:
    """Refuse a single output file whose folder is missing, is a file, or cannot be written
    (checked before the work, not when the file is written at the end)."""
    if out.parent.exists() and not out.parent.is_dir():
        raise OutputRefused(f"{option} {out}: {out.parent} is a file, not a folder; give a path "
                            "in a folder")
    if not out.parent.is_dir():
        raise OutputRefused(f"{option} {out}: the folder {out.parent} does not exist")
    if not os.access(out.parent, os.W_OK | os.X_OK):
        raise OutputRefused(f"{option} {out}: no permission to write in {out.parent.resolve()}; "
                            "give a folder you can write to")


def _listing(path: Path, n: int = 3) -> str:
    names = sorted(p.name for p in path.iterdir())
    shown = ", ".join(names[:n])
    return shown + (f" and {len(names) - n} more" if len(names) > n else "")


def write_marker(path: str | Path, command: str,
                 settings: Mapping[str, Any] | None = None) -> None:
    """Write (atomically) the marker that says ``command`` wrote ``path``."""
    out = user_path(path)
    out.mkdir(parents=True, exist_ok=True)
    data = {"command": command, "settings": dict(settings or {}),
            "written": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}
    write_text_atomic(out / MARKER, json.dumps(data, indent=2))


def umask() -> int:
    """The process's file-mode creation mask (read by setting it and setting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def usual_mode(path: str | Path, fd: int | None = None, *, folder: bool = False) -> None:
    """Give a file (or, with ``folder``, a folder) made by ``tempfile`` the mode a plain
    ``open``/``mkdir`` gives: ``mkstemp`` makes 0600 files and ``mkdtemp`` 0700 folders, so
    an output written through them and moved into place was unreadable to the user's group
    and other users (a lab's shared run folder, a web server serving a report)."""
    mode = (0o777 if folder else 0o666) & ~umask()
    if fd is not None:
        os.fchmod(fd, mode)
    else:
        os.chmod(path, mode)


def write_bytes_atomic(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` so that readers see the old or the new file, never a mix (a
    temporary file beside it, flushed to disk, then ``os.replace``; a kill leaves the old file).
    ``path`` may start with ``~``; its folder is created when missing. The file gets the mode
    ``open`` would give it (0666 less the umask; ``mkstemp`` alone makes 0600)."""
    path = user_path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        usual_mode(tmp, fd)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """:func:`write_bytes_atomic` for text, written as UTF-8."""
    write_bytes_atomic(path, text.encode("utf-8"))


def _stamp(root: Path) -> Path:
    base = root / PREVIOUS / time.strftime("%Y%m%d-%H%M%S", time.gmtime())
    target, i = base, 1
    while target.exists():
        target, i = base.with_name(f"{base.name}-{i}"), i + 1
    return target


def archive(folder: str | Path, names: Iterable[str]) -> Path | None:
    """Move the entries ``names`` of ``folder`` that exist into ``folder/previous/<time>/``.

    Returns the archive folder, or None when none of them existed.
    """
    root = user_path(folder)
    present = [n for n in dict.fromkeys(names) if n and n != PREVIOUS and (root / n).exists()]
    if not present:
        return None
    target = _stamp(root)
    target.mkdir(parents=True)
    for name in present:
        dest = target / name
        dest.parent.mkdir(parents=True, exist_ok=True)
        os.replace(root / name, dest)
    return target


@contextmanager
def staged_output(path: str | Path, command: str,
                  settings: Mapping[str, Any] | None = None) -> Iterator[Path]:
    """Yield a temporary folder to write ``command``'s output into; move it to ``path`` at the end.

    The check (:func:`check_out`) runs before anything is written. On an exception nothing at
    ``path`` changes and the temporary folder is removed. On success a previous output of the
    same command at ``path`` is moved into ``path/previous/<time>/`` (its own ``previous/``
    history is carried over), never deleted. A link to a folder writes into the folder; the
    working folder (``--out .``) keeps its place: its entries are moved, not the folder.
    """
    out = user_path(path)
    had_previous = check_out(out, command, settings)
    # the folder itself, not a link to it nor "." (os.replace cannot replace either: '--out .'
    # in an empty folder and '--out link' ended in a traceback, the output left in a .partial)
    out = Path(os.path.realpath(out))
    out.parent.mkdir(parents=True, exist_ok=True)
    check_unfinished(out, command)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}{PARTIAL}", dir=out.parent))
    try:
        usual_mode(tmp, folder=True)
        claim(tmp, command)  # a live run's folder: not taken for a killed one's
        yield tmp
        write_marker(tmp, command, settings)
    except BaseException:
        release(tmp)
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    release(tmp)
    if out.exists() and had_previous and out == Path.cwd():
        # '--out .' again: moved whole, the user's shell would sit in previous/<time>/ and its
        # `ls` show the old output; the entries are swapped in place instead
        archive(out, [p.name for p in out.iterdir()])
        _move_entries(tmp, out)
        return
    if out.exists() and had_previous:
        keep = tmp / PREVIOUS
        if (out / PREVIOUS).is_dir():
            os.replace(out / PREVIOUS, keep)
        target = _stamp(tmp)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(out, target)
    elif out.exists():  # an empty folder (maybe a shell's working folder): filled in place
        _move_entries(tmp, out)
        return
    os.replace(tmp, out)


PARTIAL = ".partial-"
"""Infix of the folder a staged output is written into beside ``--out`` (``.NAME.partial-XXXX``)."""


def _held(path: Path) -> bool:
    """Whether a process holds ``path``'s writer's lock (:func:`claim`) right now."""
    try:
        import fcntl
    except ImportError:
        return False
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)
    return False


def check_unfinished(out: Path, command: str) -> None:
    """Refuse ``out`` while an unfinished staged output of an earlier run into it lies beside it
    (``.NAME.partial-XXXX``, no run writing it: the run was killed, or the machine went down,
    before it finished; Ctrl-C removes it). Before, the next run went ahead and left it there,
    hidden; stopped during its last moves it held the output that had been at ``out`` (in its
    ``previous/``), then lost from sight. The refusal says what it holds and what to type."""
    for left in sorted(out.parent.glob(f".{out.name}{PARTIAL}*")):
        if not left.is_dir() or _held(left):
            continue
        here, there = shlex.quote(str(left)), shlex.quote(str(out))
        history = (left / PREVIOUS).is_dir()
        if read_marker(left) is None:
            what = f"an unfinished output nothing reads; remove it with: rm -r {here}"
        elif not out.exists():
            what = (f"a finished output stopped in its last move (the output that was at --out "
                    f"is in its {PREVIOUS}/); put it in place with: mv {here} {there}")
        elif history:
            what = (f"a finished output stopped in its last moves, holding --out's {PREVIOUS}/ "
                    f"history; put that back with: mv {here}/{PREVIOUS} {there}/, then rm -r "
                    f"{here}")
        else:
            what = (f"a finished output never moved into place (--out is unchanged); remove it "
                    f"with: rm -r {here}")
        raise OutputRefused(
            f"--out {out}: {left.name} beside it was left by an earlier run into this folder "
            f"that was stopped before it finished (killed, or the machine went down; Ctrl-C "
            f"cleans up): {what}; then run 'lowcostdex {command}' again")


def _move_entries(src: Path, dest: Path) -> None:
    """Move every entry of ``src`` into the empty folder ``dest``, the marker last (a run
    stopped midway leaves files without it: refused, never taken for a finished output), then
    remove the empty ``src``."""
    names = sorted((p.name for p in src.iterdir()), key=lambda n: n == MARKER)
    for name in names:
        os.replace(src / name, dest / name)
    src.rmdir()


_HELD: dict[str, int] = {}
"""Folders this process holds the writer's lock of: real path -> the open folder's descriptor."""


def claim(path: str | Path, what: str, then: str = "") -> None:
    """Hold the writer's lock of the existing folder ``path`` (``flock`` on the folder itself:
    no file is added) until :func:`release` or the process ends. Another process holding it
    (the same ``train`` started twice, or ``--resume`` while the run still trains: both wrote
    its config, metrics and checkpoints in turn) is refused; this process may claim it again.
    Where there is no ``flock`` (Windows) or the file system refuses it, nothing is locked.
    ``what`` names the writer, ``then`` what to do after stopping it (the refusal says both).

    Raises:
      OutputRefused: another process holds the lock.
    """
    try:
        import fcntl
    except ImportError:
        return
    key = os.path.realpath(user_path(path))
    if key in _HELD:
        return
    fd = os.open(key, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise OutputRefused(f"{path} is being written by another process right now ({what}); "
                            f"it is left to it. Wait for it to end, or stop it first{then}"
                            ) from None
    except OSError:
        os.close(fd)
        return
    _HELD[key] = fd


def release(path: str | Path) -> None:
    """Let go of the lock :func:`claim` took on ``path`` (no-op when not held)."""
    fd = _HELD.pop(os.path.realpath(user_path(path)), None)
    if fd is not None:
        os.close(fd)


def check_out_file(path: str | Path, *, overwrite: bool = False) -> Path:
    """Check that a single output file may be written at ``path``.

    Raises:
      OutputRefused: ``path`` is a folder, its folder does not exist, or it exists and
        ``overwrite`` is False (the user's file is left untouched).
    """
    out = user_path(path)
    if out.is_dir():
        raise OutputRefused(f"--out {out} is a folder; give a file path")
    check_file_folder(out)
    if out.exists() and not overwrite:
        raise OutputRefused(f"--out {out} already exists and is left untouched; give a new file "
                            "name, or --overwrite to replace it")
    return out


def check_json_out(path: str | Path, command: str, keys: Iterable[str],
                   option: str = "--json") -> Path:
    """Check that ``option FILE`` may be written: a new file in an existing folder, or the
    command's own previous output (a JSON object holding every one of ``keys``), which is
    replaced. A user's other file is refused untouched, before the command does its work."""
    import json

    out = user_path(path)
    if out.is_dir():
        raise OutputRefused(f"{option} {out} is a folder; give a file path, e.g. "
                            f"{option} {out / 'summary.json'}")
    check_file_folder(out, option)
    if out.exists():
        try:
            old = json.loads(out.read_text())
        except (OSError, ValueError):
            old = None
        if not (isinstance(old, dict) and all(k in old for k in keys)):
            raise OutputRefused(f"{option} {out} already exists and is not a '{command}' output; "
                                "it is left untouched. Give a new file name")
    return out
