"""Figures that stages log to MLflow and write beside their DVC plots."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from uqdrive.files import atomic_path  # noqa: E402


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
    return np.vstack([np.hstack(tiles[r * columns:(r + 1) * columns]) for r in range(rows)])


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
