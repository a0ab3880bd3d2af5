"""Phase two's regions: the unit cube split into boxes, finer where phase one places the boundary η1 = τ, and
the family-wise error γ split across them.

The partition is a function of phase one's rollouts only, so once it is fixed the certification rollouts
(fresh seeds) are independent of it: each region's test keeps its own error γ_r, and the union bound makes the
whole map right with probability ≥ 1 − Σ γ_r ≥ 1 − γ.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Annotated

import numpy as np
from pydantic import Field, Strict

from uqdrive.envelope.search import BoundaryModel
from uqdrive.schema import invalid, schema

Depth = Annotated[int, Strict(), Field(ge=0, le=5)]  # 2^(d * depth) regions at most: 32768 for three axes at 5


@schema(frozen=True)
class PartitionSettings:
    """Every region is split (into 2^d halves) down to ``min_depth``, and further, down to ``max_depth``,
    while phase one's kernel-smoothed rate of safe runs crosses τ inside it: the finest regions are 2^-max_depth of each
    axis wide, and lie along the boundary."""

    min_depth: Depth = 1
    max_depth: Depth = 3

    def __post_init__(self) -> None:
        if self.min_depth > self.max_depth:
            raise invalid("min_depth", self.min_depth, f"must be <= max_depth ({self.max_depth})")


@dataclass(frozen=True)
class Region:
    """A box [low, high) of the unit cube (closed at 1), named by its path of splits: child c of a split holds
    the upper half of axis k when bit k of c is set; the empty path is the whole cube."""

    low: tuple[float, ...]
    high: tuple[float, ...]
    path: tuple[int, ...] = ()

    @classmethod
    def cube(cls, dim: int) -> Region:
        return cls((0.0,) * dim, (1.0,) * dim)

    @property
    def dim(self) -> int:
        return len(self.low)

    @property
    def depth(self) -> int:
        return len(self.path)

    @property
    def name(self) -> str:
        return "r" + "".join(map(str, self.path))

    @property
    def volume(self) -> float:
        return math.prod(h - lo for lo, h in zip(self.low, self.high))

    def children(self) -> list[Region]:
        mid = [(lo + h) / 2 for lo, h in zip(self.low, self.high)]
        out = []
        for c in range(2**self.dim):
            upper = [(c >> k) & 1 for k in range(self.dim)]
            low = tuple(m if u else lo for u, lo, m in zip(upper, self.low, mid))
            high = tuple(h if u else m for u, h, m in zip(upper, self.high, mid))
            out.append(Region(low, high, (*self.path, c)))
        return out

    def at(self, unit: np.ndarray) -> np.ndarray:
        """Points of the region from points of the unit cube (a uniform draw stays uniform)."""
        return np.asarray(self.low) + np.asarray(unit) * (np.asarray(self.high) - np.asarray(self.low))

    def contains(self, points: np.ndarray) -> np.ndarray:
        p = np.atleast_2d(points)
        low, high = np.asarray(self.low), np.asarray(self.high)
        return ((p >= low) & ((p < high) | ((high == 1.0) & (p == 1.0)))).all(1)

    def grid(self, steps: int) -> np.ndarray:
        """The (steps + 1)^d points of a regular grid over the region, its faces included."""
        ticks = np.linspace(0.0, 1.0, steps + 1)
        return self.at(np.array(list(itertools.product(ticks, repeat=self.dim))))


def partition(model: BoundaryModel, dim: int, settings: PartitionSettings) -> tuple[Region, ...]:
    """The regions phase two certifies, in depth-first order of their paths."""
    threshold = model.threshold

    def crosses(region: Region) -> bool:
        rate = model.rate(region.grid(2 ** (settings.max_depth - region.depth + 1)))
        return bool(rate.max() >= threshold > rate.min())

    def visit(region: Region) -> Iterator[Region]:
        if region.depth < settings.min_depth or (region.depth < settings.max_depth and crosses(region)):
            for child in region.children():
                yield from visit(child)
        else:
            yield region

    return tuple(visit(Region.cube(dim)))
