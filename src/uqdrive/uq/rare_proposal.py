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
MIXTURE_CONCENTRATION = 300.0  # a mixture component's cap: each covers one failure mode and the components together
# the set, so they may be narrow (sd ≥ 3 % of the support); on the suite's 16 small modes cap 30 left the mixture
# no better than one law (3,604 rollouts to refute p = 10⁻³ against m = 10⁻⁴), 300 took 1,566
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
        return _log_density(points, a, b, self.low, self.high)

    def step(self, points, margins, weights, elite: float, smoothing: float) -> ProductBeta:
        """The cross-entropy update (`cross_entropy_step`)."""
        return cross_entropy_step(self, points, margins, weights, elite, smoothing)


def _log_density(points: np.ndarray, a: np.ndarray, b: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """Σ_j log Beta(a_j, b_j) density on [low_j, high_j] at ``points`` (last axis j; −inf outside the support)."""
    width = high - low
    u = (points - low) / width
    inside = np.all((u >= 0) & (u <= 1), axis=-1)
    u = np.clip(u, 1e-300, 1 - 1e-16)
    terms = (a - 1) * np.log(u) + (b - 1) * np.log1p(-u) - special.betaln(a, b) - np.log(width)
    return np.where(inside, terms.sum(-1), -np.inf)


@dataclass(frozen=True)
class BetaMixture:
    """Σ_k π_k Π_j Beta(a_kj, b_kj) on one support: ``a``, ``b`` [runs, K, d], ``weights`` π [runs, K]. A proposal
    that can sit on several failure modes at once, where one product of Betas sits on one (or between them)."""

    a: np.ndarray
    b: np.ndarray
    weights: np.ndarray
    low: np.ndarray
    high: np.ndarray

    @classmethod
    def copies(cls, law: ProductBeta, components: int, runs: int) -> BetaMixture:
        """``components`` equal copies of ``law`` per run: the first step's seeding tells them apart."""
        one = law.runs(runs)
        a, b = (np.repeat(x[:, None, :], components, 1) for x in (one.a, one.b))
        return cls(a, b, np.full((runs, components), 1.0 / components), law.low, law.high)

    @property
    def dim(self) -> int:
        return self.a.shape[-1]

    def sample(self, rng: np.random.Generator, runs: int, n: int) -> np.ndarray:
        """[runs, n, d] points: each point's component drawn by π, then its Betas."""
        cumulative = np.cumsum(self.weights, 1)
        k = np.minimum(
            (rng.random((runs, n, 1)) * cumulative[:, None, -1:] > cumulative[:, None, :]).sum(-1), self.a.shape[1] - 1
        )
        a, b = (np.take_along_axis(x, k[..., None], 1) for x in (self.a, self.b))
        return self.low + (self.high - self.low) * rng.beta(a, b)

    def log_pdf(self, points: np.ndarray) -> np.ndarray:
        """[runs, n] log density at ``points`` [runs, n, d]: log Σ_k π_k g_k."""
        per = _log_density(points[:, :, None, :], self.a[:, None], self.b[:, None], self.low, self.high)
        with np.errstate(divide="ignore"):
            return special.logsumexp(per + np.log(self.weights)[:, None, :], axis=-1)

    def step(self, points, margins, weights, elite: float, smoothing: float) -> BetaMixture:
        """The cross-entropy update for a mixture (`mixture_step`); ``smoothing`` is 1 (checked by RareSettings)."""
        return mixture_step(self, points, margins, weights, elite)


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
    nominal: ProductBeta,
    proposal: ProductBeta | BetaMixture,
    defensive: float,
    rng: np.random.Generator,
    runs: int,
    n: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Points [runs, n, d] from q = λ·nominal + (1 − λ)·proposal, and their weights nominal/q ≤ 1/λ."""
    if defensive == 1:  # plain Monte Carlo
        return nominal.sample(rng, runs, n), np.ones((runs, n))
    from_nominal = rng.random((runs, n, 1)) < defensive
    points = np.where(from_nominal, nominal.sample(rng, runs, n), proposal.sample(rng, runs, n))
    log_f, log_g = nominal.log_pdf(points), proposal.log_pdf(points)
    with np.errstate(divide="ignore"):
        log_q = np.logaddexp(np.log(defensive) + log_f, np.log1p(-defensive) + log_g if defensive < 1 else -np.inf)
    return points, np.minimum(np.exp(log_f - log_q), 1.0 / defensive)  # where g underflows: 1/λ, not 1/λ + ulp


def _elite(margins: np.ndarray, weights: np.ndarray, elite: float) -> tuple[np.ndarray, np.ndarray]:
    """Each run's elite, weighted by nominal/q and normalised ([runs, n]), and the runs with none (``unranked``).
    The elite: the points whose margin is at most max(its ``elite`` quantile, 0) (the failures once they are that
    common); where the quantile sits on a tie holding every point (±1 margins by the outcome), only those strictly
    below it (the failures)."""
    level = np.maximum(np.quantile(margins, elite, axis=1), 0.0)[:, None]
    chosen, below = margins <= level, margins < level
    tied = chosen.all(1, keepdims=True)  # the quantile sits on a tie that holds every point
    chosen = np.where(tied, below, chosen)  # then only those strictly below it (a failure among ±1 margins)
    w = weights * chosen
    return w / np.maximum(w.sum(1, keepdims=True), 1e-300), ~chosen.any(1)


def _moment_fit(u: np.ndarray, w: np.ndarray, cap: float = MAX_CONCENTRATION) -> tuple[np.ndarray, np.ndarray]:
    """Beta shapes [runs, K, d] matching the ``w``-weighted ([runs, n, K], each column summing to 1) mean and
    variance of ``u`` [runs, n, d], the concentration in [1, ``cap``], each shape ≥ MIN_SHAPE."""
    mean = np.einsum("rnk,rnd->rkd", w, u)
    var = np.einsum("rnk,rnkd->rkd", w, (u[:, :, None, :] - mean[:, None]) ** 2)
    mean = np.clip(mean, 1e-3, 1 - 1e-3)
    spread = mean * (1 - mean)
    concentration = np.clip(spread / np.maximum(var, spread / (cap + 1)) - 1, 1.0, cap)
    return np.maximum(mean * concentration, MIN_SHAPE), np.maximum((1 - mean) * concentration, MIN_SHAPE)


def _unit(law: ProductBeta | BetaMixture, points: np.ndarray) -> np.ndarray:
    return np.clip((points - law.low) / (law.high - law.low), 0, 1)


def cross_entropy_step(
    proposal: ProductBeta, points: np.ndarray, margins: np.ndarray, weights: np.ndarray, elite: float, smoothing: float
) -> ProductBeta:
    """One cross-entropy update per run: the elite (`_elite`) fitted by moments to a Beta per axis, and blended
    with the current law by ``smoothing`` (1: take the fit). The margin orders rollouts before any fails. A run with
    no elite keeps its law: moments of an unranked sample are noise, and fitting them narrowed the proposal at
    random (measured on the suite's outcome-only corner: 1,891 rollouts to refute without this guard, 1,170 with
    it)."""
    w, unranked = _elite(margins, weights, elite)
    a, b = (x[:, 0] for x in _moment_fit(_unit(proposal, points), w[..., None]))
    current = proposal.runs(points.shape[0])
    old_mean, old_total = current.a / (current.a + current.b), current.a + current.b
    new_mean = smoothing * a / (a + b) + (1 - smoothing) * old_mean
    total = np.exp(smoothing * np.log(a + b) + (1 - smoothing) * np.log(old_total))
    a, b = np.maximum(new_mean * total, MIN_SHAPE), np.maximum((1 - new_mean) * total, MIN_SHAPE)
    keep = unranked[:, None]
    return ProductBeta(np.where(keep, current.a, a), np.where(keep, current.b, b), proposal.low, proposal.high)


def _farthest(u: np.ndarray, w: np.ndarray, count: int) -> np.ndarray:
    """``count`` centres [runs, count, d] among each run's elite points (w > 0): the heaviest first, then each time
    the elite point farthest from every centre so far, so separate failure modes get separate centres."""
    runs = np.arange(u.shape[0])
    centres = [u[runs, np.argmax(w, 1)]]
    nearest = np.linalg.norm(u - centres[0][:, None], axis=-1)
    for _ in range(count - 1):
        centres.append(u[runs, np.argmax(np.where(w > 0, nearest, -1.0), 1)])
        nearest = np.minimum(nearest, np.linalg.norm(u - centres[-1][:, None], axis=-1))
    return np.stack(centres, 1)


def mixture_step(
    mixture: BetaMixture, points: np.ndarray, margins: np.ndarray, weights: np.ndarray, elite: float
) -> BetaMixture:
    """One cross-entropy update of a K-component mixture per run: the elite (`_elite`) split among K centres by
    farthest-point seeding (`_farthest`), each point to its nearest centre, each component fitted by moments to its
    points and weighted by their share of the elite's weight. A component left with no point keeps its shapes at
    weight 0; a run with no elite keeps its law. Predictable as the single law is: a function of past rounds only."""
    w, unranked = _elite(margins, weights, elite)
    u, components = _unit(mixture, points), mixture.a.shape[1]
    centres = _farthest(u, w, components)
    nearest = np.argmin(np.linalg.norm(u[:, :, None, :] - centres[:, None], axis=-1), 2)
    member = w[..., None] * (nearest[..., None] == np.arange(components))
    mass = member.sum(1)
    a, b = _moment_fit(u, member / np.maximum(mass[:, None, :], 1e-300), MIXTURE_CONCENTRATION)
    empty = (mass <= 0)[..., None] | unranked[:, None, None]
    share = np.where(unranked[:, None], mixture.weights, mass / np.maximum(mass.sum(1, keepdims=True), 1e-300))
    return BetaMixture(np.where(empty, mixture.a, a), np.where(empty, mixture.b, b), share, mixture.low, mixture.high)
