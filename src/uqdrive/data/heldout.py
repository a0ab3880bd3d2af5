"""Held-out frames: the `heldout` stage's autopilot frames of one weather × noise (data/heldout/<condition>.parquet),
preprocessed exactly as the training frames were."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import FrameSet, frames_from_table
from uqdrive.data.preprocess import Split, preprocess_raw
from uqdrive.data.tables import RAW_SCHEMA, read_table
from uqdrive.resolvers import condition_label


def heldout_path(folder: str | Path, scenario: str, weather: str, noise: float) -> Path:
    return Path(folder) / f"{condition_label(scenario, weather, noise)}.parquet"


def load_heldout(path: Path, scenario: str, weather: str, noise: float, bins: SteeringBins) -> FrameSet:
    """Held-out autopilot frames → network inputs and class labels, through the training preprocessing;
    refuses a file recorded in another scenario or condition than its name says."""
    raw = read_table(path, RAW_SCHEMA)
    recorded = {col: set(raw.column(col).to_pylist()) for col in ("scenario", "weather", "noise")}
    if (
        recorded["scenario"] != {scenario}
        or recorded["weather"] != {weather}
        or not np.allclose(sorted(recorded["noise"]), [noise], atol=1e-6)
    ):
        raise ValueError(
            f"{path} holds frames of scenario {sorted(recorded['scenario'])}, weather "
            f"{sorted(recorded['weather'])}, noise {sorted(recorded['noise'])}; expected {scenario}, "
            f"{weather}, {noise}: collect it again (dvc repro heldout)"
        )
    table, _ = preprocess_raw(raw, bins, Split(val_fraction=0.0))
    return frames_from_table(table, bins.num_classes, str(path))
