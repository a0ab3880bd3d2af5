"""Sample sizes and exact intervals for estimating a Bernoulli rate η to within ±θ with confidence 1 − γ.

η is either η1 (fraction of safe paths) or η2 (fraction of weight samples deciding within ε of
π(o)); both are Bernoulli rates, so everything here is about k successes in n draws.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from scipy import special


def check_unit(name: str, value: float) -> float:
    """Return ``value`` as float if it lies in the open interval (0, 1), else raise ``ValueError``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not (0.0 < v < 1.0):
        raise ValueError(f"{name} must be in (0, 1), got {value!r}")
    return v


def check_look_size(look_size: int) -> int:
    """Validate the samples drawn between two looks of a sequential scheme (an integer ≥ 1)."""
    if isinstance(look_size, bool) or int(look_size) != look_size or look_size < 1:
        raise ValueError(f"look_size must be an integer >= 1 (samples between looks), got {look_size!r}")
    return int(look_size)


def check_counts(k: int, n: int) -> tuple[int, int]:
    """Validate a success count ``k`` out of ``n`` draws (integers, 0 ≤ k ≤ n, n ≥ 1)."""
    if int(n) != n or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    if int(k) != k or not 0 <= k <= n:
        raise ValueError(f"k must be an integer in [0, n={int(n)}], got {k!r}")
    return int(k), int(n)


def chernoff_n(theta: float, gamma: float) -> int:
    """The paper's a-priori sample size: the smallest integer n > ln(2/γ) / (2θ²).

    By the Chernoff–Hoeffding bound P(|η̂ − η| > θ) ≤ 2·exp(−2nθ²) ≤ γ for every η, so the
    n runs can be planned and launched in parallel before any result is seen (θ = γ = 0.05 → 738).
    """
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    return math.floor(math.log(2 / gamma) / (2 * theta**2)) + 1


def massart_h(p: float, theta: float) -> float:
    """Massart's exponent h_a(p, θ) = 9 / (2 (3p + θ)(3(1 − p) − θ)), for 0 ≤ p < 1 − θ."""
    return 4.5 / ((3 * p + theta) * (3 * (1 - p) - theta))


def massart_n(theta: float, gamma: float, rate_bound: float = 0.5) -> int:
    """Sample size from Massart's bound, given a-priori min(η, 1 − η) ≤ ``rate_bound`` ≤ ½.

    Massart (1990, "The tight constant in the Dvoretzky–Kiefer–Wolfowitz inequality", Ann.
    Probab. 18(3)), in the form used by Jegourel, Sun & Dong (2019, "Sequential schemes for
    frequentist estimation of properties in statistical model checking", ACM TOMACS; QEST 2017):
    P(η̂ − η ≥ θ) ≤ exp(−nθ² h_a(η, θ)) for η < 1 − θ, and P(η̂ − η ≤ −θ) ≤ exp(−nθ² h_b(η, θ))
    with h_b(η, θ) = h_a(1 − η, θ). For η ≤ ½ one has h_a ≤ h_b, and h_a(·, θ) decreases up to
    p* = ½ − θ/3 where it equals 2 (Hoeffding). Hence with p = min(rate_bound, p*),
    n ≥ ln(2/γ) / (θ² h_a(p, θ)) gives P(|η̂ − η| > θ) ≤ γ for every η in the assumed range
    (and for η ≥ 1 − rate_bound by symmetry). ``rate_bound = 0.5`` assumes nothing and never
    needs more than Chernoff; the guarantee is only as good as the a-priori bound.
    """
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    try:
        b = float(rate_bound)
    except (TypeError, ValueError):
        b = math.nan
    if not 0.0 <= b <= 0.5:
        raise ValueError(f"rate_bound must be in [0, 0.5] (a bound on min(eta, 1 - eta)), got {rate_bound!r}")
    p = min(b, 0.5 - theta / 3)
    return math.ceil(math.log(2 / gamma) / (theta**2 * massart_h(p, theta)))


def clopper_pearson_interval(k: np.ndarray | int, n: int, gamma: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact (Clopper–Pearson) two-sided interval at level 1 − γ, vectorised over counts ``k``.

    Each tail has probability ≤ γ/2 for every η, so P(η ∉ [low, high]) ≤ γ. Equal to
    ``scipy.stats.binomtest(k, n).proportion_ci(1 - γ, method='exact')``.
    """
    k = np.asarray(k)
    with np.errstate(all="ignore"):
        low = np.where(k > 0, special.betaincinv(k, n - k + 1, gamma / 2), 0.0)
        high = np.where(k < n, special.betaincinv(k + 1, n - k, 1 - gamma / 2), 1.0)
    return low, high


@lru_cache(maxsize=2048)
def fit_tails(n: int, theta: float) -> tuple[np.ndarray, np.ndarray]:
    """For each count k = 0..n: (P(Bin(n, k/n − θ) ≥ k), P(Bin(n, k/n + θ) ≤ k)), 0 where the rate leaves [0, 1].

    How likely a count this high (low) would be if η sat at the lower (upper) edge of k/n ± θ.
    Read-only (cached).
    """
    k = np.arange(n + 1)
    p = k / n
    upper = np.where(
        (k > 0) & (p - theta > 0), special.betainc(np.maximum(k, 1), n - k + 1, np.clip(p - theta, 0, 1)), 0.0
    )
    lower = np.where(
        (k < n) & (p + theta < 1), special.betainc(np.maximum(n - k, 1), k + 1, np.clip(1 - p - theta, 0, 1)), 0.0
    )
    upper.setflags(write=False)
    lower.setflags(write=False)
    return upper, lower


@lru_cache(maxsize=2048)
def fit_levels(n: int, theta: float) -> np.ndarray:
    """For each count k = 0..n: the smallest γ at which the exact interval lies inside [k/n ± θ].

    The interval at level 1 − γ has low ≥ k/n − θ iff P(Bin(n, k/n − θ) ≥ k) ≤ γ/2, and
    high ≤ k/n + θ iff P(Bin(n, k/n + θ) ≤ k) ≤ γ/2 (each tail is monotone in the rate), so
    the count fits at every γ ≥ twice the larger tail (:func:`fit_tails`). One table serves
    every γ, which is what lets a sequential scheme's level be calibrated quickly. Read-only (cached).
    """
    levels = 2 * np.maximum(*fit_tails(n, theta))
    levels.setflags(write=False)
    return levels


def clopper_pearson_fits(n: int, theta: float, gamma: float) -> np.ndarray:
    """For each count k = 0..n: does the exact interval at level 1 − γ lie inside [k/n − θ, k/n + θ]?

    Where it does, |k/n − η| > θ implies η outside the interval, an event of probability ≤ γ.
    """
    return fit_levels(int(n), float(theta)) <= gamma


def _middle_fits(n: np.ndarray, theta: float, gamma: float) -> np.ndarray:
    """The fit test for the two middle counts only (the widest intervals), vectorised over n."""
    ok = np.ones(n.shape, dtype=bool)
    for k in (n // 2, (n + 1) // 2):
        low, high = clopper_pearson_interval(k, n, gamma)
        ok &= (low >= k / n - theta) & (high <= k / n + theta)
    return ok


@lru_cache(maxsize=256)
def clopper_pearson_n(theta: float, gamma: float) -> int:
    """Smallest fixed n at which the exact interval at level 1 − γ fits in ±θ for *every* count.

    With that n fixed in advance, P(|k/n − η| > θ) ≤ P(η ∉ interval) ≤ γ: the same a-priori
    guarantee as Chernoff, with about half the samples at θ = γ = 0.05 (404 vs 738) because
    the exact binomial tails are used instead of an exponential bound. The scan starts at
    ln(2/γ)/(−ln(1 − θ)), below which even k = 0 cannot fit, screens blocks of n with the two
    middle counts (a necessary condition) and confirms each candidate on all counts.
    """
    theta, gamma = check_unit("theta", theta), check_unit("gamma", gamma)
    n = math.ceil(math.log(2 / gamma) / -math.log1p(-theta))
    while True:
        block = np.arange(n, n + 512)
        for cand in block[_middle_fits(block, theta, gamma)]:
            if clopper_pearson_fits(int(cand), theta, gamma).all():
                return int(cand)
        n += 512
