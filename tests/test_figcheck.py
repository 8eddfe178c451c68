"""The figure checker flags what a reader would trip over (so the figure tests can fail)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from figcheck import figure_problems  # noqa: E402


def test_flags_missing_labels_title_and_a_legend_over_data():
    fig, ax = plt.subplots()
    ax.plot([0, 1, 2, 3], [0, 1, 2, 3], "o-", label="data")
    ax.legend(loc="center")   # right over the middle of the diagonal
    problems = figure_problems(fig)
    assert any("no y label" in p for p in problems)
    assert any("no x label" in p for p in problems)
    assert any("no title" in p for p in problems)
    assert any("legend covers" in p for p in problems)
    plt.close(fig)


def test_a_clean_figure_passes():
    fig, ax = plt.subplots()
    ax.plot([0, 1, 2, 3], [0, 1, 2, 3], "o-", label="data")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("angle [rad]")
    ax.set_title("a ramp")
    ax.legend(loc="lower right")
    assert figure_problems(fig) == []
    plt.close(fig)
