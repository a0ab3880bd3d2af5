"""The preprocess figure: how the steering classes are spread in each split."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np


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
