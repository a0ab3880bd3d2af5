"""What every figure module shares: saving a figure atomically, tiling frames, walking a grid of panels."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, never a window: before pyplot draws anything
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
    return np.vstack([np.hstack(tiles[r * columns : (r + 1) * columns]) for r in range(rows)])


def panel_grid(axes: np.ndarray, panels: dict[tuple[str, str], dict], rows: list[str], columns: list[str]):
    """(ax, row, column, panel) of a figure's grid of panels, row by row; cells without a panel are blanked."""
    for i, row in enumerate(rows):
        for j, column in enumerate(columns):
            panel = panels.get((row, column))
            if panel is None:
                axes[i, j].axis("off")
            else:
                yield axes[i, j], row, column, panel
