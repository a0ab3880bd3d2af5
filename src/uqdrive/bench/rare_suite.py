"""A suite of synthetic rare-failure worlds whose failure probability over the domain is known exactly, for the
rare-event bench: the worlds the importance sampler was not built for beside the one it was.

Each world is a small frozen class with ``__call__(points [runs, n, d], seeds [runs, n]) -> (failed, margins)``
(the `uqdrive.uq.rare.Rollouts` protocol), ``domain`` (the nominal law on the unit cube), ``margin`` (how the
margin is fed: ``exact`` signed distance, ``noisy`` distance plus seeded Gaussian noise, ``outcome`` ±1 by the
outcome) and ``failure_probability()``: in closed form, by one-dimensional quadrature (`scipy.integrate.quad`,
absolute error < 1e-12 at p = 10⁻³) or, for the walk, by Gauss–Legendre quadrature that is exact for its
polynomial integrand; the tests check each against simulation. ``at(p)`` solves the world's size parameter so
that p is the one asked for (`scipy.optimize.brentq`, relative error < 1e-9).

Region worlds fail with probability ``inside`` on a region of the cube and never elsewhere; the margin is the
region's signed distance (Chebyshev for boxes, Euclidean for the disk and the half-plane), ≤ 0 for a failure.
The walk world's failure depends on the time-course of a rollout: a ±1 random walk (its steps drawn from the
seed) whose up-probability rises with c₁ fails when it reaches a level within its horizon, and its margin is the
smallest distance to that level along the trajectory, not a function of the start condition.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import integrate, optimize, stats

from uqdrive.bench.rare_world import seed_uniform
from uqdrive.uq.rare_proposal import ProductBeta

NOISE_SD = 0.05  # the noisy margin's standard deviation, unit coordinates (the corner's own scale is ~0.3)
QUADRATURE = 64  # Gauss–Legendre nodes for the walk world: exact for polynomials of degree < 128


def beta_domain(dim: int) -> ProductBeta:
    """Beta(2, 5) on each of ``dim`` axes (the bench's domain: most conditions mild, a long tail)."""
    return ProductBeta.of([2.0] * dim, [5.0] * dim)


def _feed(margin: str, distance: np.ndarray, failed: np.ndarray, seeds: np.ndarray) -> np.ndarray:
    """The margin the sampler sees: ≤ 0 where the rollout failed, whatever the kind."""
    if margin == "outcome":
        return np.where(failed, -1.0, 1.0)
    if margin == "constant":  # nothing to adapt on: refused by `refute` before any rollout
        return np.zeros(np.shape(failed))
    if margin == "noisy":
        z = stats.norm.ppf(np.clip(seed_uniform(np.asarray(seeds) ^ 0x5DEECE66D), 1e-12, 1 - 1e-12))
        distance = distance + NOISE_SD * z
    return np.where(failed, np.minimum(distance, 0.0), np.maximum(distance, 0.0))


@dataclass(frozen=True)
class Corner:
    """{c_j > size on every axis in ``axes``}: the shipped corner (axes (0, 1)), or on few of many axes."""

    size: float
    axes: tuple[int, ...] = (0, 1)
    bracket = (1e-6, 1 - 1e-6)

    def distance(self, points: np.ndarray) -> np.ndarray:
        return np.max(self.size - points[..., list(self.axes)], axis=-1)

    def mass(self, domain: ProductBeta) -> float:
        j = list(self.axes)
        return float(np.prod(stats.beta.sf(self.size, domain.a[j], domain.b[j])))


@dataclass(frozen=True)
class Square:
    """An interior square of half-width ``size`` about ``center`` (axis-aligned, away from every edge)."""

    size: float
    center: tuple[float, float] = (0.5, 0.5)
    bracket = (1e-6, 0.5 - 1e-6)

    def distance(self, points: np.ndarray) -> np.ndarray:
        return np.max(np.abs(points[..., :2] - np.asarray(self.center)) - self.size, axis=-1)

    def mass(self, domain: ProductBeta) -> float:
        c, a, b = np.asarray(self.center), domain.a[:2], domain.b[:2]
        return float(np.prod(stats.beta.cdf(c + self.size, a, b) - stats.beta.cdf(c - self.size, a, b)))


@dataclass(frozen=True)
class TwoBoxes:
    """Two disconnected failure modes, {c₁ > size, c₂ < ``low``} and {c₂ > size, c₁ < ``low``} (size > low):
    one Beta proposal cannot sit on both."""

    size: float
    low: float = 0.3
    bracket = (0.3 + 1e-6, 1 - 1e-6)

    def distance(self, points: np.ndarray) -> np.ndarray:
        c1, c2 = points[..., 0], points[..., 1]
        first = np.maximum(self.size - c1, c2 - self.low)
        return np.minimum(first, np.maximum(self.size - c2, c1 - self.low))

    def mass(self, domain: ProductBeta) -> float:
        (a1, a2), (b1, b2) = domain.a[:2], domain.b[:2]
        one = stats.beta.sf(self.size, a1, b1) * stats.beta.cdf(self.low, a2, b2)
        return float(one + stats.beta.sf(self.size, a2, b2) * stats.beta.cdf(self.low, a1, b1))


@dataclass(frozen=True)
class Disk:
    """A curved region: the disk of radius ``size`` about the cube's far corner (1, 1)."""

    size: float
    bracket = (1e-3, 1 - 1e-6)

    def distance(self, points: np.ndarray) -> np.ndarray:
        return np.linalg.norm(1.0 - points[..., :2], axis=-1) - self.size

    def mass(self, domain: ProductBeta) -> float:
        (a1, a2), (b1, b2) = domain.a[:2], domain.b[:2]

        def slice_(x: float) -> float:  # c₁ = x: c₂ > 1 − √(r² − (1 − x)²)
            return stats.beta.pdf(x, a1, b1) * stats.beta.sf(1 - math.sqrt(self.size**2 - (1 - x) ** 2), a2, b2)

        return integrate.quad(slice_, 1 - self.size, 1, epsabs=1e-14, epsrel=1e-10, limit=200)[0]


@dataclass(frozen=True)
class HalfPlane:
    """A region aligned with no axis: {c₁ + c₂ > size}, its margin the Euclidean distance to the line."""

    size: float
    bracket = (1e-3, 2 - 1e-6)

    def distance(self, points: np.ndarray) -> np.ndarray:
        return (self.size - points[..., 0] - points[..., 1]) / math.sqrt(2)

    def mass(self, domain: ProductBeta) -> float:
        (a1, a2), (b1, b2) = domain.a[:2], domain.b[:2]
        low = max(0.0, self.size - 1)
        slice_ = lambda x: stats.beta.pdf(x, a1, b1) * stats.beta.sf(self.size - x, a2, b2)  # noqa: E731
        return integrate.quad(slice_, low, 1, epsabs=1e-14, epsrel=1e-10, limit=200)[0]


@dataclass(frozen=True)
class ModeGrid:
    """``per_axis``² boxes of half-width ``size`` in the domain's own quantile coordinates u_j = F_j(c_j) (its
    Beta(``shape``) CDF on each of the first two axes), centred on a grid: failure modes of equal mass (2·size)²
    each, spread over the domain, so one mode alone can hold less than m while all together hold p."""

    size: float
    shape: tuple[float, float] = (2.0, 5.0)
    per_axis: int = 4

    @property
    def bracket(self) -> tuple[float, float]:
        return 1e-9, 0.5 / self.per_axis - 1e-9  # the boxes stay apart

    def distance(self, points: np.ndarray) -> np.ndarray:
        u = stats.beta.cdf(points[..., :2], *self.shape)
        centres = (np.arange(self.per_axis) + 0.5) / self.per_axis
        per_axis = np.min(np.abs(u[..., None] - centres), axis=-1) - self.size  # to the nearest grid line's box
        return np.max(per_axis, axis=-1)

    def mass(self, domain: ProductBeta) -> float:
        return float((self.per_axis * 2 * self.size) ** 2)


FailureRegion = Corner | Square | TwoBoxes | Disk | HalfPlane | ModeGrid


@dataclass(frozen=True)
class RegionWorld:
    """Fails with probability ``inside`` on ``region`` and never elsewhere; p = inside · mass(region)."""

    name: str
    region: FailureRegion
    domain: ProductBeta
    inside: float = 0.5
    margin: str = "exact"

    def at(self, p: float) -> RegionWorld:
        """The same world with the region's size solved so that its failure probability is exactly ``p``."""
        if not 0 < p < self.inside:
            raise ValueError(f"{self.name}: failure probability must be in (0, inside={self.inside}), got {p!r}")
        gap = lambda s: math.log(replace(self.region, size=s).mass(self.domain) * self.inside / p)  # noqa: E731
        size = optimize.brentq(gap, *self.region.bracket, xtol=1e-14, rtol=1e-12)
        return replace(self, region=replace(self.region, size=size))

    def failure_probability(self) -> float:
        return self.inside * self.region.mass(self.domain)

    def __call__(self, points: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        distance = self.region.distance(points)
        failed = (distance < 0) & (seed_uniform(seeds) < self.inside)
        return failed, _feed(self.margin, np.where((distance < 0) & ~failed, 0.0, distance), failed, seeds)


def walk_failure(up: np.ndarray, steps: int, level: int) -> np.ndarray:
    """P(a ±1 walk from 0 with up-probability ``up`` reaches ``level`` within ``steps`` steps), exactly, by a
    forward pass over its positions (vectorised over ``up``)."""
    up = np.atleast_1d(np.asarray(up, float))
    alive = np.zeros((up.size, steps + level + 1))  # positions −steps … level − 1; index = position + steps
    alive[:, steps], hit = 1.0, np.zeros(up.size)
    for _ in range(steps):
        moved = np.zeros_like(alive)
        moved[:, 1:] += alive[:, :-1] * up[:, None]
        moved[:, :-1] += alive[:, 1:] * (1 - up[:, None])
        hit += moved[:, -1]
        moved[:, -1] = 0.0
        alive = moved
    return hit


@dataclass(frozen=True)
class WalkWorld:
    """A rollout is a ±1 walk of ``steps`` steps from 0, each step up with probability
    q(c) = ``low`` + ``size``·c₁ (drawn from the seed); it fails when the walk reaches ``level``. Its margin
    is min over the trajectory of (level − position)/level: the time-course decides, not the start condition."""

    name: str
    domain: ProductBeta
    size: float = 0.3
    low: float = 0.25
    steps: int = 40
    level: int = 10
    margin: str = "exact"

    def at(self, p: float) -> WalkWorld:
        gap = lambda s: math.log(replace(self, size=s).failure_probability() / p)  # noqa: E731
        return replace(self, size=optimize.brentq(gap, 1e-6, 1 - self.low - 1e-9, xtol=1e-14, rtol=1e-12))

    def failure_probability(self) -> float:
        """∫ Beta(c₁) · P(fail | q(c₁)) dc₁: a polynomial in c₁ of degree steps + a + b − 2 (integer shapes), so
        Gauss–Legendre with ``QUADRATURE`` nodes integrates it exactly (up to rounding)."""
        a, b = self.domain.a[0], self.domain.b[0]
        nodes, weights = np.polynomial.legendre.leggauss(QUADRATURE)
        x = (nodes + 1) / 2
        return float(
            weights @ (stats.beta.pdf(x, a, b) * walk_failure(self.low + self.size * x, self.steps, self.level)) / 2
        )

    @property
    def horizon(self) -> int:
        return self.steps

    def begin(self, points: np.ndarray) -> np.ndarray:
        """States [k, 4] (position, step, running maximum, up-probability) at step 0: copyable, so splittable."""
        states = np.zeros((points.shape[0], 4))
        states[:, 3] = self.low + self.size * points[:, 0]
        return states

    def advance(self, states: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One step of each walk (drawn from ``rng``: splitting's copies must differ): (states, running maximum /
        level (≥ 1: failed), done)."""
        position = states[:, 0] + np.where(rng.random(states.shape[0]) < states[:, 3], 1.0, -1.0)
        highest = np.maximum(states[:, 2], position)
        states = np.column_stack([position, states[:, 1] + 1, highest, states[:, 3]])
        return states, highest / self.level, states[:, 1] >= self.steps

    def __call__(self, points: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        up = self.low + self.size * points[..., 0]
        ticks = np.asarray(seeds).astype(np.uint64)[..., None] * np.uint64(self.steps) + np.arange(
            self.steps, dtype=np.uint64
        )
        path = np.cumsum(np.where(seed_uniform(ticks) < up[..., None], 1, -1), axis=-1)
        highest = np.maximum.accumulate(path, axis=-1)
        failed = highest[..., -1] >= self.level
        return failed, _feed(self.margin, (self.level - highest[..., -1]) / self.level, failed, seeds)


SuiteWorld = RegionWorld | WalkWorld


def suite() -> tuple[SuiteWorld, ...]:
    """The bench's worlds (each still to be put at its p by ``at``)."""
    two, six = beta_domain(2), beta_domain(6)
    corner = RegionWorld("corner (shipped)", Corner(0.5), two)
    diffuse = replace(corner, name="diffuse corner, 25x the mass", inside=0.02)
    walk = WalkWorld("walk, margin along the trajectory", two)
    return (
        corner,
        replace(corner, name="corner, noisy margin", margin="noisy"),
        replace(corner, name="corner, outcome-only margin", margin="outcome"),
        diffuse,
        replace(diffuse, name="diffuse, outcome-only margin", margin="outcome"),
        RegionWorld("interior square at (0.5, 0.5)", Square(0.1), two),
        RegionWorld("corner on 2 of 6 axes", Corner(0.5), six),
        RegionWorld("two disconnected boxes", TwoBoxes(0.5), two),
        RegionWorld("16 modes, each alone below m", ModeGrid(0.01), two),
        RegionWorld("disk about (1, 1), curved", Disk(0.5), two),
        RegionWorld("half-plane c1 + c2 > s, rotated", HalfPlane(1.0), two),
        walk,
        replace(walk, name="walk, outcome-only margin", margin="outcome"),
    )
