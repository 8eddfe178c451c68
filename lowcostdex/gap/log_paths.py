"""Which log files a user's paths name: a file, a folder (its logs; the user's other files
in it passed over and said), a glob pattern the shell left unexpanded, or a list of them; and
which model file goes with logs named as one of the project's hands (``model_for``)."""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from lowcostdex.gap.log_checks import MIN_SAMPLES
from lowcostdex.gap.log_csv import may_be_log
from lowcostdex.gap.trajectory import LogError

LOG_SUFFIXES = (".csv", ".npz", ".json")


def expand_log_paths(paths: str | Path | Sequence[str | Path],
                     notes: list[str] | None = None, once: bool = False) -> list[Path]:
    """The log files meant by ``paths``: one path or a sequence of them, where each may be a
    file, a folder (its ``LOG_SUFFIXES`` files, sorted) or a glob pattern that the shell did
    not expand (``"logs/*.csv"``, sorted matches). Raises LogError when nothing is named, a
    folder holds no log or a pattern matches nothing. Hidden files (``.lowcostdex.json``, the
    marker ``record-log`` leaves) are not logs, nor are the JSON files of a folder that holds
    project-format logs (CSV/NPZ): a BAM log (JSON) cannot be analysed beside them, and such a
    JSON is the folder's own notes (``gap generate``'s truth.json); each left out is said in
    ``notes``. ``once``: a file named twice is refused (``named_once``)."""
    entries: list = []
    if isinstance(paths, (str, os.PathLike)):
        entries = [paths]
    elif isinstance(paths, Iterable) and not isinstance(paths, (Mapping, np.ndarray, bytes)):
        entries = list(paths)
    if not all(isinstance(p, (str, os.PathLike)) for p in entries) or (
            not entries and not isinstance(paths, (list, tuple))):
        raise LogError(f"logs are given as file paths (a path, a folder, a glob pattern or a "
                       f"list of them), not {type(paths).__name__}; write arrays to a file "
                       "first: lowcostdex.gap.write_log(path, Trajectory(...))")
    if not entries:
        raise LogError("no log files given")
    out: list[Path] = []
    for entry in entries:
        one = Path(entry)
        if one.is_dir():
            found = sorted(p for p in one.iterdir()  # not .lowcostdex.json (a marker)
                           if p.is_file() and not p.name.startswith(".")
                           and p.suffix.lower() in LOG_SUFFIXES)
            if not found:
                other = sorted(p.name for p in one.iterdir() if p.is_file()
                               and not p.name.startswith(".") and reads_as_csv_log(p))
                renamed = (f"; {', '.join(other[:3])}{' ...' if len(other) > 3 else ''} read "
                           "as CSV logs under another name: rename them .csv" if other else "")
                raise LogError(f"{one}: a folder without logs ({', '.join(LOG_SUFFIXES)})"
                               + renamed + _in_subfolders(one))
            if any(p.suffix.lower() != ".json" for p in found):
                json_files = [p for p in found if p.suffix.lower() == ".json"]
                found = [p for p in found if p.suffix.lower() != ".json"]
                if json_files and notes is not None:
                    notes.append(f"{one}: left out {', '.join(p.name for p in json_files)} (JSON "
                                 "beside project-format CSV/NPZ logs: not a log of them)")
                tables = [p for p in found if p.suffix.lower() == ".csv"  # the user's own
                          and not may_be_log(p, MIN_SAMPLES)]  # short tables
                found = [p for p in found if p not in tables]
                what = (f"no 'goal:' or 'qpos:' column and under {MIN_SAMPLES} rows")
                if tables and not found:
                    raise LogError(f"{one}: a folder without logs: its CSV files "
                                   f"{', '.join(p.name for p in tables)} have {what}")
                if tables and notes is not None:
                    notes.append(f"{one}: left out {', '.join(p.name for p in tables)} ({what}: "
                                 "not a log)")
            out += found
        elif not one.exists() and any(c in str(one) for c in "*?["):
            found = sorted(Path(p) for p in glob.glob(str(one)) if Path(p).is_file())
            if not found:
                raise LogError(f"{one}: no file matches this pattern")
            out += found
        else:
            out.append(one)
    return named_once(out) if once else out


def named_once(paths: list[Path]) -> list[Path]:
    """``paths`` unchanged when no file is in it twice; else LogError naming the file (the same
    log twice in one analysis is fitted twice and weighs double; a folder and a file in it, or
    two spellings of one path, count as twice). The CLI uses each file once with a note
    (``gap.cli.distinct_logs``); from Python the caller says which it meant."""
    seen: dict[Path, Path] = {}
    for p in paths:
        key = p.resolve()
        if key in seen:
            how = "" if str(seen[key]) == str(p) else f" (as {seen[key]} and as {p})"
            raise LogError(f"{p}: the same log given twice{how}; each log is fitted once: give "
                           "it once (a list of distinct files, or the folder alone)")
        seen[key] = p
    return paths


def _in_subfolders(folder: Path) -> str:
    """What to type when a folder's logs sit one level down (a session per subfolder): the
    folder's own files are read, not its subfolders'."""
    subs = sorted(d for d in folder.iterdir() if d.is_dir() and not d.name.startswith("."))
    holding = [d for d in subs if any(p.is_file() and not p.name.startswith(".")
                                      and p.suffix.lower() in LOG_SUFFIXES for p in d.iterdir())]
    if not holding:
        return ""
    names = ", ".join(d.name for d in holding[:4]) + (" ..." if len(holding) > 4 else "")
    return (f"; its subfolders {names} hold some (only a folder's own files are read): give "
            f"them, e.g. {' '.join(str(d) for d in holding[:2])}, or the pattern "
            f"'{folder / '*' / '*.csv'}'")


def no_such_log(path: Path) -> LogError:
    """The error for a log ``path`` that does not exist, with what the user may have meant: a
    pattern given to a reader of one file, the file under another case or with its suffix
    (``log0`` for ``log0.csv``), a near name in its folder, or a folder that is missing too."""
    path = Path(path)
    if any(c in path.name for c in "*?["):
        return LogError(f"{path}: no such file (a pattern: read_log reads one file; "
                        "load_dataset and `gap analyze --log` read the files a pattern matches)")
    folder = path.parent
    if not folder.is_dir():
        return LogError(f"{path}: no such file (its folder {folder} does not exist either)")
    names = sorted(p.name for p in folder.iterdir() if p.is_file()
                   and not p.name.startswith(".") and p.suffix.lower() in LOG_SUFFIXES)
    want = path.name.lower()
    close = [n for n in names if n.lower() == want or Path(n).stem.lower() == want]
    if not close:
        import difflib

        close = difflib.get_close_matches(path.name, names, n=2, cutoff=0.75)
    if not close:
        return LogError(f"{path}: no such file")
    return LogError(f"{path}: no such file; did you mean "
                    f"{' or '.join(repr(str(folder / n)) for n in close)}?")


def folder_not_log(path: Path) -> LogError:
    """The error for a folder given to a reader of one log file."""
    return LogError(f"{path}: is a folder, not a log file (read_log reads one file; "
                    f"load_dataset({str(path)!r}, model=...) and `gap analyze --log` read a "
                    "folder's logs)")


def reads_as_csv_log(path: Path) -> bool:
    """Whether a file of another suffix (.txt, .log, .dat) starts with a project-format CSV
    header: a 'time' column and a 'goal:' or 'qpos:' one, separated by ',', ';' or a tab."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096).decode("utf-8", "ignore").lstrip("\ufeff")
    except OSError:
        return False
    first = next((line for line in head.splitlines() if line.strip()
                  and not line.lstrip().startswith("#")), "").lower()
    cells = [c.strip().strip('"') for c in first.replace(";", ",").replace("\t", ",").split(",")]
    return "time" in cells and any(c.startswith(("qpos:", "goal:")) for c in cells)


def csv_under_another_name(path: Path) -> str:
    """The hint for a log file of an unknown suffix that reads as a CSV log ('' if not)."""
    if reads_as_csv_log(path):
        return f" (its first line is a CSV log header: rename it {path.with_suffix('.csv').name})"
    return ""


def model_path(model: object) -> Path:
    """``load_dataset``'s ``model``: the MJCF file's path (a leading ``~`` read as home), which
    must exist. A compiled ``MjModel`` or ``MjSpec`` (before: a bare TypeError from ``Path``)
    or the XML text itself (before: "no such model file" quoting the whole text) is refused
    naming what to pass."""
    if isinstance(model, str) and model.lstrip().startswith("<"):
        raise LogError("model: give the MJCF file's path, not its XML text; write the text to a "
                       "file first, e.g. pathlib.Path('robot.xml').write_text(xml)")
    if not isinstance(model, (str, os.PathLike)):
        raise LogError(f"model: give the MJCF file's path (a str or pathlib.Path), not "
                       f"{type(model).__name__}; save it to a file first, e.g. "
                       "pathlib.Path('robot.xml').write_text(spec.to_xml()) for a mujoco.MjSpec")
    path = Path(os.path.expanduser(os.fspath(model)))
    if not path.exists():
        raise LogError(f"{path}: no such model file")
    return path


HAND_NAMES = {  # the project's hands' actuator names (sim/models/dclaw.py, allegro.py)
    "dclaw": ("D'Claw", re.compile(r"(ff|mf|th)_(top|middle|bottom)")),
    "allegro": ("Allegro", re.compile(r"(index|middle|ring|thumb)_[0-3]")),
}


def model_for(actuators: tuple[str, ...]) -> str:
    """What model to give for a log whose actuators are named as one of the project's hands."""
    for hand, (title, pattern) in HAND_NAMES.items():
        fingers = [m.group(1) for a in actuators if (m := pattern.fullmatch(a))]
        if fingers and len(fingers) == len(actuators):
            return (f"its names are the {title}'s: `lowcostdex model {hand} --station none "
                    f"--fingers {','.join(dict.fromkeys(fingers))} --out {hand}.xml` writes "
                    "the model of those fingers")
    return ("give the MJCF of the robot that wrote the log (an actuator named as each 'goal:' "
            "column)")


def more_of_the_hand(names: tuple[str, ...]) -> str:
    """The hint for a log naming more of one of the project's hands than the model holds (a
    log of two fingers, a model of one): the model command of the log's fingers."""
    what = model_for(names)
    return f"; the log moves more of the hand than the model holds: {what}" if what.startswith(
        "its names") else ""
