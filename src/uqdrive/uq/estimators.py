"""Estimators of a Bernoulli rate η (η1 or η2) that say whether they carry the (θ, γ) guarantee.

Every estimator returns an :class:`Estimate`. ``guaranteed`` is True only when the scheme,
as it was run, really gives P(|value − η| > θ) ≤ γ for every η (under any stated a-priori
assumption); approximate schemes (Wilson, SPRT intervals) always say False.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np
from scipy import stats

from uqdrive.uq.bounds import (
    check_counts,
    check_unit,
    chernoff_n,
    clopper_pearson_fits,
    clopper_pearson_interval,
    clopper_pearson_n,
    first_fit_n,
    massart_n,
)

Draw = Callable[[int], np.ndarray]
"""``draw(k)`` returns k independent 0/1 outcomes; it may run them in parallel."""


@dataclass(frozen=True)
class Estimate:
    """A rate estimate ``value`` with interval ``[low, high]`` from ``n`` samples.

    ``guaranteed``: whether P(|value − η| > θ) ≤ γ really holds for the scheme ``method``.
    """

    value: float
    low: float
    high: float
    n: int
    theta: float
    gamma: float
    method: str
    guaranteed: bool


def _ball(k: int, n: int, theta: float, gamma: float, method: str, guaranteed: bool) -> Estimate:
    v = k / n
    return Estimate(v, max(0.0, v - theta), min(1.0, v + theta), n, theta, gamma, method, guaranteed)


def chernoff(k: int, n: int, theta: float, gamma: float) -> Estimate:
    """The paper's estimator k/n ± θ; guaranteed iff n ≥ :func:`chernoff_n` (fixed in advance)."""
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    k, n = check_counts(k, n)
    return _ball(k, n, theta, gamma, "chernoff", n >= chernoff_n(theta, gamma))


def massart(k: int, n: int, theta: float, gamma: float, rate_bound: float = 0.5) -> Estimate:
    """k/n ± θ sized by Massart's bound; guaranteed iff n ≥ :func:`massart_n`, *given* the
    a-priori assumption min(η, 1 − η) ≤ ``rate_bound`` (named in ``method``)."""
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    k, n = check_counts(k, n)
    ok = n >= massart_n(theta, gamma, rate_bound)
    return _ball(k, n, theta, gamma, f"massart(rate_bound={rate_bound:g})", ok)


@lru_cache(maxsize=1024)
def _cp_complete(n: int, gamma: float, theta: float) -> bool:
    return bool(clopper_pearson_fits(n, gamma, theta).all())


def clopper_pearson(k: int, n: int, theta: float, gamma: float) -> Estimate:
    """k/n with the exact interval at level 1 − γ.

    The interval always covers η with probability ≥ 1 − γ; the ±θ guarantee additionally
    needs every possible count at this fixed n to have its interval inside ±θ (true for
    n ≥ :func:`clopper_pearson_n`), which is what ``guaranteed`` reports.
    """
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    k, n = check_counts(k, n)
    low, high = clopper_pearson_interval(k, n, gamma)
    return Estimate(k / n, float(low), float(high), n, theta, gamma, "clopper_pearson", _cp_complete(n, gamma, theta))


def wilson(k: int, n: int, theta: float, gamma: float) -> Estimate:
    """Wilson score interval: a normal approximation, so never labelled guaranteed.

    Its coverage dips below 1 − γ for some η and n; kept only as a familiar reference.
    """
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    k, n = check_counts(k, n)
    z = stats.norm.ppf(1 - gamma / 2)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return Estimate(p, max(0.0, centre - half), min(1.0, centre + half), n, theta, gamma, "wilson", False)


@dataclass(frozen=True)
class SequentialPlan:
    """Group-sequential look schedule: after ``looks[j]`` samples, spend ``gammas[j]`` of γ.

    Rule: at look j compute the exact (Clopper–Pearson) interval at level 1 − γ_j and stop
    when it lies inside [p̂ − θ, p̂ + θ]; the final look must be *complete* (every count stops).
    Guarantee: when the run stops at look j with |p̂ − η| > θ, η lies outside that look's
    interval; each interval misses η with probability ≤ γ_j whatever η is, so by the union
    bound over looks P(|p̂ − η| > θ) ≤ Σ γ_j ≤ γ (Bonferroni holds for any, unequal, split).
    The same bound shows the reported interval covers η with probability ≥ 1 − γ.
    """

    theta: float
    gamma: float
    looks: tuple[int, ...]
    gammas: tuple[float, ...]

    def __post_init__(self) -> None:
        check_unit("theta", self.theta)
        check_unit("gamma", self.gamma)
        looks, gammas = tuple(self.looks), tuple(float(g) for g in self.gammas)
        if not looks or len(looks) != len(gammas):
            raise ValueError(f"looks and gammas must be non-empty and of equal length, got {looks} and {gammas}")
        if any(int(n) != n or n < 1 for n in looks) or any(b <= a for a, b in zip(looks, looks[1:])):
            raise ValueError(f"looks must be strictly increasing integers >= 1, got {looks}")
        object.__setattr__(self, "looks", tuple(int(n) for n in looks))
        object.__setattr__(self, "gammas", gammas)
        if any(not 0 < g < 1 for g in gammas) or sum(gammas) > self.gamma * (1 + 1e-12):
            raise ValueError(f"gammas must be in (0, 1) and sum to at most gamma={self.gamma}, got {gammas}")
        if not _cp_complete(looks[-1], gammas[-1], self.theta):
            raise ValueError(
                f"final look n={looks[-1]} at gamma={gammas[-1]} is not complete for theta={self.theta}: "
                f"use n >= clopper_pearson_n(theta, gamma_final)={clopper_pearson_n(self.theta, gammas[-1])}"
            )

    @cached_property
    def stop_tables(self) -> tuple[np.ndarray, ...]:
        """``stop_tables[j][k]``: does look j stop with k successes? (The last is all True.)"""
        return tuple(clopper_pearson_fits(n, g, self.theta) for n, g in zip(self.looks, self.gammas))


def sequential_plan(theta: float, gamma: float) -> SequentialPlan:
    """Default plan: two early looks and one final look, γ split γ/2, γ/10, 2γ/5.

    The final look is :func:`clopper_pearson_n` at 2γ/5 (561 at θ = γ = 0.05, 0.76 of
    Chernoff's 738, so the worst case stays below the paper's n). The early looks sit where a
    count with ≤ 2 (at level γ/2) and ≤ 6 (at level γ/10) minority outcomes first fits in ±θ
    (119 and 206 at θ = γ = 0.05): near η = 0 or 1 most runs stop there. The split was chosen
    by exact expected sample sizes (:func:`sequential_operating_characteristics`): a large
    first-look share buys early stops near 0 and 1, the final share keeps the worst case low.
    Early looks that would not come before the final one are dropped (their γ is unspent).
    """
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    g1, g2, g_final = gamma / 2, gamma / 10, 2 * gamma / 5
    final = clopper_pearson_n(theta, g_final)
    early = [(n, g) for n, g in ((first_fit_n(2, g1, theta), g1), (first_fit_n(6, g2, theta), g2)) if n < final]
    if len(early) == 2 and early[1][0] <= early[0][0]:
        early = early[:1]
    looks = tuple(n for n, _ in early) + (final,)
    return SequentialPlan(theta, gamma, looks, tuple(g for _, g in early) + (g_final,))


def _plan_for(theta: float, gamma: float, plan: SequentialPlan | None) -> SequentialPlan:
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    if plan is None:
        return sequential_plan(theta, gamma)
    if (plan.theta, plan.gamma) != (theta, gamma):
        raise ValueError(f"plan is for theta={plan.theta}, gamma={plan.gamma}, not theta={theta}, gamma={gamma}")
    return plan


def _outcomes(batch: np.ndarray, size: int) -> np.ndarray:
    b = np.asarray(batch).reshape(-1)
    if b.shape[0] != size or not np.isin(b, (0, 1)).all():
        raise ValueError(f"draw({size}) must return {size} outcomes in {{0, 1}}, got shape {np.shape(batch)}")
    return b.astype(np.int64)


def sequential(draw: Draw, theta: float, gamma: float, plan: SequentialPlan | None = None) -> Estimate:
    """Group-sequential estimate with the (θ, γ) guarantee (see :class:`SequentialPlan`).

    Calls ``draw`` once per look with the number of new samples needed, so each batch can be
    run in parallel; stops early when η is near 0 or 1, never uses more than the final look.
    """
    plan = _plan_for(theta, gamma, plan)
    k, used = 0, 0
    for n, g, stop in zip(plan.looks, plan.gammas, plan.stop_tables):
        k += int(_outcomes(draw(n - used), n - used).sum())
        used = n
        if stop[k]:
            break
    low, high = clopper_pearson_interval(k, used, g)
    return Estimate(k / used, float(low), float(high), used, plan.theta, plan.gamma, "sequential", True)


def simulate_sequential(
    rate: float, reps: int, rng: np.random.Generator, plan: SequentialPlan
) -> tuple[np.ndarray, np.ndarray]:
    """Run ``reps`` independent sequential estimates at true ``rate`` at once: (values, samples used)."""
    k = np.zeros(reps, dtype=np.int64)
    value = np.empty(reps)
    used = np.zeros(reps, dtype=np.int64)
    prev = 0
    for n, stop in zip(plan.looks, plan.stop_tables):
        k += rng.binomial(n - prev, rate, size=reps)
        prev = n
        now = (used == 0) & stop[k]
        value[now] = k[now] / n
        used[now] = n
    return value, used


def sequential_operating_characteristics(plan: SequentialPlan, rate: float) -> tuple[float, float]:
    """Exact (expected samples, P(|p̂ − η| > θ)) of ``plan`` at true ``rate``, by dynamic programming
    over the count at each look; lets tests check the guarantee with no Monte-Carlo slack."""
    dist = np.ones(1)
    prev, mean_n, error = 0, 0.0, 0.0
    for n, stop in zip(plan.looks, plan.stop_tables):
        dist = np.convolve(dist, stats.binom.pmf(np.arange(n - prev + 1), n - prev, rate))
        prev = n
        far = np.abs(np.arange(n + 1) / n - rate) > plan.theta
        mean_n += n * dist[stop].sum()
        error += dist[stop & far].sum()
        dist = np.where(stop, 0.0, dist)
    return float(mean_n), float(error)


@dataclass(frozen=True)
class SPRTResult:
    """Wald SPRT outcome: ``accept`` is the decision "η ≥ δ"; ``truncated`` if the cap decided it."""

    accept: bool
    truncated: bool
    llr: float
    estimate: Estimate


@dataclass(frozen=True)
class _SPRTParams:
    delta: float
    half_width: float
    alpha: float
    beta: float
    max_n: int

    @property
    def steps(self) -> tuple[float, float]:
        p0, p1 = self.delta - self.half_width, self.delta + self.half_width
        return math.log(p1 / p0), math.log((1 - p1) / (1 - p0))

    @property
    def thresholds(self) -> tuple[float, float]:
        return math.log(self.beta / (1 - self.alpha)), math.log((1 - self.beta) / self.alpha)


def _sprt_params(delta: float, half_width: float, alpha: float, beta: float, max_n: int | None) -> _SPRTParams:
    delta, alpha, beta = check_unit("delta", delta), check_unit("alpha", alpha), check_unit("beta", beta)
    if not (0 < half_width and 0 < delta - half_width and delta + half_width < 1):
        raise ValueError(f"half_width must be > 0 with 0 < delta ± half_width < 1, got {half_width!r} (delta={delta})")
    if alpha + beta >= 1:
        raise ValueError(f"alpha + beta must be < 1, got {alpha} + {beta}")
    cap = chernoff_n(half_width, min(alpha, beta)) if max_n is None else max_n
    if int(cap) != cap or cap < 1:
        raise ValueError(f"max_n must be an integer >= 1, got {max_n!r}")
    return _SPRTParams(delta, float(half_width), alpha, beta, int(cap))


def sprt_cap(delta: float, half_width: float, alpha: float = 0.05, beta: float = 0.05, max_n: int | None = None) -> int:
    """The SPRT's worst-case sample count (its cap) after validating the test's parameters."""
    return _sprt_params(delta, half_width, alpha, beta, max_n).max_n


def _sprt_estimate(k: int, n: int, prm: _SPRTParams) -> Estimate:
    low, high = clopper_pearson_interval(k, n, prm.alpha + prm.beta)
    return Estimate(k / n, float(low), float(high), n, prm.half_width, prm.alpha + prm.beta, "sprt", False)


def sprt(
    draw: Draw,
    delta: float,
    half_width: float,
    alpha: float = 0.05,
    beta: float = 0.05,
    max_n: int | None = None,
    batch: int = 16,
) -> SPRTResult:
    """Wald's sequential probability ratio test of η ≤ δ − Δ against η ≥ δ + Δ (Δ = ``half_width``).

    Decides "η ≥ δ" with error rates about α (when η ≤ δ − Δ) and β (when η ≥ δ + Δ) — Wald's
    thresholds give α' + β' ≤ α + β — and no promise inside the indifference region. At the cap
    (default: Chernoff's n for (Δ, min(α, β))) it decides by p̂ ≥ δ, which adds at most min(α, β).
    It guarantees the *decision*, not |p̂ − η| ≤ θ: optional stopping biases p̂, so the returned
    interval (exact, at level α + β, as if n had been fixed) is labelled guaranteed=False.
    ``draw`` is called with ``batch`` samples at a time (run in parallel); samples after the
    boundary crossing within a batch are discarded.
    """
    prm = _sprt_params(delta, half_width, alpha, beta, max_n)
    up, down = prm.steps
    lo, hi = prm.thresholds
    llr, k, n = 0.0, 0, 0
    while n < prm.max_n:
        size = min(batch, prm.max_n - n)
        x = _outcomes(draw(size), size)
        path = llr + np.cumsum(np.where(x == 1, up, down))
        crossed = np.flatnonzero((path <= lo) | (path >= hi))
        m = int(crossed[0]) + 1 if crossed.size else size
        llr, k, n = float(path[m - 1]), k + int(x[:m].sum()), n + m
        if crossed.size:
            return SPRTResult(llr >= hi, False, llr, _sprt_estimate(k, n, prm))
    return SPRTResult(k / n >= prm.delta, True, llr, _sprt_estimate(k, n, prm))


def simulate_sprt(
    rate: float,
    reps: int,
    rng: np.random.Generator,
    delta: float,
    half_width: float,
    alpha: float = 0.05,
    beta: float = 0.05,
    max_n: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Run ``reps`` SPRTs at true ``rate`` at once: (accept decisions, samples used)."""
    prm = _sprt_params(delta, half_width, alpha, beta, max_n)
    up, down = prm.steps
    lo, hi = prm.thresholds
    x = rng.random((reps, prm.max_n)) < rate
    path = np.cumsum(np.where(x, up, down), axis=1)
    crossed = (path <= lo) | (path >= hi)
    hit = crossed.any(axis=1)
    m = np.where(hit, crossed.argmax(axis=1) + 1, prm.max_n)
    final = path[np.arange(reps), m - 1]
    k = np.cumsum(x, axis=1)[np.arange(reps), m - 1]
    accept = np.where(hit, final >= hi, k / m >= prm.delta)
    return accept, m
