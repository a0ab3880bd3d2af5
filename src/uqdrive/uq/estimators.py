"""Estimators of a Bernoulli rate η (η1 or η2) that say whether they carry the (θ, γ) guarantee.

Every estimator returns an :class:`Estimate`. ``guaranteed`` is True only when the scheme,
as it was run, really gives P(|value − η| > θ) ≤ γ for every η, or for every η satisfying the
a-priori assumption written in ``condition``; approximate schemes (Wilson, SPRT intervals)
always say False.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import stats

from uqdrive.uq.bounds import (
    check_counts,
    check_unit,
    chernoff_n,
    clopper_pearson_fits,
    clopper_pearson_interval,
    massart_n,
)
from uqdrive.uq.sequential import sequential_scheme

Draw = Callable[[int], np.ndarray]
"""``draw(k)`` returns k independent 0/1 outcomes; it may run them in parallel."""


@dataclass(frozen=True)
class Estimate:
    """A rate estimate ``value`` with interval ``[low, high]`` from ``n`` samples.

    ``guaranteed``: whether P(|value − η| > θ) ≤ γ really holds for the estimation ``scheme``;
    ``condition``: the assumption on η it holds under ("" when it holds for every η).
    """

    value: float
    low: float
    high: float
    n: int
    theta: float
    gamma: float
    scheme: str  # the estimation scheme (chernoff, clopper_pearson, sequential, …), not the posterior
    guaranteed: bool
    condition: str = ""


def _ball(k: int, n: int, theta: float, gamma: float, scheme: str, guaranteed: bool) -> Estimate:
    v = k / n
    return Estimate(v, max(0.0, v - theta), min(1.0, v + theta), n, theta, gamma, scheme, guaranteed)


def chernoff(k: int, n: int, theta: float, gamma: float) -> Estimate:
    """The paper's estimator k/n ± θ; guaranteed iff n ≥ :func:`chernoff_n` (fixed in advance)."""
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    k, n = check_counts(k, n)
    return _ball(k, n, theta, gamma, "chernoff", n >= chernoff_n(theta, gamma))


def massart(k: int, n: int, theta: float, gamma: float, rate_bound: float = 0.5) -> Estimate:
    """k/n ± θ sized by Massart's bound; holds for every η with min(η, 1 − η) ≤ ``rate_bound``.

    That assumption is the ``condition`` of the result (none when ``rate_bound = 0.5``).
    ``guaranteed`` needs n ≥ :func:`massart_n` and data that do not contradict the assumption:
    when the exact interval at level 1 − γ lies inside (b, 1 − b), every η it admits breaks the
    bound (40 successes of 77 with b = 0.01 would have exact error 0.43), so the flag is False.
    """
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    k, n = check_counts(k, n)
    planned = massart_n(theta, gamma, rate_bound)
    b = float(rate_bound)
    if b >= 0.5:
        return _ball(k, n, theta, gamma, "massart(rate_bound=0.5)", n >= planned)
    low, high = clopper_pearson_interval(k, n, gamma)
    contradicted = bool(low > b and high < 1 - b)
    condition = f"min(eta, 1 - eta) <= {b:g}" + (" (contradicted by the data)" if contradicted else "")
    est = _ball(k, n, theta, gamma, f"massart(rate_bound={b:g})", n >= planned and not contradicted)
    return dataclasses.replace(est, condition=condition)


@lru_cache(maxsize=1024)
def _cp_complete(n: int, theta: float, gamma: float) -> bool:
    return bool(clopper_pearson_fits(n, theta, gamma).all())


def clopper_pearson(k: int, n: int, theta: float, gamma: float) -> Estimate:
    """k/n with the exact interval at level 1 − γ.

    The interval always covers η with probability ≥ 1 − γ; the ±θ guarantee additionally
    needs every possible count at this fixed n to have its interval inside ±θ (true for
    n ≥ :func:`clopper_pearson_n`), which is what ``guaranteed`` reports.
    """
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    k, n = check_counts(k, n)
    low, high = clopper_pearson_interval(k, n, gamma)
    return Estimate(k / n, float(low), float(high), n, theta, gamma, "clopper_pearson", _cp_complete(n, theta, gamma))


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
    low = 0.0 if k == 0 else min(max(centre - half, 0.0), 1.0)  # exact endpoints, not 1 − 1e-16
    high = 1.0 if k == n else min(max(centre + half, 0.0), 1.0)
    return Estimate(p, low, high, n, theta, gamma, "wilson", False)


def _outcomes(batch: np.ndarray, size: int) -> np.ndarray:
    b = np.asarray(batch).reshape(-1)
    if b.shape[0] != size or not np.isin(b, (0, 1)).all():
        raise ValueError(f"draw({size}) must return {size} outcomes in {{0, 1}}, got shape {np.shape(batch)}")
    return b.astype(np.int64)


def sequential(draw: Draw, theta: float, gamma: float, look_size: int = 1) -> Estimate:
    """Sequential estimate with the (θ, γ) guarantee (:mod:`uqdrive.uq.sequential`).

    Calls ``draw(look_size)`` once per look (each batch can run in parallel) and stops as soon as
    the calibrated rule allows; at most ``sequential_scheme(θ, γ, look_size).max_n`` samples. The
    value is k/n or, where a ball other than k/n ± θ settled first, that ball's centre; the interval
    is the ball, value ± θ within [0, 1] (ends rounded to 12 decimals), and its exact coverage is
    what the calibration computed: P(η ∉ [low, high]) ≤ γ for every η.
    """
    scheme = sequential_scheme(theta, gamma, look_size)
    k, n = 0, 0
    while True:
        k += int(_outcomes(draw(scheme.look_size), scheme.look_size).sum())
        n += scheme.look_size
        if scheme.stops(k, n):
            value, low, high = scheme.report(k, n)
            return Estimate(value, low, high, n, scheme.theta, scheme.gamma, "sequential", True)


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
