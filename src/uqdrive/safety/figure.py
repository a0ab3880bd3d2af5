"""The offline-safety figures: where the car drove, as hexagons of visits on the road, one cell or a grid."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.collections import PolyCollection
from matplotlib.colors import LogNorm

from uqdrive.figures import panel_grid

VISITS = "viridis"  # the colour map of visits per hexagon (`safety_hexbin`)


def safety_hexbin(
    ax: plt.Axes,
    x: np.ndarray,
    y: np.ndarray,
    route: np.ndarray,
    boundaries: tuple[np.ndarray, np.ndarray] | None,
    extent: tuple[float, float, float, float],
    title: str,
    road: np.ndarray | None = None,
) -> PolyCollection | None:
    """The paper's offline-safety panel: where the rollouts drove (visits per hexagon, log colour scale) on the
    road map, the reference trajectory and the safe set's edges, so unsafe paths show as mass outside the edges.
    Returns the hexagons (None when no position is inside) for a colour bar (`visits_colour_bar`)."""
    if road is not None and road.size:  # an empty raster: a world whose road uqdrive does not know
        ax.imshow(road, extent=extent, origin="lower", cmap="gray", vmin=-1.5, vmax=2.5, interpolation="nearest")
    inside = (x >= extent[0]) & (x <= extent[1]) & (y >= extent[2]) & (y <= extent[3])
    hexagons = None
    if inside.any():
        hexagons = ax.hexbin(x[inside], y[inside], gridsize=60, extent=extent, norm=LogNorm(), cmap=VISITS, mincnt=1)
    if len(route):  # none in a world whose road uqdrive does not know
        ax.plot(route[:, 0], route[:, 1], "w--", lw=1.0, label="reference")
    if boundaries is not None:
        for edge in boundaries:
            ax.plot(edge[:, 0], edge[:, 1], "r-", lw=0.8)
        ax.plot([], [], "r-", lw=0.8, label="safe-set boundary")
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.set_facecolor("0.15")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    return hexagons


def visits_colour_bar(fig: plt.Figure, hexagons: list[PolyCollection], axes: list[plt.Axes]) -> None:
    """One log-scale colour bar for every panel's hexagons: panels share the scale, so their colours compare."""
    if not hexagons:
        return
    top = max(float(h.get_array().max()) for h in hexagons)
    norm = LogNorm(vmin=1.0, vmax=max(top, 10.0))
    for h in hexagons:
        h.set_norm(norm)
    bar = fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=VISITS), ax=axes, fraction=0.03, pad=0.02)
    bar.set_label("visits per hexagon (log scale)", fontsize=9)
    bar.ax.tick_params(labelsize=8)


def safety_hexbin_grid(
    panels: dict[tuple[str, str], dict[str, np.ndarray]], rows: list[str], columns: list[str], title: str
) -> plt.Figure:
    """Method × weather grid of `safety_hexbin` panels; ``panels[(row, column)]`` holds x, y, route,
    left, right (empty left/right: road-only safe set) and eta1; missing cells stay blank."""
    fig, axes = plt.subplots(len(rows), len(columns), figsize=(3.4 * len(columns), 3.3 * len(rows)), squeeze=False)
    hexagons = []
    for ax, row, column, panel in panel_grid(axes, panels, rows, columns):
        boundaries = (panel["left"], panel["right"]) if len(panel["left"]) else None
        extent = tuple(float(v) for v in panel["extent"])
        drawn = safety_hexbin(
            ax,
            panel["x"],
            panel["y"],
            panel["route"],
            boundaries,
            extent,
            f"{row} · {column}: η̂1 = {float(panel['eta1']):.2f}",
            panel.get("road"),
        )
        hexagons += [drawn] if drawn is not None else []
    axes[0, 0].legend(loc="lower left", fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    visits_colour_bar(fig, hexagons, axes.ravel().tolist())
    return fig
