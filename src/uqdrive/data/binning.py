"""Steering ↔ class mapping: the one place that decides what a class means.

Steering in [-1, 1] (positive = left) is binned into tenths as the paper does. Classes are
**centres** k / per_unit (nearest centre), not intervals, so that "straight ahead" (0.0) is a
class of its own and every class decodes to a steering value the car can apply directly.

The paper's final layer has "neurons equal to the number of classes (variable per
experiment)": an experiment keeps only the tenths its training labels use, from ``low`` to
``high`` (the defaults, -1 … 1, are all 21). Steering beyond them lands in the end classes.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Annotated

import numpy as np
from pydantic import Field

from uqdrive.schema import Count, Float, invalid, schema

Steering = Annotated[Float, Field(ge=-1.0, le=1.0)]  # steering value: +1 full left


@schema(frozen=True)
class SteeringBins:
    """Uniform class centres ``low + k / per_unit`` for ``k = 0 … num_classes - 1`` (up to ``high``)."""

    per_unit: Count = 10
    low: Steering = -1.0
    high: Steering = 1.0

    def __post_init__(self) -> None:
        for name in ("low", "high"):
            steps = getattr(self, name) * self.per_unit
            if abs(steps - round(steps)) > 1e-9:
                raise invalid(name, getattr(self, name), f"must be a multiple of 1/per_unit={1 / self.per_unit}")
        if not self.low < self.high:
            raise invalid("low", self.low, f"must be < high={self.high!r} (at least two classes)")

    @classmethod
    def from_dict(cls, data: Mapping) -> SteeringBins:
        """From ``to_dict``'s output (a checkpoint's or a config's ``bins``); ``num_classes`` is derived."""
        return cls(per_unit=int(data["per_unit"]), low=float(data["low"]), high=float(data["high"]))

    @property
    def _low_step(self) -> int:
        return int(round(self.low * self.per_unit))

    @property
    def num_classes(self) -> int:
        return int(round(self.high * self.per_unit)) - self._low_step + 1

    @property
    def centres(self) -> np.ndarray:
        """Steering value of each class, ascending (class 0 = the rightmost kept tenth)."""
        return (self._low_step + np.arange(self.num_classes)) / self.per_unit

    @property
    def width(self) -> float:
        return 1.0 / self.per_unit

    def to_class(self, steering: np.ndarray | float) -> np.ndarray:
        """Index of the nearest centre (ties go up); values beyond low/high land in the end classes."""
        steering = np.asarray(steering, dtype=np.float64)
        if not np.all(np.isfinite(steering)):
            raise ValueError("steering contains NaN or infinite values")
        index = np.floor(steering * self.per_unit + 0.5).astype(np.int64) - self._low_step
        return np.clip(index, 0, self.num_classes - 1)

    def to_steering(self, classes: np.ndarray | int) -> np.ndarray:
        classes = np.asarray(classes)
        if classes.size and (classes.min() < 0 or classes.max() >= self.num_classes):
            raise ValueError(f"class index out of range [0, {self.num_classes - 1}]: {classes.min()}..{classes.max()}")
        return self.centres[classes]

    def clipped(self, steering: np.ndarray) -> np.ndarray:
        """Which steering values lie beyond the end classes by more than half a class (lost by the binning)."""
        steering = np.asarray(steering, dtype=np.float64)
        half = 0.5 / self.per_unit
        return (steering < self.low - half) | (steering >= self.high + half)

    def to_dict(self) -> dict:
        return {"per_unit": self.per_unit, "low": self.low, "high": self.high, "num_classes": self.num_classes}
