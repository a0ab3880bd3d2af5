"""A synthetic world whose failure probability over a domain is known exactly, for the rare-event bench and tests.

A rollout at condition c (a point of the unit cube) fails with probability ``inside`` if c lies in the corner
{c_j > t_j for every axis j} and never outside it, so η1(c) = 1 − inside·1{c in the corner} in closed form and,
under a product-of-Betas domain, p = inside · Π_j P(c_j > t_j). The outcome is a Bernoulli draw from the
rollout's seed alone (a splitmix64 hash), so a failure record's seed re-drives it. The margin is the signed
distance to the corner, max_j (t_j − c_j): positive outside it, ≤ 0 for a failure inside, 0 for a rollout that
survives inside (it touched the boundary). Vectorised: microseconds a rollout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from uqdrive.uq.rare_proposal import ProductBeta

_GOLDEN, _MIX1, _MIX2 = np.uint64(0x9E3779B97F4A7C15), np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)


def seed_uniform(seeds: np.ndarray) -> np.ndarray:
    """A uniform in [0, 1) per seed: splitmix64's output for that seed (the same seed, the same draw)."""
    z = np.asarray(seeds).astype(np.uint64) * _GOLDEN + _GOLDEN
    with np.errstate(over="ignore"):
        z = (z ^ (z >> np.uint64(30))) * _MIX1
        z = (z ^ (z >> np.uint64(27))) * _MIX2
    z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)).astype(float) / 2.0**53


@dataclass(frozen=True)
class CornerWorld:
    """Fails with probability ``inside`` in the corner above ``thresholds`` (unit coordinates), never elsewhere."""

    thresholds: np.ndarray
    inside: float = 0.5

    @classmethod
    def at(cls, failure: float, domain: ProductBeta, inside: float = 0.5) -> CornerWorld:
        """The world whose failure probability over ``domain`` (shared shapes [d]) is exactly ``failure``."""
        if not 0 < failure < inside:
            raise ValueError(f"failure must be in (0, inside={inside}), got {failure!r}")
        per_axis = (failure / inside) ** (1 / domain.dim)
        unit = stats.beta.isf(per_axis, domain.a, domain.b)
        return cls(domain.low + (domain.high - domain.low) * unit, inside)

    def failure_probability(self, domain: ProductBeta) -> float:
        """p over ``domain`` (shared shapes [d]), in closed form."""
        unit = (self.thresholds - domain.low) / (domain.high - domain.low)
        return float(self.inside * np.prod(stats.beta.sf(unit, domain.a, domain.b)))

    def __call__(self, points: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        distance = np.max(self.thresholds - points, axis=-1)
        corner = distance < 0
        failed = corner & (seed_uniform(seeds) < self.inside)
        return failed, np.where(corner & ~failed, 0.0, distance)


DOMAIN = ProductBeta.of([2.0, 2.0], [5.0, 5.0])
"""The bench's domain: Beta(2, 5) on both axes of the unit square (most conditions mild, a long tail)."""
MISSING = ProductBeta.of([1.0, 1.0], [40.0, 40.0])
"""A proposal that misses the failure corner: its mass sits at the opposite corner."""
COVERING = ProductBeta.of([1.0, 1.0], [1.0, 1.0])
"""A proposal that over-covers it: uniform on the square."""
