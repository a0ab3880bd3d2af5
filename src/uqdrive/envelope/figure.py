"""The envelope's map: regions coloured by verdict, phase one's rollouts as points (failures as crosses).

Two axes make one panel; with three, one panel per quarter of the third axis, each showing the regions that
cross the quarter's middle and the rollouts inside the quarter.
"""

from __future__ import annotations

from collections.abc import Sequence

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Patch, Rectangle

from uqdrive.envelope.certify import RegionResult
from uqdrive.envelope.space import Axis

COLOURS = {"safe": "#4daf4a", "unsafe": "#e41a1c", "undecided": "#bdbdbd"}
SLICES = 4  # panels along a third axis


def _scale(axis: Axis, unit: np.ndarray | float) -> np.ndarray | float:
    return axis.low + np.asarray(unit) * (axis.high - axis.low)


def _panel(
    ax: plt.Axes, axes: Sequence[Axis], results: Sequence[RegionResult], points: np.ndarray, outcomes: np.ndarray
) -> None:
    x_axis, y_axis = axes[0], axes[1]
    for r in results:
        (x0, y0), (x1, y1) = r.region.low[:2], r.region.high[:2]
        ax.add_patch(
            Rectangle(
                (_scale(x_axis, x0), _scale(y_axis, y0)),
                _scale(x_axis, x1) - _scale(x_axis, x0),
                _scale(y_axis, y1) - _scale(y_axis, y0),
                facecolor=COLOURS[r.verdict],
                edgecolor="white",
                linewidth=1.0,
                alpha=0.75,
            )
        )
        ax.text(
            _scale(x_axis, (x0 + x1) / 2),
            _scale(y_axis, (y0 + y1) / 2),
            f"{r.safe}/{r.rollouts}",
            ha="center",
            va="center",
            fontsize=6,
        )
    for outcome, marker, colour, size in ((1, "o", "black", 6), (0, "x", "black", 22)):
        chosen = points[outcomes == outcome]
        ax.scatter(_scale(x_axis, chosen[:, 0]), _scale(y_axis, chosen[:, 1]), marker=marker, s=size, c=colour, lw=0.8)
    ax.set_xlim(x_axis.low, x_axis.high)
    ax.set_ylim(y_axis.low, y_axis.high)
    ax.set_xlabel(x_axis.key)
    ax.set_ylabel(y_axis.key)


def envelope_figure(
    axes: Sequence[Axis],
    results: Sequence[RegionResult],
    points: np.ndarray,
    outcomes: np.ndarray,
    title: str,
) -> plt.Figure:
    """The map: ``results`` (regions with verdicts), ``points``/``outcomes``: phase one's rollouts (unit cube,
    1 = safe). Each region is labelled with its safe and total certification rollouts."""
    if len(axes) == 2:
        fig, ax = plt.subplots(figsize=(5.5, 4.8))
        _panel(ax, axes, results, points, outcomes)
        panels = [ax]
    else:
        fig, panels = plt.subplots(1, SLICES, figsize=(4.2 * SLICES, 4.4), sharey=True)
        edges = np.linspace(0.0, 1.0, SLICES + 1)
        for ax, lo, hi in zip(panels, edges[:-1], edges[1:]):
            middle = (lo + hi) / 2
            crossing = [r for r in results if r.region.low[2] <= middle < r.region.high[2]]
            inside = (points[:, 2] >= lo) & (points[:, 2] < hi if hi < 1 else points[:, 2] <= hi)
            _panel(ax, axes, crossing, points[inside], outcomes[inside])
            ax.set_title(f"{axes[2].key} in [{_scale(axes[2], lo):.3g}, {_scale(axes[2], hi):.3g}]", fontsize=9)
    handles = [Patch(facecolor=c, alpha=0.75, label=v) for v, c in COLOURS.items()]
    handles += [
        plt.Line2D([], [], marker="x", ls="", c="black", label="phase-one failure"),
        plt.Line2D([], [], marker="o", ms=3, ls="", c="black", label="phase-one safe run"),
    ]
    panels[-1].legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7)
    fig.suptitle(title, fontsize=10)
    return fig
