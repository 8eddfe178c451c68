"""One row per iteration: the metric column names every trainer uses, the metrics CSV (append-only,
widening, safe against a kill) and the learning-curve plot."""

from __future__ import annotations

import csv
import io
import math
import os
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from lowcostdex.outdir import write_bytes_atomic, write_text_atomic

ITERATION = "iteration"
SAMPLES = "samples"
"""Cumulative environment steps used for learning (not counting evaluation rollouts)."""
ROBOT_HOURS = "robot_hours"
"""Cumulative robot wall-clock time [h]: control time of the samples plus resets and pauses."""
SUCCESS_RATE = "success_rate"
"""Fraction of the iteration's (stochastic) training trajectories that succeeded."""
RETURN_MEAN = "return_mean"
EVAL_SUCCESS_RATE = "eval_success_rate"
"""Fraction of deterministic (mean-action) evaluation trajectories that succeeded."""
EVAL_RETURN_MEAN = "eval_return_mean"
WALL_SECONDS = "time_elapsed"
"""Cumulative wall-clock time of the training [s] (sampling, updates, evaluations; a column
named ``time_*`` like the per-iteration timings, which reproducibility checks ignore)."""


# ----------------------------------------------------------------------------------------------
# Metrics


def _format_value(value: Any) -> str:
    if value is None:
        return "nan"
    if isinstance(value, (bool, np.bool_)):
        return str(int(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    torch = sys.modules.get("torch")  # a tensor exists only if torch was imported
    if torch is not None and isinstance(value, torch.Tensor) and value.numel() == 1:
        return repr(float(value.item()))
    if isinstance(value, str):
        return value
    raise TypeError(f"metric value {value!r} must be a number, bool, str or None")


def _read_rows(path: Path) -> list[list[str]]:
    """CSV rows of ``path``; a last line without its newline (cut by a kill) is dropped."""
    if not path.exists():
        return []
    text = path.read_text(encoding="utf-8")
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    return list(csv.reader(io.StringIO(text, newline="")))


def read_metrics(path: str | os.PathLike[str]) -> dict[str, np.ndarray]:
    """Read a metrics CSV into ``{column: (rows,) float64 array}``.

    A last line cut by a kill and rows whose field count does not match the header are
    skipped; non-numeric cells become NaN.
    """
    rows = _read_rows(Path(path))
    if not rows:
        return {}
    header, body = rows[0], [r for r in rows[1:] if len(r) == len(rows[0])]
    out: dict[str, np.ndarray] = {}
    for j, name in enumerate(header):
        values = []
        for row in body:
            try:
                values.append(float(row[j]))
            except ValueError:
                values.append(math.nan)
        out[name] = np.asarray(values, dtype=np.float64)
    return out


class MetricsLog:
    """Append-only CSV of one row per iteration with a fixed, growing set of columns.

    A key first seen after earlier rows were written widens the file (rewritten atomically,
    earlier rows get "nan"), so rows never misalign.
    """

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)
        self._columns: list[str] = []
        self._rows: list[list[str]] = []
        if self.path.exists():
            rows = _read_rows(self.path)
            if rows:
                self._columns = rows[0]
                self._rows = [r for r in rows[1:] if len(r) == len(self._columns)]
            self._rewrite()

    @property
    def columns(self) -> list[str]:
        return list(self._columns)

    def append(self, row: Mapping[str, Any]) -> None:
        """Append one row; keys absent from ``row`` are written as "nan"."""
        new = [k for k in row if k not in self._columns]
        cells = {k: _format_value(v) for k, v in row.items()}
        if new:
            self._columns += new
            self._rows = [r + ["nan"] * len(new) for r in self._rows]
        line = [cells.get(k, "nan") for k in self._columns]
        self._rows.append(line)
        if new or len(self._rows) == 1:
            self._rewrite()
        else:
            with self.path.open("a", newline="", encoding="utf-8") as f:
                csv.writer(f, lineterminator="\n").writerow(line)
                f.flush()
                os.fsync(f.fileno())

    def truncate(self, last_iteration: int | None) -> None:
        """Keep only rows with ``iteration <= last_iteration`` (all rows dropped if None)."""
        if ITERATION not in self._columns:
            self._rows = [] if last_iteration is None else self._rows
        else:
            j = self._columns.index(ITERATION)
            limit = -math.inf if last_iteration is None else last_iteration
            self._rows = [r for r in self._rows if float(r[j]) <= limit]
        self._rewrite()

    def _rewrite(self) -> None:
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        if self._columns:
            writer.writerow(self._columns)
        writer.writerows(self._rows)
        write_text_atomic(self.path, buf.getvalue())


# ----------------------------------------------------------------------------------------------
# Learning curves


def plot_learning_curves(
    metrics: Mapping[str, np.ndarray], png_path: str | os.PathLike[str], title: str = ""
) -> Path:
    """Plot success rate and return against samples and against robot hours; save a PNG.

    Args:
      metrics: columns as returned by :func:`read_metrics`; uses SAMPLES and (if present)
        ROBOT_HOURS as x axes, SUCCESS_RATE / EVAL_SUCCESS_RATE and RETURN_MEAN /
        EVAL_RETURN_MEAN as curves. Missing columns are skipped.
      png_path: output file.
      title: figure title.

    Returns:
      The PNG path.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    x_axes = [(SAMPLES, "samples (env steps)"), (ROBOT_HOURS, "robot time [h]")]
    x_axes = [(k, label) for k, label in x_axes if k in metrics and len(metrics[k])]
    rows = [
        (
            "success rate",
            [(SUCCESS_RATE, "training (stochastic)"), (EVAL_SUCCESS_RATE, "eval (mean action)")],
        ),
        (
            "return",
            [(RETURN_MEAN, "training (stochastic)"), (EVAL_RETURN_MEAN, "eval (mean action)")],
        ),
    ]
    n_cols = max(len(x_axes), 1)
    fig, axes = plt.subplots(2, n_cols, figsize=(5.5 * n_cols, 7), squeeze=False)
    for i, (ylabel, curves) in enumerate(rows):
        for j, (xkey, xlabel) in enumerate(x_axes):
            ax = axes[i][j]
            x = metrics[xkey]
            for ykey, label in curves:
                if ykey in metrics:
                    y = metrics[ykey]
                    ok = np.isfinite(x) & np.isfinite(y)
                    if ok.any():
                        ax.plot(x[ok], y[ok], marker="." if ok.sum() < 30 else None, label=label)
            ax.set_xlabel(xlabel)
            ax.set_ylabel(ylabel)
            ax.grid(alpha=0.3)
            if ax.lines:
                ax.legend(fontsize="small")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    write_bytes_atomic(png_path, buf.getvalue())
    return Path(png_path)
