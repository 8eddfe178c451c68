"""Reading a CSV log of the project's format (``lowcostdex.gap.logs`` describes the columns)
into {column: float array}: the layouts spreadsheets and loggers write (a byte-order mark, blank
lines, '#' comments, tabs, a trailing ',' on every row), refused with the fix named when it
cannot be read (';' separators, rows of another length, a word in a channel); a column of text
that is not a channel (a user's 'mode' or 'note') is left out with a note.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from lowcostdex.gap.log_checks import PREFIXES_ACTUATOR, PREFIXES_JOINT
from lowcostdex.gap.trajectory import LogError

MAX_COLUMNS = 1024
"""Columns per log: a 16-joint hand logs about 113 (7 channels a joint and the time); bounds the
memory a log may ask for, with ``log_checks.MAX_SAMPLES``."""


def read_csv(path: Path, max_rows: int) -> tuple[dict[str, np.ndarray], list[str]]:
    """Rows streamed (at most ``max_rows``), a UTF-8 byte-order mark (spreadsheets) ignored.
    A column holding text that is not a log channel (a user's 'mode' or 'note') is left out
    with a note; text in a channel ('time', 'goal:...', 'qpos:...') is refused, naming the row."""
    text: dict[int, tuple[int, str]] = {}  # column -> its first text cell (line, cell)
    stamps: dict[int, list[str]] = {}  # 'time' / 'goal_time' column -> its cells (dates?)
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            raw = csv.reader(f, delimiter=_delimiter(f))
            reader = (row for row in raw  # blank lines and '#' comments skipped
                      if (len(row) > 1 or (row and row[0].strip()))
                      and not row[0].lstrip().startswith("#"))
            header = [h.strip() for h in next(reader, [])]
            if not header:
                raise LogError(f"{path}: empty file (no header row)")
            if len(header) > MAX_COLUMNS:
                raise LogError(f"{path}: the header has {len(header)} columns; a log has at "
                               f"most {MAX_COLUMNS}")
            if len(header) == 1 and ";" in header[0]:  # ';' may come with decimal commas
                raise LogError(f"{path}: the header {header[0]!r} is separated by ';'; the log "
                               "format separates columns by ',' (and uses '.' for decimals)")
            trailing = len(header) > 1 and header[-1] == ""  # 'a,b,c,' (a logger's habit)
            if len(set(header)) != len(header):
                dup = sorted({h for h in header if header.count(h) > 1})
                raise LogError(f"{path}: duplicate columns {dup}")
            stamps = {c: [] for c, h in enumerate(header) if h.lower() in ("time", "goal_time")}
            rows = []
            for r, row in enumerate(reader):
                if r >= max_rows:
                    raise LogError(f"{path}: more than {max_rows} rows; at most "
                                   f"{max_rows} per log (split the log into shorter ones)")
                if trailing and len(row) == len(header) and not row[-1].strip():
                    row = row[:-1]
                elif trailing:
                    raise LogError(f"{path}: row {raw.line_num} has a value under the "
                                   "header's empty last column")
                if len(row) != len(header) - trailing:
                    raise LogError(f"{path}: row {raw.line_num} has {len(row)} fields, the "
                                   f"header has {len(header) - trailing}")
                for c, cells in stamps.items():
                    cells.append(row[c])
                try:
                    rows.append([float(cell) if cell.strip() else np.nan for cell in row])
                except ValueError:
                    for c, cell in enumerate(row):
                        if not _is_float(cell):
                            text.setdefault(c, (raw.line_num, cell))
                    rows.append([float(cell) if cell.strip() and c not in text else np.nan
                                 for c, cell in enumerate(row)])
    except UnicodeDecodeError:
        raise LogError(f"{path}: not a text CSV file (binary data?)") from None
    except csv.Error as exc:  # a field over the csv module's 128 kB: not a log's number
        raise LogError(f"{path}: not a CSV log (line {raw.line_num}: {exc})") from None
    header = header[:len(header) - trailing]
    data = np.array(rows, dtype=float).reshape(len(rows), len(header))
    notes = []
    for c, (line, cell) in sorted(text.items()):
        seconds = _dates(stamps[c]) if c in stamps else None
        if seconds is not None:  # pandas' to_csv of a DatetimeIndex, a logger's ISO stamps
            data[:, c] = seconds
            notes.append(f"{path.name}: column {header[c]!r} holds dates and times ({cell!r} "
                         f"in row {line}); read as seconds")
            continue
        if is_channel(header[c]):
            raise LogError(f"{path}: row {line}, column {header[c]!r}: {cell!r} is not a number")
        notes.append(f"{path.name}: column {header[c]!r} holds text ({cell!r} in row {line}), "
                     "not a log channel; left out")
    kept = [i for i in range(len(header)) if i not in text or i in stamps]
    return {header[i]: data[:, i] for i in kept}, notes


def _dates(cells: list[str]) -> np.ndarray | None:
    """ISO 8601 dates and times ('2026-11-28 01:02:03.125', 'T', a zone or 'Z') as POSIX
    seconds (no zone: read as UTC; only differences matter), empty cells NaN; None unless every
    other cell is one."""
    from datetime import datetime, timezone

    out = np.full(len(cells), np.nan)
    for i, cell in enumerate(cells):
        if cell.strip():
            try:
                t = datetime.fromisoformat(cell.strip())
            except ValueError:
                return None
            out[i] = (t if t.tzinfo else t.replace(tzinfo=timezone.utc)).timestamp()
    return out


def is_channel(column: str) -> bool:
    """'time', 'goal_time' or '<kind>:<name>' of a known kind (any case, spaces around ':')."""
    kind, sep, _ = (part.strip().lower() for part in column.partition(":"))
    return kind in PREFIXES_ACTUATOR + PREFIXES_JOINT if sep else kind in ("time", "goal_time")


def _delimiter(f) -> str:
    """',' or, for a header separated by tabs and holding no ',' (a tab-separated export), tab;
    ``f`` is left at its start."""
    for line in f:
        if line.strip() and not line.lstrip().startswith("#"):
            f.seek(0)
            return "\t" if "\t" in line and "," not in line else ","
    f.seek(0)
    return ","


def _is_float(cell: str) -> bool:
    try:
        float(cell) if cell.strip() else None
    except ValueError:
        return False
    return True
