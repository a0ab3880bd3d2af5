"""Densities over a unit cube of conditions for rare-event sampling: the domain (nominal) and the proposal a
cross-entropy step adapts toward failure, both products of Beta laws, vectorised over independent runs.

Why Betas: the condition cube is bounded, so a proposal must put no mass where the domain's density is zero
(a rollout there carries weight 0 and is wasted, and the world there may not even be valid); a product of Betas
on the same support cannot, and the cross-entropy step stays closed form (weighted moment matching).
Parameters have shape [runs, d] (one proposal per independent run; a run's proposal depends on its own data
only) or [d] (shared); points are [runs, n, d].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

MAX_CONCENTRATION = 30.0  # a + b of a fitted Beta: sd ≥ 9 % of the support at its middle; a narrower proposal
# under-weights most of the failure set, and X = w·1{fail} then sits below p on most failures (400: 188 rollouts
# to refute p = 10⁻³ against m = 10⁻⁴ on the bench world, 30: 94)
MIN_SHAPE = 0.5  # a, b of a fitted Beta: no pole stronger than the arcsine law's at a support's end


@dataclass(frozen=True)
class ProductBeta:
    """Independent Beta(a_j, b_j) laws on [low_j, high_j] ⊆ [0, 1] per axis j; ``a``/``b`` [d] or [runs, d]."""

    a: np.ndarray
    b: np.ndarray
    low: np.ndarray
    high: np.ndarray

    @classmethod
    def of(cls, a, b, low=0.0, high=1.0) -> ProductBeta:
        a, b = np.asarray(a, float), np.asarray(b, float)
        if a.shape != b.shape or a.ndim not in (1, 2) or not (np.all(a > 0) and np.all(b > 0)):
            raise ValueError(f"Beta shapes must be positive arrays of one shape [d] or [runs, d], got {a}, {b}")
        d = a.shape[-1]
        low, high = np.broadcast_to(np.asarray(low, float), (d,)), np.broadcast_to(np.asarray(high, float), (d,))
        if not (np.all(0 <= low) and np.all(low < high) and np.all(high <= 1)):
            raise ValueError(f"each axis's support must satisfy 0 <= low < high <= 1, got {low}, {high}")
        return cls(a, b, low.copy(), high.copy())

    @property
    def dim(self) -> int:
        return self.a.shape[-1]

    def runs(self, count: int) -> ProductBeta:
        """The same law for ``count`` independent runs (parameters [count, d])."""
        shape = (count, self.dim)
        return ProductBeta(
            np.broadcast_to(self.a, shape).copy(), np.broadcast_to(self.b, shape).copy(), self.low, self.high
        )

    def _params(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """a, b shaped to broadcast against points [runs, n, d]."""
        a, b = (self.a[:, None, :], self.b[:, None, :]) if self.a.ndim == 2 else (self.a, self.b)
        return a, b

    def sample(self, rng: np.random.Generator, runs: int, n: int) -> np.ndarray:
        """[runs, n, d] points."""
        a, b = self._params(np.empty((runs, 1, self.dim)))
        shape = (runs, n, self.dim)
        return self.low + (self.high - self.low) * rng.beta(np.broadcast_to(a, shape), np.broadcast_to(b, shape))

    def log_pdf(self, points: np.ndarray) -> np.ndarray:
        """[runs, n] log density at ``points`` [runs, n, d] (−inf outside the support)."""
        a, b = self._params(points)
        width = self.high - self.low
        u = (points - self.low) / width
        inside = np.all((u >= 0) & (u <= 1), axis=-1)
        u = np.clip(u, 1e-300, 1 - 1e-16)
        terms = (a - 1) * np.log(u) + (b - 1) * np.log1p(-u) - special.betaln(a, b) - np.log(width)
        return np.where(inside, terms.sum(-1), -np.inf)


def check_support(nominal: ProductBeta, proposal: ProductBeta, names: tuple[str, ...]) -> None:
    """One line naming the axis where the proposal puts mass and the domain's density is zero, if any."""
    for j, name in enumerate(names):
        if nominal.low[j] > proposal.low[j] or nominal.high[j] < proposal.high[j]:
            raise ValueError(
                f"domain.{name}: density zero on part of [{proposal.low[j]:g}, {proposal.high[j]:g}] (unit "
                f"coordinates), where the proposal puts mass; the domain's support is [{nominal.low[j]:g}, "
                f"{nominal.high[j]:g}]: make the domain's range the condition space's"
            )


def mixture_sample(
    nominal: ProductBeta, proposal: ProductBeta, defensive: float, rng: np.random.Generator, runs: int, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Points [runs, n, d] from q = λ·nominal + (1 − λ)·proposal, and their weights nominal/q ≤ 1/λ."""
    if defensive == 1:  # plain Monte Carlo
        return nominal.sample(rng, runs, n), np.ones((runs, n))
    from_nominal = rng.random((runs, n, 1)) < defensive
    points = np.where(from_nominal, nominal.sample(rng, runs, n), proposal.sample(rng, runs, n))
    log_f, log_g = nominal.log_pdf(points), proposal.log_pdf(points)
    with np.errstate(divide="ignore"):
        log_q = np.logaddexp(np.log(defensive) + log_f, np.log1p(-defensive) + log_g if defensive < 1 else -np.inf)
    return points, np.exp(log_f - log_q)


def cross_entropy_step(
    proposal: ProductBeta, points: np.ndarray, margins: np.ndarray, weights: np.ndarray, elite: float, smoothing: float
) -> ProductBeta:
    """One cross-entropy update per run: the points whose margin is at most max(its ``elite`` quantile, 0) (the
    failures once they are that common), weighted by nominal/q, fitted by moments to a Beta per axis, and blended
    with the current law by ``smoothing`` (1: take the fit). The margin orders rollouts before any fails. Ties:
    where the quantile sits on a tie holding every point (±1 margins by the outcome), the elite are the points
    strictly below it (the failures), and a run with none keeps its law: moments of an unranked sample are noise,
    and fitting them narrowed the proposal at random (measured on the suite's outcome-only corner: 1,891 rollouts
    to refute without this guard, 1,170 with it)."""
    level = np.maximum(np.quantile(margins, elite, axis=1), 0.0)[:, None]
    chosen, below = margins <= level, margins < level
    tied = chosen.all(1, keepdims=True)  # the quantile sits on a tie that holds every point
    chosen = np.where(tied, below, chosen)  # then only those strictly below it (a failure among ±1 margins)
    unranked = ~chosen.any(1)
    w = weights * chosen
    w = w / np.maximum(w.sum(1, keepdims=True), 1e-300)
    u = np.clip((points - proposal.low) / (proposal.high - proposal.low), 0, 1)
    mean = np.einsum("rn,rnd->rd", w, u)
    var = np.einsum("rn,rnd->rd", w, (u - mean[:, None, :]) ** 2)
    mean = np.clip(mean, 1e-3, 1 - 1e-3)
    spread = mean * (1 - mean)
    concentration = np.clip(spread / np.maximum(var, spread / (MAX_CONCENTRATION + 1)) - 1, 1.0, MAX_CONCENTRATION)
    a, b = np.maximum(mean * concentration, MIN_SHAPE), np.maximum((1 - mean) * concentration, MIN_SHAPE)
    current = proposal.runs(points.shape[0])
    old_mean, old_total = current.a / (current.a + current.b), current.a + current.b
    new_mean = smoothing * a / (a + b) + (1 - smoothing) * old_mean
    total = np.exp(smoothing * np.log(a + b) + (1 - smoothing) * np.log(old_total))
    a, b = np.maximum(new_mean * total, MIN_SHAPE), np.maximum((1 - new_mean) * total, MIN_SHAPE)
    keep = unranked[:, None]
    return ProductBeta(np.where(keep, current.a, a), np.where(keep, current.b, b), proposal.low, proposal.high)
