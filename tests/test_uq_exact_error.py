"""Exact error P(|η̂ − η| > θ) of every scheme that claims the (θ, γ) guarantee.

Computed here, independently of `uqdrive.uq`: binomial sums for fixed-n schemes and, for the
sequential scheme, a dynamic program over the count run for every η at once, with the
stopping rule rebuilt from scipy's beta quantiles. η runs over a regular grid plus both
one-sided limits (η0 ± 1e-10) at every jump η0 = k/n ± θ, where the worst case sits.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq import chernoff, chernoff_n, clopper_pearson, clopper_pearson_n, massart, massart_n
from uqdrive.uq.sequential import CALIBRATED, calibrate_level, sequential_scheme

SETTINGS = [(0.05, 0.05), (0.1, 0.05), (0.25, 0.05), (0.05, 0.01)]
SIDE = 1e-10  # offset that puts η on one side of a jump; far from any other jump (gaps ≥ 1/n²)


def _with_limits(jumps: np.ndarray, points: int = 2001) -> np.ndarray:
    etas = np.concatenate([np.linspace(0, 1, points), jumps - SIDE, jumps + SIDE])
    return np.unique(etas[(etas >= 0) & (etas <= 1)])


def fixed_n_error(n: int, theta: float, etas: np.ndarray) -> np.ndarray:
    """P(|k/n − η| > θ) for k ~ Bin(n, η), for each η."""
    k = np.arange(n + 1)[:, None]
    far = np.abs(k / n - etas[None, :]) > theta
    return (stats.binom.pmf(k, n, etas[None, :]) * far).sum(0)


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
            dist, lo = dist[alive[0]:alive[-1] + 1] * ~stop[alive[0]:alive[-1] + 1, None], lo + alive[0]
    raise AssertionError("the last look must stop every run")


def _reachable_stops(tables: dict[int, np.ndarray]) -> np.ndarray:
    """k/n of every stop reached with positive probability (the same set for every η in (0, 1))."""
    alive = np.ones(1, dtype=bool)
    points = []
    for n in range(1, max(tables) + 1):
        alive = np.concatenate([alive, [False]]) | np.concatenate([[False], alive])
        if n in tables:
            hit = alive & tables[n]
            points.append(np.flatnonzero(hit) / n)
            alive &= ~tables[n]
    return np.concatenate(points)


def _tables_of(scheme) -> dict[int, np.ndarray]:
    looks = range(scheme.look_size, scheme.max_n + 1, scheme.look_size)
    tables = {n: stop_table(n, np.arange(n + 1), scheme.level, scheme.theta) for n in looks}
    assert tables[scheme.max_n].all()
    return tables


@pytest.mark.parametrize(("theta", "gamma"), SETTINGS)
def test_fixed_n_schemes_have_exact_error_at_most_gamma(theta: float, gamma: float) -> None:
    for n, est in ((chernoff_n(theta, gamma), chernoff), (clopper_pearson_n(theta, gamma), clopper_pearson)):
        assert est(n // 2, n, theta, gamma).guaranteed
        assert fixed_n_error(n, theta, fixed_n_etas(n, theta)).max() <= gamma
    for bound in (0.5, 0.1, 0.01):
        n = massart_n(theta, gamma, bound)
        etas = fixed_n_etas(n, theta)
        inside = np.minimum(etas, 1 - etas) <= bound
        assert fixed_n_error(n, theta, etas[inside]).max() <= gamma, bound
        assert massart(0, n, theta, gamma, rate_bound=bound).guaranteed


def test_clopper_pearson_one_below_its_n_really_fails() -> None:
    """The label is tight: at n − 1 some η has error above γ (so the check above can fail)."""
    n = clopper_pearson_n(0.05, 0.05)
    assert not clopper_pearson(0, n - 1, 0.05, 0.05).guaranteed


@pytest.mark.parametrize(("theta", "gamma", "look_size"), [
    *[(theta, gamma, size) for theta, gamma in SETTINGS[:3] for size in (1, 10)],
    (0.05, 0.01, 10), pytest.param(0.05, 0.01, 1, marks=pytest.mark.slow),  # ~10 s on a busy machine
])
def test_sequential_has_exact_error_at_most_gamma(theta: float, gamma: float, look_size: int) -> None:
    scheme = sequential_scheme(theta, gamma, look_size)
    tables = _tables_of(scheme)
    for n, stop in tables.items():  # the runtime rule is the rule checked here
        assert np.array_equal(stop, scheme.stop_tables[n // look_size - 1]), n
    p = _reachable_stops(tables)
    etas = _with_limits(np.concatenate([p - theta, p + theta]), points=401)
    error, mean_n = sequential_error(tables, theta, etas)
    assert error.max() <= gamma
    if look_size == 1 and theta <= 0.1:  # fine looks: calibration spends almost all of the budget
        assert error.max() >= 0.9 * gamma
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
    p = _reachable_stops(tables)
    error, _ = sequential_error(tables, 0.05, _with_limits(np.concatenate([p - 0.05, p + 0.05]), points=401))
    assert 0.05 < error.max() < 0.052


@pytest.mark.slow
def test_calibrated_table_is_what_calibration_gives() -> None:
    for (theta, gamma, look_size), level in CALIBRATED.items():
        assert calibrate_level(theta, gamma, look_size) == pytest.approx(level, rel=1e-12)


def test_calibrated_table_entry_is_reproduced() -> None:
    assert calibrate_level(0.25, 0.05, 1) == pytest.approx(CALIBRATED[(0.25, 0.05, 1)], rel=1e-12)
