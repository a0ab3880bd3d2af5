"""Steering ↔ class mapping: the one place that decides what a class means.

Steering in [-1, 1] (positive = left) is binned into tenths as the paper does. We use
**21 class centres** -1.0, -0.9, …, 1.0 (nearest centre), not 20 intervals, so that
"straight ahead" (0.0) is a class of its own and every class decodes to a steering
value the car can apply directly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uqdrive.checks import ConfigError


@dataclass(frozen=True)
class SteeringBins:
    """Uniform class centres ``k / per_unit - max_abs`` for ``k = 0 … num_classes - 1``."""

    per_unit: int = 10
    max_abs: float = 1.0

    def __post_init__(self) -> None:
        if not isinstance(self.per_unit, int) or self.per_unit < 1:
            raise ConfigError(f"bins.per_unit={self.per_unit!r} must be a positive integer")
        if not self.max_abs > 0:
            raise ConfigError(f"bins.max_abs={self.max_abs!r} must be > 0")
        steps = self.max_abs * self.per_unit
        if abs(steps - round(steps)) > 1e-9:
            raise ConfigError(f"bins.max_abs={self.max_abs!r} must be a multiple of 1/per_unit={1 / self.per_unit}")

    @property
    def num_classes(self) -> int:
        return int(round(2 * self.max_abs * self.per_unit)) + 1

    @property
    def centres(self) -> np.ndarray:
        """Steering value of each class, ascending (class 0 = full right)."""
        return (np.arange(self.num_classes) - self.num_classes // 2) / self.per_unit

    @property
    def width(self) -> float:
        return 1.0 / self.per_unit

    def to_class(self, steering: np.ndarray | float) -> np.ndarray:
        """Index of the nearest centre (ties go up); values beyond ±max_abs land in the end classes."""
        steering = np.asarray(steering, dtype=np.float64)
        if not np.all(np.isfinite(steering)):
            raise ValueError("steering contains NaN or infinite values")
        index = np.floor(steering * self.per_unit + 0.5).astype(np.int64) + self.num_classes // 2
        return np.clip(index, 0, self.num_classes - 1)

    def to_steering(self, classes: np.ndarray | int) -> np.ndarray:
        classes = np.asarray(classes)
        if classes.size and (classes.min() < 0 or classes.max() >= self.num_classes):
            raise ValueError(f"class index out of range [0, {self.num_classes - 1}]: {classes.min()}..{classes.max()}")
        return self.centres[classes]

    def to_dict(self) -> dict:
        return {"per_unit": self.per_unit, "max_abs": self.max_abs, "num_classes": self.num_classes}
