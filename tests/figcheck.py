"""Checks a reader's eye makes of a matplotlib figure, read from the figure objects: every axes
that shows data has x and y labels, the figure or each axes has a title, and no legend covers a
plotted point or bar."""

from __future__ import annotations

import numpy as np


def _data_points(ax) -> np.ndarray:
    pts = []
    for line in ax.get_lines():
        xy = np.asarray(line.get_xydata(), float)
        xy = xy[np.isfinite(xy).all(axis=1)]
        if len(xy):
            d = ax.transData.transform(xy)
            if line.get_linestyle() not in ("None", "", " ") and len(d) > 1:
                # the drawn segments too, not only their vertices
                s = np.linspace(0, 1, 12)[:, None, None]
                d = (d[:-1][None] * (1 - s) + d[1:][None] * s).reshape(-1, 2)
            pts.append(d)
    for patch in ax.patches:
        ext = patch.get_window_extent()
        if ext.width > 0 and ext.height > 0:   # a bar: its corners and centre
            pts.append(np.array([[ext.x0, ext.y0], [ext.x1, ext.y1], [ext.x0, ext.y1],
                                 [ext.x1, ext.y0], [(ext.x0 + ext.x1) / 2,
                                                    (ext.y0 + ext.y1) / 2]]))
    return np.concatenate(pts) if pts else np.zeros((0, 2))


def figure_problems(fig) -> list[str]:
    fig.canvas.draw()
    problems = []
    shown = [ax for ax in fig.axes if ax.axison and (ax.get_lines() or ax.patches)]
    has_suptitle = fig._suptitle is not None and fig._suptitle.get_text()
    for i, ax in enumerate(shown):
        if not ax.get_xlabel() and not any(a.get_xlabel() for a in shown
                                           if a.get_subplotspec() and ax.get_subplotspec() and
                                           a.get_subplotspec().colspan == ax.get_subplotspec()
                                           .colspan):
            problems.append(f"axes {i} has no x label")
        if not ax.get_ylabel():
            problems.append(f"axes {i} ({ax.get_title()!r}) has no y label")
        if not (has_suptitle or ax.get_title()):
            problems.append(f"axes {i} has no title and the figure none")
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend()]
    for leg in legends:
        box = leg.get_window_extent()
        for i, ax in enumerate(shown):
            p = _data_points(ax)
            inside = ((p[:, 0] > box.x0) & (p[:, 0] < box.x1) & (p[:, 1] > box.y0)
                      & (p[:, 1] < box.y1))
            if inside.any():
                problems.append(f"a legend covers {int(inside.sum())} data points of axes {i}")
    return problems
