"""A confidence interval for the mean of a bounded variable that holds for every distribution on its range:
betting (Waudby-Smith & Ramdas, "Estimating means of bounded random variables by betting", JRSS-B 2024).

Why not Student's t: training runs that fail outright make the per-run differences skewed or bimodal, and the t's
error then reaches 100× its level (`tests/test_uq_claims.py` measures it). Why not Hoeffding: it ignores the
spread the data show and is far wider where runs agree.

Scaled to x ∈ [0, 1], for a candidate mean m a gambler starts with wealth 1 and stakes a fraction λ_i of it on
x_i − m, λ_i fixed by x_1 … x_{i−1} only: K⁺(m) = ∏ (1 + λ_i (x_i − m)) bets the mean is above m, K⁻(m) below.
If the mean of independent x_i is m (or below, for K⁺; above, for K⁻), each is a nonnegative supermartingale
starting at 1, so P(K ≥ 2/α) ≤ α/2 (Markov; Ville at any stopping time). The lower end is the smallest m at
which K⁺(m) stays below 2/α, the upper end the largest at which K⁻(m) does: each end misses with probability
≤ α/2, whatever the distribution. The stakes are WSR's predictable plug-in, capped at c/m (c/(1 − m)) so the
wealth never reaches 0; with that cap K⁺ is non-increasing in m and K⁻ non-decreasing, so both ends are found
by bisection. Observations enter in the order given (e.g. replicate order, fixed before the data).

Two tunings of the stakes, both predictable and so both valid: WSR's confidence-sequence stakes (the default;
valid at any stopping time, λ_i shrinking like 1/√(i ln i)) and, where the number of observations N is fixed
before the data (``horizon``), WSR's fixed-N confidence-interval stakes λ_i = √(2 ln(2/α)/(σ̂²_{i−1} N)), narrower
for that N (docs/measurements.md compares them with empirical-Bernstein and Hoeffding on the study's spread).
`rejects` reads the same wealth at one candidate mean: the interval's end lies past it exactly when it rejects.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from uqdrive.uq.bounds import check_unit

CAP = 0.75  # c: a stake never risks more than 75 % of the wealth on one observation (WSR's hedged choice)
BISECTIONS = 40  # halvings of [0, 1]: ends found to 1e-12, rounded outward


@dataclasses.dataclass(frozen=True)
class MeanInterval:
    """The betting interval [``low``, ``high``] for the mean at level 1 − ``level`` (each end misses with
    probability ≤ level/2); ``estimate``: the sample mean; ``p_value``: of the two-sided test of "the mean is
    ``null``" (2 / the larger wealth, at most 1): p ≤ level exactly when the interval excludes ``null``.
    Arrays shaped like the values less their last axis."""

    estimate: np.ndarray
    low: np.ndarray
    high: np.ndarray
    p_value: np.ndarray
    null: float
    level: float


def _stakes(x: np.ndarray, level: float, horizon: int | None = None) -> np.ndarray:
    """WSR's predictable plug-in stakes λ̃_i = √(2 ln(2/α) / (σ̂²_{i−1} i ln(1 + i))), σ̂² a running variance
    shrunk toward ¼ (so the first stake is defined), over the last axis; with a fixed ``horizon`` N,
    λ̃_i = √(2 ln(2/α) / (σ̂²_{i−1} N)) (WSR's fixed-N plug-in)."""
    count = x.shape[-1]
    i = np.arange(1, count + 1)
    means = (0.5 + np.cumsum(x, -1)) / (i + 1)
    previous_means = np.concatenate([np.full(x.shape[:-1] + (1,), 0.5), means[..., :-1]], -1)
    variances = (0.25 + np.cumsum((x - previous_means) ** 2, -1)) / (i + 1)
    previous = np.concatenate([np.full(x.shape[:-1] + (1,), 0.25), variances[..., :-1]], -1)
    spend = i * np.log1p(i) if horizon is None else np.full(count, float(horizon))
    return np.sqrt(2 * np.log(2 / level) / (previous * spend))


def _log_wealth(x: np.ndarray, stakes: np.ndarray, m: np.ndarray, above: bool, cap: float = CAP) -> np.ndarray:
    """log K⁺(m) (``above``) or log K⁻(m) for every row of ``x`` at its own candidate ``m``."""
    m = m[..., None]
    if above:
        lam = np.minimum(stakes, cap / np.maximum(m, 1e-300))
        return np.sum(np.log1p(lam * (x - m)), -1)
    lam = np.minimum(stakes, cap / np.maximum(1 - m, 1e-300))
    return np.sum(np.log1p(-lam * (x - m)), -1)


def _end(x: np.ndarray, stakes: np.ndarray, threshold: float, above: bool, cap: float) -> np.ndarray:
    """The lower end (``above``: the smallest m with K⁺(m) < threshold) or the upper end, rounded outward."""
    shape = x.shape[:-1]
    rejected, kept = (np.zeros(shape), np.ones(shape)) if above else (np.ones(shape), np.zeros(shape))
    edge_kept = _log_wealth(x, stakes, rejected, above, cap) < threshold  # the edge itself is not rejected
    for _ in range(BISECTIONS):
        middle = (rejected + kept) / 2
        reject = _log_wealth(x, stakes, middle, above, cap) >= threshold
        rejected, kept = np.where(reject, middle, rejected), np.where(reject, kept, middle)
    return np.where(edge_kept, 0.0 if above else 1.0, rejected)


def _scaled(values, low: float, high: float, block: int) -> np.ndarray:
    values = np.asarray(values, float)
    if values.ndim < 1 or values.shape[-1] < 1:
        raise ValueError(f"the betting interval needs at least one observation, got shape {values.shape}")
    if not high > low or np.any(values < low) or np.any(values > high) or not np.isfinite(values).all():
        raise ValueError(f"every value must lie in [{low}, {high}]")
    if values.shape[-1] % block:
        raise ValueError(f"{values.shape[-1]} observations do not fill blocks of {block}")
    return (values - low) / (high - low)


def rejects(
    values, low: float, high: float, level: float, tests, horizon: int | None = None, cap: float = CAP
) -> np.ndarray:
    """Whether the betting test at level 1 − ``level`` rejects "the mean is ``at``" on one side, for each
    (``at``, ``above``) of ``tests``: ``above``, that the mean is ≤ ``at`` (then the interval's lower end lies above
    ``at``), else that it is ≥ ``at`` (its upper end lies below). Each side errs with probability ≤ level/2 for
    every distribution on [low, high]. Shape: (len(tests), *leading axes); the same stakes, ``horizon`` and ``cap``
    as `mean_interval` (block 1)."""
    x = _scaled(values, low, high, 1)
    stakes, threshold = _stakes(x, check_unit("level", level), horizon), np.log(2 / level)
    shape = x.shape[:-1]
    return np.stack(
        [
            _log_wealth(x, stakes, np.full(shape, (at - low) / (high - low)), above, cap) >= threshold
            for at, above in tests
        ]
    )


def mean_interval(
    values,
    low: float,
    high: float,
    level: float,
    block: int = 1,
    null: float = 0.0,
    horizon: int | None = None,
    cap: float = CAP,
) -> MeanInterval:
    """The betting interval for the mean of independent ``values`` (last axis: the observations, in a fixed order)
    known to lie in [``low``, ``high``], at level 1 − ``level``; vectorised over the leading axes.

    ``block`` > 1: the observations come in blocks of that many with their own means (one from each of ``block``
    strata, e.g. a rollout of each controller), and the interval is for the mean of the strata's means. The stake
    is fixed for a whole block (from the blocks before it), so by the AM–GM inequality a block's factors multiply
    to at most (1 + λ (mean of the strata's means − m))^block in expectation: the wealth stays a supermartingale
    under the averaged null. ``horizon``: the fixed number of observations the fixed-N stakes are tuned for;
    ``cap``: c < 1, the largest share of the wealth one stake risks (any c < 1 keeps the guarantee)."""
    if not 0 < cap < 1:
        raise ValueError(f"cap must lie in (0, 1), got {cap}")
    level = check_unit("level", level)
    values = np.asarray(values, float)
    x = _scaled(values, low, high, block)
    stakes, threshold = np.repeat(_stakes(x, level, horizon)[..., ::block], block, -1), np.log(2 / level)
    lower, upper = _end(x, stakes, threshold, True, cap), _end(x, stakes, threshold, False, cap)
    at_null = np.full(x.shape[:-1], (null - low) / (high - low))
    above, below = _log_wealth(x, stakes, at_null, True, cap), _log_wealth(x, stakes, at_null, False, cap)
    p_value = np.minimum(1.0, 2 * np.exp(-np.maximum(above, below)))
    scale = high - low
    lower, upper = low + scale * lower, low + scale * upper
    # the bisection rounds each end outward; where the test rejects the null the end is kept past it, so the
    # interval excludes the null exactly when p ≤ level
    lower = np.where(above >= threshold, np.maximum(lower, np.nextafter(null, np.inf)), lower)
    upper = np.where(below >= threshold, np.minimum(upper, np.nextafter(null, -np.inf)), upper)
    return MeanInterval(values.mean(-1), lower, upper, p_value, float(null), level)
