"""Raw episodes → network-ready frames: grayscale 64x48, steering class, train/val split by episode."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyarrow as pa

from uqdrive.data.binning import SteeringBins
from uqdrive.data.frames import decode_png
from uqdrive.data.tables import PROCESSED_SCHEMA
from uqdrive.network_input import preprocess_frame
from uqdrive.records import record
from uqdrive.schema import ConfigError


@dataclass(frozen=True)
class Split:
    """Which (scenario, episode) pairs go to validation; whole episodes, so val frames are unseen roads."""

    val_fraction: float = 0.2
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.val_fraction < 1.0:
            raise ConfigError(f"preprocess.val_fraction={self.val_fraction!r} must be in [0, 1)")

    def val_episodes(self, episodes: np.ndarray) -> set[int]:
        """At least one episode goes to validation when val_fraction > 0 and there are two or more."""
        unique = np.unique(episodes)
        n_val = int(round(self.val_fraction * len(unique)))
        if self.val_fraction > 0 and len(unique) > 1:
            n_val = min(max(n_val, 1), len(unique) - 1)
        rng = np.random.default_rng(self.seed)
        return set(rng.choice(unique, size=n_val, replace=False).tolist())


def preprocess_raw(raw: pa.Table, bins: SteeringBins, split: Split) -> tuple[pa.Table, pa.Table]:
    """One scenario's raw table → (train, val) tables in the processed schema."""
    if raw.num_rows == 0:
        raise ValueError("raw table has no frames; did collect run with episodes > 0?")
    columns = raw.select(["scenario", "weather", "noise", "episode", "step", "steering"]).to_pydict()
    steering = np.asarray(columns["steering"], dtype=np.float64)
    images = [preprocess_frame(decode_png(png)).tobytes() for png in raw.column("image").to_pylist()]
    labels = bins.to_class(steering).astype(np.int16)
    processed = pa.Table.from_pydict({**columns, "label": labels, "image": images}, schema=PROCESSED_SCHEMA)

    episodes = np.asarray(columns["episode"])
    is_val = np.isin(episodes, list(split.val_episodes(episodes)))
    return processed.filter(pa.array(~is_val)), processed.filter(pa.array(is_val))


def class_histogram(labels: np.ndarray, bins: SteeringBins) -> np.ndarray:
    return np.bincount(np.asarray(labels, dtype=np.int64), minlength=bins.num_classes)


@record
class Preprocessed:
    """metrics/<experiment>/preprocess.json: the class set, how far the labels reach, the split's sizes."""

    experiment: str
    num_classes: int
    clipped_label_fraction: float  # labels beyond the end classes by more than half a tenth: the set should cover them
    steering_min: float
    steering_max: float
    train_frames: int
    val_frames: int
    majority_class_fraction: float
