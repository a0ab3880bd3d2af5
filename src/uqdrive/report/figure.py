"""The report's figure: every cell's η̂1 with its interval, per method."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np


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
