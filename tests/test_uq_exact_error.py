"""Exact error of every scheme that claims the (θ, γ) guarantee.

Computed here, independently of `uqdrive.uq`'s own computations: binomial tail sums for fixed-n
schemes, P(|k/n − η| > θ), over a regular η grid plus both one-sided limits (η0 ± 1e-10) at every
jump η0 = k/n ± θ. For the sequential scheme the rule is read off the scheme (stop or not, and the
interval it reports, at every look and count; the fit rule is checked against scipy's beta quantiles
and the ball rule against scipy's root finder and binomial tails) and its error P(η ∉ reported
interval) is computed from the number of paths (orderings of outcomes) that reach each stop, counted
in log space, over a regular grid, the exact one-sided limits at every end of a reported interval
and a dense neighbourhood of the largest values; the worst values are checked again by a second
method, a forward dynamic program over the count at each η.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import optimize, special, stats

from uqdrive.uq import chernoff, chernoff_n, clopper_pearson, clopper_pearson_n, massart, massart_n
from uqdrive.uq.sequential import CALIBRATED, SequentialScheme, calibrate, sequential_scheme

SETTINGS = [(0.05, 0.05), (0.1, 0.05), (0.25, 0.05), (0.05, 0.01)]
SIDE = 1e-10  # offset that puts η on one side of a fixed-n jump k/n ± θ; far from any other (gaps ≥ 1/n²)


def _with_limits(jumps: np.ndarray, points: int = 2001) -> np.ndarray:
    etas = np.concatenate([np.linspace(0, 1, points), jumps - SIDE, jumps + SIDE])
    return np.unique(etas[(etas >= 0) & (etas <= 1)])


def fixed_n_error(n: int, theta: float, etas: np.ndarray) -> np.ndarray:
    """P(|k/n − η| > θ) = P(k < n(η − θ)) + P(k > n(η + θ)) for k ~ Bin(n, η), for each η."""
    below = stats.binom.cdf(np.ceil(n * (etas - theta)) - 1, n, etas)
    above = stats.binom.sf(np.floor(n * (etas + theta)), n, etas)
    return below + above


def fixed_n_etas(n: int, theta: float) -> np.ndarray:
    p = np.arange(n + 1) / n
    return _with_limits(np.concatenate([p - theta, p + theta]))


Rule = dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]
"""look n → (stop, low, high) over the counts k = 0..n; every count stops at the last look."""


def rule_of(scheme: SequentialScheme) -> Rule:
    """The scheme's rule as `sequential` runs it: `scheme.look` at every look, everything stopping at max_n."""
    rule = {}
    for n in range(scheme.look_size, scheme.max_n + 1, scheme.look_size):
        look = scheme.look(n, np.arange(n + 1))
        rule[n] = (look.stop | (n == scheme.max_n), look.low, look.high)
    return rule


def stop_paths(rule: Rule) -> tuple[np.ndarray, ...]:
    """(n, k, log #paths, low, high) of every reachable stop: P(stop at (n, k) | η) = #paths · η^k (1 − η)^(n−k)."""
    log_paths = np.zeros(1)  # log of the number of running paths with k successes; -inf: none
    found = []
    for n in range(1, max(rule) + 1):
        log_paths = np.logaddexp(np.append(log_paths, -np.inf), np.insert(log_paths, 0, -np.inf))
        if n in rule:
            stop, low, high = rule[n]
            hit = stop & np.isfinite(log_paths)
            k = np.flatnonzero(hit)
            found.append((np.full(k.size, n), k, log_paths[hit], low[hit], high[hit]))
            log_paths = np.where(stop, -np.inf, log_paths)
    assert not np.isfinite(log_paths).any(), "the last look must stop every run"
    return tuple(np.concatenate(column) for column in zip(*found))


def error_by_paths(paths: tuple[np.ndarray, ...], etas: np.ndarray, side: int = 0) -> np.ndarray:
    """P(η ∉ [low, high]) at each η; ``side`` −1 / +1: the limit as η rises / falls to the given value."""
    n, k, log_paths, low, high = paths
    error = np.zeros(etas.size)
    for part in np.array_split(np.arange(etas.size), max(1, etas.size // 200)):
        eta = etas[part][None, :]
        with np.errstate(divide="ignore"):
            log_p = log_paths[:, None] + special.xlogy(k[:, None], eta) + special.xlog1py((n - k)[:, None], -eta)
        lo, hi = low[:, None], high[:, None]
        if side < 0:
            outside = (eta <= lo) | (eta > hi)
        elif side > 0:
            outside = (eta < lo) | (eta >= hi)
        else:
            outside = (eta < lo) | (eta > hi)
        error[part] = (np.exp(log_p) * outside).sum(0)
    return error


def worst_by_paths(paths: tuple[np.ndarray, ...]) -> tuple[float, np.ndarray]:
    """The largest error found (grid, both limits at every jump, dense around the 20 largest) and where."""
    _, _, _, low, high = paths
    jumps = np.unique(np.concatenate([low, high]))
    jumps = jumps[(jumps > 0) & (jumps < 1)]
    grid = np.linspace(0, 1, 2001)
    values = [error_by_paths(paths, jumps, -1), error_by_paths(paths, jumps, 1), error_by_paths(paths, grid)]
    etas = np.concatenate([jumps, jumps, grid])
    errors = np.concatenate(values)
    top = etas[np.argsort(errors)[-20:]]
    near = np.clip((top[:, None] + np.linspace(-5e-4, 5e-4, 101)[None, :]).ravel(), 0, 1)
    near_error = error_by_paths(paths, near)
    worst = max(float(errors.max()), float(near_error.max()))
    return worst, np.concatenate([top, near[np.argsort(near_error)[-5:]]])


def forward_dp(rule: Rule, etas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(error, expected n) at each η by a forward dynamic program over the count distribution."""
    dist = np.ones((1, etas.size))
    error, mean_n = np.zeros(etas.size), np.zeros(etas.size)
    for n in range(1, max(rule) + 1):
        nxt = np.zeros((dist.shape[0] + 1, etas.size))
        nxt[:-1] += dist * (1 - etas)
        nxt[1:] += dist * etas
        dist = nxt
        if n in rule:
            stop, low, high = rule[n]
            outside = (etas[None, :] < low[:, None]) | (etas[None, :] > high[:, None])
            error += (dist * (stop[:, None] & outside)).sum(0)
            mean_n += n * dist[stop].sum(0)
            dist = dist * ~stop[:, None]
    return error, mean_n


def fit_rule(n: int, level: float, theta: float) -> np.ndarray:
    """Clopper–Pearson interval at 1 − level (scipy beta quantiles) inside [k/n ± θ]?"""
    k = np.arange(n + 1)
    low = np.where(k > 0, stats.beta.ppf(level / 2, np.maximum(k, 1), n - k + 1), 0.0)
    high = np.where(k < n, stats.beta.ppf(1 - level / 2, k + 1, np.maximum(n - k, 1)), 1.0)
    return (low >= k / n - theta) & (high <= k / n + theta)


def ball_level(n: int, k: int, theta: float) -> tuple[float, float]:
    """(level √(2(U² + L²)), centre) of the documented ball rule at (n, k), by brentq and scipy's binomial."""

    def size(centre: float) -> float:
        upper = stats.binom.cdf(k, n, centre + theta) if centre + theta < 1 else 0.0
        lower = stats.binom.sf(k - 1, n, centre - theta) if centre - theta > 0 else 0.0
        return math.sqrt(2 * (upper**2 + lower**2))

    p = k / n
    a, b = max(theta, p - theta), min(1 - theta, p + theta)

    def gap(c: float) -> float:
        return special.xlogy(p, (c + theta) / (c - theta)) - special.xlogy(1 - p, (1 - c + theta) / (1 - c - theta))

    inner = [] if a >= b or gap(a + 1e-13) <= 0 or gap(b - 1e-13) >= 0 else [optimize.brentq(gap, a + 1e-13, b - 1e-13)]
    return min((size(c), c) for c in [*inner, theta, 1 - theta])


@pytest.mark.parametrize(("theta", "gamma"), SETTINGS)
def test_fixed_n_schemes_have_exact_error_at_most_gamma(theta: float, gamma: float) -> None:
    for n, est in ((chernoff_n(theta, gamma), chernoff), (clopper_pearson_n(theta, gamma), clopper_pearson)):
        assert est(n // 2, n, theta, gamma).guaranteed
        etas = fixed_n_etas(n, theta)
        error = fixed_n_error(n, theta, etas)
        near = (etas[np.argsort(error)[-20:], None] + np.linspace(-5e-4, 5e-4, 101)[None, :]).ravel()
        assert max(error.max(), fixed_n_error(n, theta, np.clip(near, 0, 1)).max()) <= gamma
    for bound in (0.5, 0.1, 0.01):
        n = massart_n(theta, gamma, bound)
        etas = fixed_n_etas(n, theta)
        inside = np.minimum(etas, 1 - etas) <= bound
        assert fixed_n_error(n, theta, etas[inside]).max() <= gamma, bound
        assert massart(0, n, theta, gamma, rate_bound=bound).guaranteed


def test_the_fixed_n_check_sees_a_too_small_n() -> None:
    """At n = 380 (< 404) the binomial sums find η with error just above γ = 0.05, near the jumps."""
    error = fixed_n_error(380, 0.05, fixed_n_etas(380, 0.05))
    assert 0.05 < error.max() < 0.06
    assert not clopper_pearson(0, 380, 0.05, 0.05).guaranteed


@pytest.mark.parametrize(("theta", "gamma", "look_size"), sorted(CALIBRATED))
def test_sequential_has_exact_error_at_most_gamma(theta: float, gamma: float, look_size: int) -> None:
    scheme = sequential_scheme(theta, gamma, look_size)
    rule = rule_of(scheme)
    worst, where = worst_by_paths(stop_paths(rule))
    assert worst <= gamma
    if look_size == 1 and theta <= 0.1:  # fine looks: calibration spends almost all of the budget
        assert worst >= 0.95 * gamma
    assert scheme.worst_error() >= worst * (1 - 1e-9)  # the scheme's own search finds the worst case
    np.testing.assert_allclose(forward_dp(rule, where)[0], error_by_paths(stop_paths(rule), where), rtol=1e-8)
    rates = np.array([0.0, 0.01, 0.3, 0.5, 0.99, 1.0])
    error, mean_n = forward_dp(rule, rates)
    own_n, own_error = scheme.operating_characteristics(rates)
    np.testing.assert_allclose(own_n, mean_n, rtol=1e-9)
    np.testing.assert_allclose(own_error, error, rtol=1e-7, atol=1e-12)


def test_sequential_meets_its_targets_at_the_default_look() -> None:
    """θ = γ = 0.05, a look every 4: E[n] ≤ 42 at η ∈ {0, 1}, ≤ 50 at 0.99, ≤ 1.12 × 404 everywhere (exact)."""
    scheme = sequential_scheme(0.05, 0.05, 4)
    grid = np.linspace(0, 1, 401)
    _, mean_n = forward_dp(rule_of(scheme), np.concatenate([[0.0, 0.99, 1.0], grid]))
    assert mean_n[0] <= 42 and mean_n[2] <= 42 and mean_n[1] <= 50
    assert mean_n.max() <= 1.12 * clopper_pearson_n(0.05, 0.05)
    assert (mean_n[0], mean_n[1]) == pytest.approx((36.0, 44.1), abs=0.05)


def test_the_rule_is_the_documented_one() -> None:
    """Fit stops where the Clopper–Pearson interval at 1 − level fits in k/n ± θ; elsewhere, ball stops where
    the best ball's level is ≤ ball_level, reporting its centre ± θ."""
    theta = 0.05
    scheme = sequential_scheme(theta, 0.05, 4)
    balls = 0
    for n in (12, 36, 40, 44, 60, 120, 200, 300, 396):
        k = np.arange(n + 1)
        look = scheme.look(n, k)
        fit = fit_rule(n, scheme.level, theta)
        np.testing.assert_array_equal(look.stop[fit], True)
        np.testing.assert_allclose(look.low[fit], np.maximum(0, k[fit] / n - theta), atol=1e-12)
        for count in k[~fit]:
            level, centre = ball_level(n, int(count), theta)
            if abs(level - scheme.ball_level) > 1e-6 * scheme.ball_level:
                assert look.stop[count] == (level <= scheme.ball_level), (n, count)
            if look.stop[count]:
                balls += 1
                assert look.value[count] == pytest.approx(centre, abs=1e-6)
                assert (look.low[count], look.high[count]) == pytest.approx(
                    (max(0, centre - theta), min(1, centre + theta)), abs=1e-6
                )
    assert balls >= 20


@pytest.mark.parametrize(("factor_level", "factor_ball"), [(1.01, 1.0), (1.0, 1.01)])
def test_a_level_just_above_the_calibrated_one_is_seen_to_overshoot(factor_level: float, factor_ball: float) -> None:
    """Calibration keeps the largest valid level on a 1 % grid: the next one up fails, and the check sees it."""
    scheme = sequential_scheme(0.05, 0.05, 4)
    bigger = SequentialScheme(0.05, 0.05, 4, scheme.level * factor_level, scheme.ball_level * factor_ball)
    worst, _ = worst_by_paths(stop_paths(rule_of(bigger)))
    assert 0.05 < worst < 0.06


def test_an_untabulated_gamma_is_calibrated_with_its_guarantee() -> None:
    """γ split over 36 cells: calibrated on the spot (once per process), exact error still ≤ γ."""
    gamma = 0.05 / 36
    assert (0.1, gamma, 4) not in CALIBRATED
    scheme = sequential_scheme(0.1, gamma, 4)
    worst, _ = worst_by_paths(stop_paths(rule_of(scheme)))
    assert 0.9 * gamma <= worst <= gamma
    assert scheme.ball_level > 0 and sequential_scheme(0.1, gamma, 4) is scheme


@pytest.mark.slow
def test_calibrated_table_is_what_calibration_gives() -> None:
    for key, levels in CALIBRATED.items():
        assert calibrate(*key) == pytest.approx(levels, rel=1e-12), key


def test_calibrated_table_entry_is_reproduced() -> None:
    assert calibrate(0.25, 0.05, 4) == pytest.approx(CALIBRATED[(0.25, 0.05, 4)], rel=1e-12)
