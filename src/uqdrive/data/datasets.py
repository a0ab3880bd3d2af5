"""Processed frames as torch tensors: the network input every model trains and predicts on.

Frames stay uint8 in memory (4x smaller than float32) and become float32 in [0, 1] with
shape [b, 1, 48, 64] only per batch, so the paper-sized data set fits comfortably in RAM.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pyarrow as pa
import torch
from torch.utils.data import Dataset

from uqdrive.data.tables import PROCESSED_SCHEMA, images_to_array, read_table


def to_inputs(images: np.ndarray | torch.Tensor) -> torch.Tensor:
    """uint8 [N, 48, 64] → float32 [N, 1, 48, 64] in [0, 1]; the one place that scales pixels."""
    images = torch.as_tensor(images)
    if images.dtype != torch.uint8 or images.ndim != 3:
        raise ValueError(f"expected uint8 frames [N, H, W], got dtype={images.dtype} shape={tuple(images.shape)}")
    return images.unsqueeze(1).to(torch.float32).div_(255.0)


class FrameSet(Dataset):
    """Frames and class labels of one split (train or val)."""

    def __init__(self, images: torch.Tensor, labels: torch.Tensor, num_classes: int, name: str = "frames") -> None:
        if len(images) == 0:
            raise ValueError(f"{name} has 0 frames: collect and preprocess data before training")
        if len(images) != len(labels):
            raise ValueError(f"{name}: {len(images)} frames but {len(labels)} labels")
        if labels.min() < 0 or labels.max() >= num_classes:
            raise ValueError(
                f"{name}: labels span {int(labels.min())}..{int(labels.max())}, "
                f"outside the {num_classes} classes of this configuration (bins changed? rerun preprocess)"
            )
        self.images = images
        self.labels = labels.to(torch.int64)
        self.num_classes = num_classes
        self.name = name

    def __len__(self) -> int:
        return len(self.labels)

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        return to_inputs(self.images[index : index + 1])[0], self.labels[index]

    def batches(
        self, batch_size: int, generator: torch.Generator | None = None
    ) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        """(inputs, labels) batches; shuffled with `generator` when one is given, in order otherwise."""
        order = torch.randperm(len(self), generator=generator) if generator is not None else torch.arange(len(self))
        for start in range(0, len(self), batch_size):
            index = order[start : start + batch_size]
            yield to_inputs(self.images[index]), self.labels[index]


def frames_from_table(table: pa.Table, num_classes: int, name: str) -> FrameSet:
    """A table in the processed schema (at least its label and image columns) as a `FrameSet`."""
    images = torch.from_numpy(images_to_array(table.column("image")).copy())
    labels = torch.from_numpy(table.column("label").to_numpy().astype(np.int64))
    return FrameSet(images, labels, num_classes, name=name)


def load_frames(path: str | Path, num_classes: int) -> FrameSet:
    """Read a processed split (``data/processed/<split>.parquet``)."""
    return frames_from_table(read_table(path, PROCESSED_SCHEMA, columns=["label", "image"]), num_classes, str(path))
