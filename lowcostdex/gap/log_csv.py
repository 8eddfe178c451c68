"""Reading a CSV log of the project's format (``lowcostdex.gap.logs`` describes the columns)
into {column: float array}: the layouts spreadsheets and loggers write (a byte-order mark, blank
lines, '#' comments, tabs, a trailing ',' on every row, ';' separators with decimal commas,
UTF-16 "Unicode text", an ANSI export's 8-bit text, a torque_enable logged as True/False, a last
row cut short by a logger stopped mid-write: dropped with a note), refused with the fix named when
it cannot be read (other rows of another length, a word in a channel); a column of text that is
not a channel (a user's 'mode' or 'note') is left out with a note.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from lowcostdex.gap.log_checks import PLAUSIBLE, PREFIXES_ACTUATOR, PREFIXES_JOINT
from lowcostdex.gap.trajectory import LogError

MAX_COLUMNS = 1024
"""Columns per log: a 16-joint hand logs about 113 (7 channels a joint and the time); bounds the
memory a log may ask for, with ``log_checks.MAX_SAMPLES``."""


def read_csv(path: Path, max_rows: int) -> tuple[dict[str, np.ndarray], list[str]]:
    """Rows streamed (at most ``max_rows``), a UTF-8 byte-order mark (spreadsheets) ignored,
    UTF-16 read by its byte-order mark, text in another 8-bit encoding (a spreadsheet's ANSI
    export: a 'ü' in a note) read as Latin-1 with a note (the numbers are ASCII either way).
    A column holding text that is not a log channel (a user's 'mode' or 'note') is left out
    with a note; text in a channel ('time', 'goal:...', 'qpos:...') is refused, naming the row."""
    try:
        return _read_csv(path, max_rows, _encoding(path))
    except UnicodeDecodeError:
        line = _not_text(path)
        cols, notes = _read_csv(path, max_rows, "latin-1")
        return cols, [f"{path.name}: line {line} is not UTF-8 text (a spreadsheet's ANSI "
                      "export?); read as Latin-1", *notes]


def _read_csv(path: Path, max_rows: int, encoding: str
              ) -> tuple[dict[str, np.ndarray], list[str]]:
    text: dict[int, tuple[int, str]] = {}  # column -> its first text cell (line, cell)
    stamps: dict[int, list[str]] = {}  # 'time' / 'goal_time' column -> its cells (dates?)
    commas = False  # a decimal comma seen in a ';'-separated file
    try:
        with open(path, newline="", encoding=encoding) as f:
            sep = _delimiter(f)
            raw = csv.reader(f, delimiter=sep)
            reader = (row for row in raw  # blank lines and '#' comments skipped
                      if (len(row) > 1 or (row and row[0].strip()))
                      and not row[0].lstrip().startswith("#"))
            header = [h.strip() for h in next(reader, [])]
            if not header:
                raise LogError(f"{path}: empty file (no header row)")
            if len(header) > MAX_COLUMNS:
                raise LogError(f"{path}: the header has {len(header)} columns; a log has at "
                               f"most {MAX_COLUMNS}")
            _check_no_units(path, header)
            trailing = len(header) > 1 and header[-1] == ""  # 'a,b,c,' (a logger's habit)
            if len(set(header)) != len(header):
                dup = sorted({h for h in header if header.count(h) > 1})
                raise LogError(f"{path}: duplicate columns {dup}")
            stamps = {c: [] for c, h in enumerate(header) if h.lower() in ("time", "goal_time")}
            parse = [_switch if h.partition(":")[0].strip().lower() == "torque_enable"
                     else _number for h in header]
            rows = []
            short: tuple[int, int] | None = None  # a row cut short: only the last may be
            for r, row in enumerate(reader):
                if short is not None:
                    raise LogError(f"{path}: row {short[0]} has {short[1]} fields, the "
                                   f"header has {len(header) - trailing}")
                if r >= max_rows:
                    raise LogError(f"{path}: more than {max_rows} rows; at most "
                                   f"{max_rows} per log (split the log into shorter ones)")
                if trailing and len(row) == len(header) and not row[-1].strip():
                    row = row[:-1]
                elif trailing:
                    raise LogError(f"{path}: row {raw.line_num} has a value under the "
                                   "header's empty last column")
                if len(row) < len(header) - trailing:  # the last row of a logger stopped
                    short = (raw.line_num, len(row))     # mid-write is dropped, said below
                    continue
                if len(row) != len(header) - trailing:
                    raise LogError(f"{path}: row {raw.line_num} has {len(row)} fields, the "
                                   f"header has {len(header) - trailing}")
                if sep == ";":  # a spreadsheet's export where ',' is the decimal mark
                    commas = commas or any("," in cell for cell in row)
                    row = [cell.replace(",", ".") for cell in row]
                if r == 0:
                    _check_units_row(path, header, row, raw.line_num)
                for c, cells in stamps.items():
                    cells.append(row[c])
                try:
                    rows.append([p(cell) for p, cell in zip(parse, row, strict=False)])
                except ValueError:
                    for c, cell in enumerate(row):
                        if not _is_float(cell, parse[c]):
                            text.setdefault(c, (raw.line_num, cell))
                    rows.append([parse[c](cell) if c not in text else np.nan
                                 for c, cell in enumerate(row)])
    except csv.Error as exc:  # a field over the csv module's 128 kB: not a log's number
        raise LogError(f"{path}: not a CSV log (line {raw.line_num}: {exc})") from None
    header = header[:len(header) - trailing]
    data = np.array(rows, dtype=float).reshape(len(rows), len(header))
    notes = [f"{path.name}: columns separated by ';' (a spreadsheet's export)"
             + (", decimal commas read as points" if commas else "")] if sep == ";" else []
    if short is not None:
        notes.append(f"{path.name}: its last row (line {short[0]}) has {short[1]} of "
                     f"{len(header)} fields (a logger stopped mid-write?); dropped")
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


def _encoding(path: Path) -> str:
    """UTF-16 where the file opens with its byte-order mark (a spreadsheet's "Unicode text"
    export: UTF-16, tab-separated), else UTF-8 (a byte-order mark of its own skipped)."""
    with open(path, "rb") as f:
        head = f.read(2)
    return "utf-16" if head in (b"\xff\xfe", b"\xfe\xff") else "utf-8-sig"


def _not_text(path: Path) -> int:
    """The first line of ``path`` that is not UTF-8 (1-based); LogError for binary data (NUL
    or other control bytes), which no encoding makes a log."""
    with open(path, "rb") as f:
        head = f.read(65536)
        if b"\0" in head or sum(b < 9 or 13 < b < 32 for b in head) > len(head) // 100:
            raise LogError(f"{path}: not a text CSV file (binary data?)")
        f.seek(0)
        for number, line in enumerate(f, 1):
            try:
                line.decode("utf-8-sig" if number == 1 else "utf-8")
            except UnicodeDecodeError:
                return number
    return 0


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


def _check_no_units(path: Path, header: list[str]) -> None:
    """A channel's name with a unit in it ('qpos:j [deg]', 'time (s)', a spreadsheet's habit):
    'time [s]' was a "missing column 'time'", and 'qpos:j [deg]' a joint named 'j [deg]' whose
    values were read as radians. Refused, naming the column to write and the unit it is in."""
    for column in header:
        name = column.rstrip()
        if not name.endswith(("]", ")")):
            continue
        opening = name.rfind("[" if name.endswith("]") else "(")
        bare, unit = name[:opening].strip(), name[opening + 1:-1].strip()
        if opening <= 0 or not bare or not is_channel(bare):
            continue
        kind = bare.partition(":")[0].strip().lower()
        si = "s" if kind in ("time", "goal_time") else PLAUSIBLE.get(kind, (0, 0, "SI units"))[2]
        raise LogError(f"{path}: column {column!r} has a unit in its name; name it {bare!r} "
                       f"and write its values in {si}" + (
                           " (degrees times pi/180)" if unit.lower().startswith("deg")
                           and si.startswith("rad") else "")
                       + ": a log's columns carry no units, each kind has its own (time s, "
                       "positions rad, velocities rad/s, current A, voltage V)")


def _check_units_row(path: Path, header: list[str], row: list[str], line: int) -> None:
    """A first row of words under every channel (a spreadsheet's units row 's, rad, rad'): it
    was "row 2, column 'time': 's' is not a number". Refused, naming it a units row, the units a
    log is read in, and the options for a log in degrees or milliseconds."""
    cells = {h: cell.strip() for h, cell in zip(header, row, strict=False) if is_channel(h)}
    if not cells or not all(cell and not _is_float(cell) for cell in cells.values()):
        return
    words = {cell.lower().strip("[]() ") for cell in cells.values()}
    time = next((c.lower().strip("[]() ") for h, c in cells.items() if h.lower() == "time"), "")
    add = (["--units deg"] if words & {"deg", "degree", "degrees", "°"} else []) + (
        [f"--time-unit {time}"] if time in ("ms", "us", "ns") else [])
    raise LogError(f"{path}: row {line} holds words under every channel "
                   f"({', '.join(cells.values())}), not numbers: a units row? Delete it: a "
                   "log's columns carry no units, each kind has its own (time s, positions "
                   "rad, velocities rad/s, current A, voltage V)"
                   + (f"; to read its numbers in the units it names, add {' '.join(add)}"
                      if add else ""))


def is_channel(column: str) -> bool:
    """'time', 'goal_time' or '<kind>:<name>' of a known kind (any case, spaces around ':')."""
    kind, sep, _ = (part.strip().lower() for part in column.partition(":"))
    return kind in PREFIXES_ACTUATOR + PREFIXES_JOINT if sep else kind in ("time", "goal_time")


def _delimiter(f) -> str:
    """',' or, for a header holding no ',', tab (a tab-separated export) or ';' (a spreadsheet's
    export where ',' is the decimal mark); ``f`` is left at its start."""
    for line in f:
        if line.strip() and not line.lstrip().startswith("#"):
            f.seek(0)
            if "," in line:
                return ","
            return "\t" if "\t" in line else ";" if ";" in line else ","
    f.seek(0)
    return ","


MISSING = frozenset(("#N/A", "#N/A N/A", "#NA", "-1.#IND", "-1.#QNAN", "-NaN", "-nan", "1.#IND",
                     "1.#QNAN", "<NA>", "N/A", "NA", "NULL", "NaN", "None", "n/a", "nan", "null"))
"""Cells that mean "no value" (pandas.read_csv's default ``na_values``: a spreadsheet's #N/A,
R's NA, a JSON null, Python's None): read as an empty cell (a failed read: the row's repair in
``log_checks`` drops it, or fills an optional channel)."""


def _number(cell: str) -> float:
    """A cell's number; NaN for an empty or ``MISSING`` cell; ValueError for other text."""
    cell = cell.strip()
    return np.nan if not cell or cell in MISSING else float(cell)


SWITCH_WORDS = {"true": 1.0, "false": 0.0, "on": 1.0, "off": 0.0}
"""A torque_enable cell as a logger writes a bool (Python's and pandas' True/False, JSON's
true/false, a spreadsheet's TRUE/FALSE, on/off)."""


def _switch(cell: str) -> float:
    """A torque_enable cell: a number, or a bool written as a word (``SWITCH_WORDS``)."""
    word = SWITCH_WORDS.get(cell.strip().lower())
    return _number(cell) if word is None else word


def _is_float(cell: str, parse=_number) -> bool:
    try:
        parse(cell)
    except ValueError:
        return False
    return True


def may_be_log(path: Path, min_rows: int) -> bool:
    """Whether a CSV file in a folder of logs may be a log: its header names a 'goal:' or
    'qpos:' column (any case), or it has at least ``min_rows`` rows (a log with misspelled
    columns is read, and refused naming them). A folder of logs may hold the user's other
    short tables (a calibration's 'joint,offset', an events list): those are no log.
    Unreadable files count as logs (``read_csv`` then says what is wrong)."""
    try:
        with open(path, newline="", encoding=_encoding(path)) as f:
            sep = _delimiter(f)
            rows = (r for r in csv.reader(f, delimiter=sep)
                    if r and any(c.strip() for c in r) and not r[0].lstrip().startswith("#"))
            header = next(rows, [])
            if any(c.partition(":")[0].strip().lower() in ("goal", "qpos") and ":" in c
                   for c in header):
                return True
            return sum(1 for _, _ in zip(range(min_rows), rows, strict=False)) >= min_rows
    except (UnicodeDecodeError, csv.Error, OSError):
        return True
