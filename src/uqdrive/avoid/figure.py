"""Collision avoidance's figures: the paths past the obstacle coloured by uncertainty, the warning signals, the
safety-autonomy trade-off."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from uqdrive.figures import panel_grid


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
    ax.set_ylabel("y across the road (m)" if road.size else "y (m)", fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("x along the road (m)" if road.size else "x (m)", fontsize=8)
    return plt.cm.ScalarMappable(norm=norm, cmap="plasma")


def avoid_trajectories_figure(
    panels: dict[tuple[str, str], dict], rows: list[str], columns: list[str], title: str
) -> plt.Figure:
    """Grid of `avoid_trajectories` panels with one colour bar (mutual information, nats)."""
    fig, axes = plt.subplots(
        len(rows), len(columns), figsize=(4.2 * len(columns), 1.9 * len(rows) + 0.8), squeeze=False
    )
    mappable = None
    for ax, row, column, panel in panel_grid(axes, panels, rows, columns):
        mappable = avoid_trajectories(ax, panel, f"{row} · {column}: {panel['title']}")
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.legend(handles=_trajectory_legend(), loc="lower center", ncol=5, fontsize=8, frameon=False)
    if mappable is not None:
        fig.colorbar(
            mappable, ax=axes.ravel().tolist(), label="mutual information (nats)", extend="max", fraction=0.02, pad=0.01
        )
    return fig


def _trajectory_legend() -> list:
    """What each mark of `avoid_trajectories` is (the colour bar gives the paths' colours)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    def mark(marker: str, colour: str) -> dict:
        return dict(color="none", marker=marker, markerfacecolor=colour, markeredgecolor="k", markersize=6, mew=0.5)

    return [
        Line2D([], [], color=plt.cm.plasma(0.6), lw=1.5, label="a run's path (colour: mutual information)"),
        Line2D([], [], **mark("x", "tab:red"), label="collision"),
        Line2D([], [], **mark("s", "orange"), label="hand-over (stopped)"),
        Patch(color="tab:red", label="obstacle"),
        Patch(color="0.35", label="road (dashed: centre line)"),
    ]


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
