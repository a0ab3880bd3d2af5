"""Exact error P(|η̂ − η| > θ) of every scheme that claims the (θ, γ) guarantee.

Computed here, independently of `uqdrive.uq`: binomial tail sums for fixed-n schemes and, for
the sequential scheme, the number of paths (orderings of outcomes) that reach each stop, counted
in log space, with the stopping rule rebuilt from scipy's beta quantiles; the worst values are
checked again by a second method, a forward dynamic program over the count at each η. η runs
over a regular grid plus both one-sided limits (η0 ± 1e-10) at every jump η0 = k/n ± θ, where
the worst case sits.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import special, stats

from uqdrive.uq import chernoff, chernoff_n, clopper_pearson, clopper_pearson_n, massart, massart_n
from uqdrive.uq.sequential import CALIBRATED, calibrate_level, sequential_scheme

SETTINGS = [(0.05, 0.05), (0.1, 0.05), (0.25, 0.05), (0.05, 0.01)]
SIDE = 1e-10  # offset that puts η on one side of a jump; far from any other jump (gaps ≥ 1/n²)


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


def stop_table(n: int, k_all: np.ndarray, level: float, theta: float) -> np.ndarray:
    """Clopper–Pearson interval at 1 − level (scipy beta quantiles) inside [k/n ± θ]?"""
    k = k_all
    low = np.where(k > 0, stats.beta.ppf(level / 2, np.maximum(k, 1), n - k + 1), 0.0)
    high = np.where(k < n, stats.beta.ppf(1 - level / 2, k + 1, np.maximum(n - k, 1)), 1.0)
    p = k / n
    return (low >= p - theta) & (high <= p + theta)


def sequential_error(tables: dict[int, np.ndarray], theta: float, etas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(error, expected n) of the rule 'at look n stop where tables[n][k]' for each η (DP over the count).

    ``dist[j]`` is P(still running with k = lo + j successes); only the band of counts still
    running is kept, so late looks (where most counts have stopped) cost little.
    """
    dist, lo = np.ones((1, etas.size)), 0
    error, mean_n = np.zeros(etas.size), np.zeros(etas.size)
    for n in range(1, max(tables) + 1):
        nxt = np.zeros((dist.shape[0] + 1, etas.size))
        nxt[:-1] += dist * (1 - etas)
        nxt[1:] += dist * etas
        dist = nxt
        if n in tables:
            k = lo + np.arange(dist.shape[0])
            stop = tables[n][k]
            far = np.abs(k[:, None] / n - etas[None, :]) > theta
            error += (dist * (stop[:, None] & far)).sum(0)
            mean_n += n * dist[stop].sum(0)
            alive = np.flatnonzero(~stop)
            if alive.size == 0:
                return error, mean_n
            dist, lo = dist[alive[0] : alive[-1] + 1] * ~stop[alive[0] : alive[-1] + 1, None], lo + alive[0]
    raise AssertionError("the last look must stop every run")


def stop_paths(tables: dict[int, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n, k, log #paths) of every reachable stop: P(stop at (n, k) | η) = #paths · η^k (1 − η)^(n−k)."""
    log_paths = np.zeros(1)  # log of the number of running paths with k successes; -inf: none
    ns, ks, logs = [], [], []
    for n in range(1, max(tables) + 1):
        log_paths = np.logaddexp(np.append(log_paths, -np.inf), np.insert(log_paths, 0, -np.inf))
        if n in tables:
            hit = tables[n] & np.isfinite(log_paths)
            ns.append(np.full(hit.sum(), n))
            ks.append(np.flatnonzero(hit))
            logs.append(log_paths[hit])
            log_paths = np.where(tables[n], -np.inf, log_paths)
    assert not np.isfinite(log_paths).any(), "the last look must stop every run"
    return np.concatenate(ns), np.concatenate(ks), np.concatenate(logs)


def sequential_error_by_paths(tables: dict[int, np.ndarray], theta: float, etas: np.ndarray) -> np.ndarray:
    n, k, log_paths = stop_paths(tables)
    error = np.zeros(etas.size)
    for part in np.array_split(np.arange(etas.size), max(1, etas.size // 500)):
        eta = etas[part][None, :]
        log_p = log_paths[:, None] + special.xlogy(k[:, None], eta) + special.xlog1py((n - k)[:, None], -eta)
        far = np.abs(k[:, None] / n[:, None] - eta) > theta
        error[part] = (np.exp(log_p) * far).sum(0)
    return error


def jump_etas(tables: dict[int, np.ndarray], theta: float, points: int) -> np.ndarray:
    n, k, _ = stop_paths(tables)
    return _with_limits(np.concatenate([k / n - theta, k / n + theta]), points=points)


def _tables_of(scheme) -> dict[int, np.ndarray]:
    """The stopping rule at each look, evaluated on the counts a running path can have there
    (the others are marked False: no path reaches them, so they do not matter); checks that
    it is the rule the scheme runs with, on every one of those counts."""
    tables, low, high = {}, 0, 0  # running paths have low ≤ k ≤ high
    for n in range(1, scheme.max_n + 1):
        high += 1
        if n % scheme.look_size == 0:
            k = np.arange(low, high + 1)
            table = np.zeros(n + 1, dtype=bool)
            table[k] = stop_table(n, k, scheme.level, scheme.theta)
            assert np.array_equal(table[k], scheme.stop_tables[n // scheme.look_size - 1][k]), n
            tables[n] = table
            running = k[~table[k]]
            if running.size == 0:
                break
            low, high = int(running[0]), int(running[-1])
    assert max(tables) <= scheme.max_n
    return tables


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


@pytest.mark.parametrize(
    ("theta", "gamma", "look_size"),
    [
        *[(theta, gamma, size) for theta, gamma in SETTINGS for size in (1, 4, 10)],
    ],
)
def test_sequential_has_exact_error_at_most_gamma(theta: float, gamma: float, look_size: int) -> None:
    scheme = sequential_scheme(theta, gamma, look_size)
    tables = _tables_of(scheme)
    etas = jump_etas(tables, theta, points=2001)
    error = sequential_error_by_paths(tables, theta, etas)
    assert error.max() <= gamma
    # between jumps the error is smooth: look densely around the 20 largest values as well
    near = (etas[np.argsort(error)[-20:], None] + np.linspace(-5e-4, 5e-4, 101)[None, :]).ravel()
    assert sequential_error_by_paths(tables, theta, np.clip(near, 0, 1)).max() <= gamma
    if look_size == 1 and theta <= 0.1:  # fine looks: calibration spends almost all of the budget
        assert error.max() >= 0.9 * gamma
    assert scheme.worst_error() >= error.max() * (1 - 1e-9)  # the scheme's own search finds the worst case
    worst = etas[np.argsort(error)[-10:]]  # the worst cases again, by the forward DP
    np.testing.assert_allclose(sequential_error(tables, theta, worst)[0], np.sort(error)[-10:], rtol=1e-8)
    mid = np.array([0.3, 0.5, 0.99])
    n_mod, err_mod = scheme.operating_characteristics(mid)
    err_here, n_here = sequential_error(tables, theta, mid)
    np.testing.assert_allclose(n_mod, n_here, rtol=1e-9)
    np.testing.assert_allclose(err_mod, err_here, rtol=1e-7, atol=1e-12)


def test_an_overclaiming_level_is_seen() -> None:
    """The same computation rejects a level just above the calibrated one: it can see a small violation."""
    scheme = sequential_scheme(0.05, 0.05, 1)
    bigger = type(scheme)(0.05, 0.05, 1, scheme.level * 1.02)
    tables = _tables_of(bigger)
    error = sequential_error_by_paths(tables, 0.05, jump_etas(tables, 0.05, points=2001))
    assert 0.05 < error.max() < 0.052


@pytest.mark.slow
def test_calibrated_table_is_what_calibration_gives() -> None:
    for (theta, gamma, look_size), level in CALIBRATED.items():
        assert calibrate_level(theta, gamma, look_size) == pytest.approx(level, rel=1e-12)


def test_calibrated_table_entry_is_reproduced() -> None:
    assert calibrate_level(0.25, 0.05, 1) == pytest.approx(CALIBRATED[(0.25, 0.05, 1)], rel=1e-12)
