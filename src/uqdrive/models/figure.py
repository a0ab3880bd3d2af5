"""The held-out evaluation's figures: reliability diagrams and how each method's measures move with the condition."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from uqdrive.figures import panel_grid


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
    for ax, row, column, panel in panel_grid(axes, panels, rows, columns):
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
