"""Figures that stages log to MLflow and write beside their DVC plots."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.colors import LogNorm  # noqa: E402

from uqdrive.files import atomic_path  # noqa: E402

VISITS = "viridis"  # the colour map of visits per hexagon (`safety_hexbin`)


def save_figure(fig: plt.Figure, path: str | Path) -> Path:
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip("."), dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def mosaic(images: list[np.ndarray], columns: int = 4) -> np.ndarray:
    """Tile equally sized frames (RGB or gray) into one image, row by row; blanks fill the last row."""
    if not images:
        raise ValueError("mosaic needs at least one image")
    rows = -(-len(images) // columns)
    blank = np.zeros_like(images[0])
    tiles = list(images) + [blank] * (rows * columns - len(images))
    return np.vstack([np.hstack(tiles[r * columns : (r + 1) * columns]) for r in range(rows)])


def class_histogram_figure(centres: np.ndarray, counts: dict[str, np.ndarray], title: str) -> plt.Figure:
    """Side-by-side bars per split: shows at a glance how dominant 'straight ahead' is."""
    fig, ax = plt.subplots(figsize=(8, 3.5))
    width = 0.8 / len(counts)
    for i, (split, values) in enumerate(counts.items()):
        ax.bar(np.arange(len(centres)) + (i - (len(counts) - 1) / 2) * width, values, width, label=split)
    ax.set_xticks(np.arange(len(centres)), [f"{c:+.1f}" for c in centres], rotation=90)
    ax.set_xlabel("steering class centre (positive = left)")
    ax.set_ylabel("frames")
    ax.set_yscale("log")
    ax.set_title(title)
    ax.legend()
    return fig


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


def _panels(axes: np.ndarray, panels: dict[tuple[str, str], dict], rows: list[str], columns: list[str]):
    """(ax, row, column, panel) of a figure's grid of panels, row by row; cells without a panel are blanked."""
    for i, row in enumerate(rows):
        for j, column in enumerate(columns):
            panel = panels.get((row, column))
            if panel is None:
                axes[i, j].axis("off")
            else:
                yield axes[i, j], row, column, panel


def safety_hexbin_grid(
    panels: dict[tuple[str, str], dict[str, np.ndarray]], rows: list[str], columns: list[str], title: str
) -> plt.Figure:
    """Method × weather grid of `safety_hexbin` panels; ``panels[(row, column)]`` holds x, y, route,
    left, right (empty left/right: road-only safe set) and eta1; missing cells stay blank."""
    fig, axes = plt.subplots(len(rows), len(columns), figsize=(3.4 * len(columns), 3.3 * len(rows)), squeeze=False)
    hexagons = []
    for ax, row, column, panel in _panels(axes, panels, rows, columns):
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


def reliability_diagram(ax: plt.Axes, panel: dict[str, np.ndarray], title: str) -> None:
    """Accuracy per top-label confidence bin against the diagonal; the hatched gap to each bin's mean
    confidence is what the ECE averages (weighted by the share of frames, the dotted line)."""
    filled = panel["frames"] > 0
    low, width = panel["low"][filled], (panel["high"] - panel["low"])[filled]
    accuracy, confidence = panel["accuracy"][filled], panel["confidence"][filled]
    ax.bar(low, accuracy, width, align="edge", color="tab:blue", edgecolor="k", lw=0.4, label="accuracy")
    ax.bar(
        low,
        confidence - accuracy,
        width,
        bottom=accuracy,
        align="edge",
        fill=False,
        hatch="///",
        edgecolor="tab:red",
        lw=0.4,
        label="gap to mean confidence",
    )
    ax.plot(
        low + width / 2,
        panel["frames"][filled] / panel["frames"].sum(),
        "k:",
        marker=".",
        lw=0.8,
        label="share of frames",
    )
    ax.plot([0, 1], [0, 1], "k--", lw=0.8)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_title(title, fontsize=9)


def reliability_grid(
    panels: dict[tuple[str, str], dict[str, np.ndarray]], rows: list[str], columns: list[str], title: str
) -> plt.Figure:
    """Grid of `reliability_diagram` panels; ``panels[(row, column)]`` holds low, high, frames,
    confidence, accuracy (per bin) and ece."""
    fig, axes = plt.subplots(len(rows), len(columns), figsize=(3 * len(columns), 3 * len(rows)), squeeze=False)
    for ax, row, column, panel in _panels(axes, panels, rows, columns):
        reliability_diagram(ax, panel, f"{column} · {row}: ECE {panel['ece']:.3f}")
    for ax in axes[-1]:
        ax.set_xlabel("confidence")
    for ax in axes[:, 0]:
        ax.set_ylabel("accuracy")
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="lower center", ncol=3, fontsize=8)
    return fig


def condition_lines_figure(
    values: dict[str, dict[str, list[float | None]]], conditions: list[str], metrics: list[tuple[str, str]], title: str
) -> plt.Figure:
    """One panel per metric, conditions along x, one line per method (``values[method][metric]``, None
    where undefined): how each method's accuracy and uncertainty move away from the training condition."""
    columns = min(3, len(metrics))
    rows = -(-len(metrics) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4 * columns, 3 * rows), squeeze=False)
    x = np.arange(len(conditions))
    for ax, (metric, label) in zip(axes.flat, metrics):
        for method, by_metric in values.items():
            ax.plot(x, [np.nan if v is None else v for v in by_metric[metric]], marker="o", label=method)
        ax.set_xticks(x, conditions, rotation=30, ha="right", fontsize=8)
        ax.set_title(label, fontsize=9)
    for ax in axes.flat[len(metrics) :]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def avoid_trajectories(ax: plt.Axes, panel: dict, title: str, vmax: float = 1.0):
    """The paper's collision-avoidance panel: each path on the obstacle road coloured by the mutual
    information of the frame seen there; × marks a collision, ■ a hand-over (stopped). Returns the
    colour mapping for a colour bar. ``panel``: paths (x, y, mi, termination), obstacle (x, y,
    length, width), road (x from, x to, right edge, centre line, left edge); both empty in a Gymnasium world (its
    road is the env's: the paths alone, at equal scale)."""
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Rectangle

    road, obstacle = np.asarray(panel["road"]), np.asarray(panel["obstacle"])
    if road.size:
        ax.axhspan(road[2], road[4], color="0.35", zorder=0)
        ax.axhline(road[3], color="w", ls="--", lw=0.8, zorder=1)
    if obstacle.size:
        ox, oy, length, width = obstacle
        ax.add_patch(Rectangle((ox - length / 2, oy - width / 2), length, width, color="tab:red", zorder=3))
    norm = plt.Normalize(0.0, vmax)
    xs = [0.0]
    for path in panel["paths"]:
        x, y, mi = (np.asarray(path[k], float) for k in ("x", "y", "mi"))
        if len(x) >= 2:
            segments = np.stack([np.stack([x[:-1], y[:-1]], 1), np.stack([x[1:], y[1:]], 1)], axis=1)
            ax.add_collection(LineCollection(segments, array=mi[:-1], cmap="plasma", norm=norm, lw=1.2, zorder=4))
        if len(x):
            xs.append(float(x.max()))
            marker = {"collision": ("x", "tab:red"), "handover": ("s", "orange")}.get(path["termination"])
            if marker:
                ax.plot(x[-1], y[-1], marker[0], color=marker[1], ms=5, mec="k", mew=0.5, zorder=5)
    if road.size:
        starts = [float(np.min(p["x"])) for p in panel["paths"] if len(p["x"])]
        ax.set_xlim(min(starts, default=road[0]) - 2, max(max(xs), obstacle[0] + obstacle[2]) + 2)
        ax.set_ylim(road[2] - 1, road[4] + 1)
    else:
        ax.autoscale_view()
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_ylabel("y (m)", fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x (m)", fontsize=8)
    return plt.cm.ScalarMappable(norm=norm, cmap="plasma")


def avoid_trajectories_figure(
    panels: dict[tuple[str, str], dict], rows: list[str], columns: list[str], title: str
) -> plt.Figure:
    """Grid of `avoid_trajectories` panels with one colour bar (mutual information, nats)."""
    fig, axes = plt.subplots(
        len(rows), len(columns), figsize=(4.2 * len(columns), 1.9 * len(rows) + 0.8), squeeze=False
    )
    mappable = None
    for ax, row, column, panel in _panels(axes, panels, rows, columns):
        mappable = avoid_trajectories(ax, panel, f"{row} · {column}: {panel['title']}")
    fig.suptitle(title)
    fig.tight_layout()
    if mappable is not None:
        fig.colorbar(
            mappable, ax=axes.ravel().tolist(), label="mutual information (nats)", extend="max", fraction=0.02, pad=0.01
        )
    return fig


def avoid_signals_figure(
    runs: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray, str]]],
    configured,
    calibrated,
    title: str,
    distance: str = "distance to the obstacle along the road (m)",
) -> plt.Figure:
    """The paper's Figure "warnings": η2 (top) and mutual information (bottom) against the distance to
    the obstacle (``distance``: what the distances are), one line per rollout (red: it collided), with the
    thresholds δ1, δ2 and τ of the configured (dashed) and calibrated (dotted) warning systems.
    ``runs[condition]``: (distance, η2, MI, termination) per rollout."""
    fig, axes = plt.subplots(2, len(runs), figsize=(4.5 * len(runs), 5.5), squeeze=False, sharex=True)
    for j, (condition, rows) in enumerate(runs.items()):
        top, bottom = axes[0, j], axes[1, j]
        for along, eta2, mi, termination in rows:
            color = "tab:red" if termination in ("collision", "off_road") else "tab:blue"
            top.plot(along, eta2, color=color, lw=0.7, alpha=0.5)
            bottom.plot(along, mi, color=color, lw=0.7, alpha=0.5)
        for cfg, style, who in ((configured, "--", "configured"), (calibrated, ":", "calibrated")):
            top.axhline(cfg.delta1, color="k", ls=style, lw=1, label=f"δ1 = {cfg.delta1:g} ({who})")
            top.axhline(cfg.delta2, color="tab:purple", ls=style, lw=1, label=f"δ2 = {cfg.delta2:g} ({who})")
            bottom.axhline(cfg.tau, color="k", ls=style, lw=1, label=f"τ = {cfg.tau:g} ({who})")
        top.set_title(f"{condition}", fontsize=9)
        top.set_ylabel("η2 (decision confidence)")
        bottom.set_ylabel("mutual information (nats)")
        bottom.set_xlabel(distance)
        top.set_ylim(-0.02, 1.02)
        bottom.set_ylim(bottom=0)
    axes[0, 0].invert_xaxis()
    axes[0, 0].plot([], [], color="tab:red", label="collided")
    axes[0, 0].legend(fontsize=7, loc="lower left")
    axes[1, 0].legend(fontsize=7, loc="upper left")
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def avoid_tradeoff_figure(
    table: dict[str, np.ndarray], chosen: int, default: int | None, target: float, title: str
) -> plt.Figure:
    """The paper's joint claim as a front: replayed unknown-condition η̂1 against known-condition autonomy
    for every candidate (δ1, δ2, τ); candidates Learn-then-Test did not certify (autonomy ≥ ``target``) are
    hollow; the Pareto front, the chosen and the configured thresholds."""
    fig, ax = plt.subplots(figsize=(5.5, 4))
    autonomy, safety, certified = table["autonomy"], table["eta1_unknown"], table["certified"].astype(bool)
    ax.scatter(
        autonomy[~certified], safety[~certified], s=10, facecolors="none", edgecolors="0.6", label="not certified"
    )
    ax.scatter(
        autonomy[certified], safety[certified], s=10, color="tab:blue", label=f"certified: autonomy ≥ {target:g}"
    )
    front = np.flatnonzero(table["pareto"])
    front = front[np.argsort(autonomy[front])]
    ax.plot(autonomy[front], safety[front], "-", color="tab:blue", lw=1, label="Pareto front")
    if default is not None:
        ax.plot(
            autonomy[default],
            safety[default],
            "D",
            color="k",
            ms=7,
            mfc="none",
            label=f"configured δ1={table['delta1'][default]:g} δ2={table['delta2'][default]:g} "
            f"τ={table['tau'][default]:g}",
        )
    ax.plot(
        autonomy[chosen],
        safety[chosen],
        "*",
        color="gold",
        mec="k",
        ms=14,
        label=f"chosen δ1={table['delta1'][chosen]:g} δ2={table['delta2'][chosen]:g} τ={table['tau'][chosen]:g}",
    )
    ax.set_xlabel("known-condition autonomy (runs with no hand-over)")
    ax.set_ylabel("unknown-condition η̂1 (replayed)")
    ax.set_xlim(-0.03, 1.03)
    ax.set_ylim(-0.03, 1.03)
    ax.legend(fontsize=7, loc="lower left")
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return fig


def eta1_intervals_figure(rows: list[dict], methods: list[str]) -> plt.Figure:
    """Each method's η̂1 per condition with its interval (``rows``: method, condition, eta1, eta1_low, eta1_high):
    where each method is safe, and how much its few training runs leave open."""
    conditions = list(dict.fromkeys(r["condition"] for r in rows))
    fig, ax = plt.subplots(figsize=(max(6.0, 0.45 * len(conditions) + 2), 5.0))
    width = 0.8 / len(methods)
    for k, method in enumerate(methods):
        mine = {r["condition"]: r for r in rows if r["method"] == method}
        value = np.array([mine[c]["eta1"] for c in conditions])
        low, high = (
            np.array([mine[c]["eta1_low"] for c in conditions]),
            np.array([mine[c]["eta1_high"] for c in conditions]),
        )
        x = np.arange(len(conditions)) + (k - (len(methods) - 1) / 2) * width
        ax.errorbar(x, value, yerr=[value - low, high - value], fmt="o", ms=4, capsize=2, lw=1, label=method)
    ax.set_xticks(np.arange(len(conditions)), conditions, rotation=60, ha="right", fontsize=7)
    ax.set_ylim(-0.04, 1.04)
    ax.set_xlabel("condition (location-weather-noise)")
    ax.set_ylabel("η1: mean of replicates, method interval")
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8, ncols=len(methods), loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False)
    fig.tight_layout()
    return fig
