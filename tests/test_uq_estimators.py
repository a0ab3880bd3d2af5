"""Sample sizes, exact intervals, labels and bad input of the Bernoulli-rate estimators.

The exact error of every guaranteed scheme is checked in test_uq_exact_error.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq import (
    chernoff,
    chernoff_n,
    clopper_pearson,
    clopper_pearson_interval,
    clopper_pearson_n,
    massart,
    massart_n,
    sequential_scheme,
    simulate_sprt,
    sprt,
    wilson,
)
from uqdrive.uq.bounds import massart_h
from uqdrive.uq.estimators import sequential

THETA = GAMMA = 0.05
REPS = 2000
# Monte-Carlo slack of the (approximate, decision-only) SPRT check: 3 binomial standard errors.
SLACK = 3 * math.sqrt(GAMMA * (1 - GAMMA) / REPS)


def test_chernoff_n_is_the_smallest_integer_above_the_bound() -> None:
    assert chernoff_n(0.05, 0.05) == 738
    for theta, gamma in [(0.1, 0.01), (0.02, 0.1), (0.3, 0.5)]:
        bound = math.log(2 / gamma) / (2 * theta**2)
        n = chernoff_n(theta, gamma)
        assert n > bound >= n - 1


@pytest.mark.parametrize("n", [1, 7, 50, 738])
@pytest.mark.parametrize("gamma", [0.05, 0.01, 0.2])
def test_clopper_pearson_equals_scipy_exact_interval(n: int, gamma: float) -> None:
    ks = sorted({0, 1, n // 3, n // 2, n - 1, n})
    low, high = clopper_pearson_interval(np.array(ks), n, gamma)
    for k, lo, hi in zip(ks, low, high):
        ci = stats.binomtest(k, n).proportion_ci(confidence_level=1 - gamma, method="exact")
        assert (lo, hi) == pytest.approx((ci.low, ci.high), abs=1e-12)
        est = clopper_pearson(k, n, 0.05, gamma)
        assert (est.low, est.high, est.value) == pytest.approx((ci.low, ci.high, k / n), abs=1e-12)


def test_clopper_pearson_fixed_n_and_its_label() -> None:
    n = clopper_pearson_n(THETA, GAMMA)
    assert n == 404
    assert clopper_pearson(200, n, THETA, GAMMA).guaranteed
    assert not clopper_pearson(200, n - 1, THETA, GAMMA).guaranteed


def test_massart_inequality_against_exact_binomial_tails() -> None:
    """P(p̂ − p ≥ θ) ≤ exp(−nθ² h_a(p, θ)) on a grid: checks the cited form of the bound."""
    for n in (10, 100, 500):
        for theta in (0.02, 0.05, 0.2):
            p = np.linspace(0, 1 - theta - 1e-9, 200)
            tail = stats.binom.sf(np.ceil(n * (p + theta) - 1e-9) - 1, n, p)
            assert np.all(tail <= np.exp(-n * theta**2 * massart_h(p, theta)))


@pytest.mark.parametrize(("rate_bound", "n"), [(0.5, 738), (0.2, 501), (0.1, 305), (0.05, 184), (0.01, 77)])
def test_massart_n_holds_exactly_under_its_assumption(rate_bound: float, n: int) -> None:
    assert massart_n(THETA, GAMMA, rate_bound) == n
    k = np.arange(n + 1)
    for eta in np.concatenate([np.linspace(0, rate_bound, 101), 1 - np.linspace(0, rate_bound, 101)]):
        far = np.abs(k / n - eta) > THETA
        assert stats.binom.pmf(k[far], n, eta).sum() <= GAMMA


def _sequence(rng: np.random.Generator, rate: float, sizes: list[int]):
    def draw(k: int) -> np.ndarray:
        sizes.append(k)
        return (rng.random(k) < rate).astype(int)

    return draw


@pytest.mark.parametrize("look_size", [1, 4, 10])
def test_sequential_follows_its_stopping_rule(look_size: int) -> None:
    """It draws look-sized batches and stops at the first look the rule (the one whose error is
    computed exactly) allows: checked against the running count of the very same outcomes."""
    scheme = sequential_scheme(THETA, GAMMA, look_size)
    rng = np.random.default_rng(look_size)
    for rate in (0.0, 0.02, 0.3, 0.5, 0.97, 1.0):
        sizes: list[int] = []
        outcomes: list[np.ndarray] = []
        draw = _sequence(rng, rate, sizes)
        est = sequential(lambda k: outcomes.append(draw(k)) or outcomes[-1], THETA, GAMMA, look_size)  # noqa: B023
        x = np.concatenate(outcomes)
        assert set(sizes) == {look_size} and est.n == x.size <= scheme.max_n
        counts = np.cumsum(x)
        looks = np.arange(look_size, x.size + 1, look_size)
        stops = [bool(scheme.look(n, counts[n - 1 : n]).stop[0]) or n == scheme.max_n for n in looks]
        assert stops[-1] and not any(stops[:-1])
        look = scheme.look(x.size, counts[-1:])
        assert (est.value, est.low, est.high) == (look.value[0], look.low[0], look.high[0])
        assert est.guaranteed and est.scheme == "sequential" and est.high - est.low <= 2 * THETA + 1e-12
        assert est.low == pytest.approx(max(0.0, est.value - THETA), abs=1e-12)
        assert est.high == pytest.approx(min(1.0, est.value + THETA), abs=1e-12)


def test_sequential_at_the_extremes_and_its_savings() -> None:
    """All successes: the ball [1 − 2θ, 1] is settled once √2 · 0.9^n ≤ ball_level (n = 37 at look 1),
    long before k/n ± θ is (72); the value is its centre, 1 − θ."""
    scheme = sequential_scheme(THETA, GAMMA, 1)
    first = math.ceil(math.log(scheme.ball_level / math.sqrt(2)) / math.log(1 - 2 * THETA))
    est = sequential(lambda k: np.ones(k, dtype=np.int8), THETA, GAMMA, 1)
    assert est.n == first == 37 and (est.value, est.low, est.high) == pytest.approx((0.95, 0.9, 1.0), abs=1e-12)
    est = sequential(lambda k: np.zeros(k, dtype=np.int8), THETA, GAMMA, 1)
    assert est.n == 37 and (est.value, est.low, est.high) == pytest.approx((0.05, 0.0, 0.1), abs=1e-12)
    mean_n, _ = scheme.operating_characteristics(np.linspace(0, 1, 201))
    assert scheme.operating_characteristics(0.99)[0][0] <= 50 and scheme.operating_characteristics(0.9)[0][0] <= 180
    assert mean_n.max() <= 1.12 * clopper_pearson_n(THETA, GAMMA)


def test_schemes_without_the_guarantee_say_so() -> None:
    assert not wilson(380, 400, THETA, GAMMA).guaranteed
    assert not chernoff(90, 100, THETA, GAMMA).guaranteed
    assert not massart(90, 100, THETA, GAMMA, rate_bound=0.5).guaranteed
    assert massart(90, 100, THETA, GAMMA, rate_bound=0.01).scheme == "massart(rate_bound=0.01)"
    assert massart(0, 738, THETA, GAMMA).guaranteed and massart(0, 738, THETA, GAMMA).condition == ""
    res = sprt(lambda k: np.ones(k, dtype=int), delta=0.7, half_width=THETA)
    assert res.accept and not res.truncated and not res.estimate.guaranteed and res.estimate.scheme == "sprt"


def test_massart_states_its_condition_and_checks_it_against_the_data() -> None:
    agrees = massart(1, 77, THETA, GAMMA, rate_bound=0.01)
    assert agrees.guaranteed and agrees.condition == "min(eta, 1 - eta) <= 0.01"
    contradicted = massart(40, 77, THETA, GAMMA, rate_bound=0.01)  # exact error 0.43 if η ≈ 0.5
    assert not contradicted.guaranteed and "contradicted by the data" in contradicted.condition


def test_wilson_ends_exactly_at_zero_and_one() -> None:
    assert wilson(404, 404, THETA, GAMMA).high == 1.0 and wilson(0, 404, THETA, GAMMA).low == 0.0
    for k in (0, 1, 200, 403, 404):
        est = wilson(k, 404, THETA, GAMMA)
        assert 0.0 <= est.low <= est.value <= est.high <= 1.0


def test_sprt_decisions_and_cap() -> None:
    rng = np.random.default_rng(3)
    for rate, want in [(0.9, True), (0.99, True), (0.5, False), (0.6, False)]:
        accept, used = simulate_sprt(rate, REPS, rng, delta=0.7, half_width=THETA, alpha=GAMMA, beta=GAMMA)
        assert np.mean(accept == want) >= 1 - GAMMA - SLACK
        assert used.max() <= chernoff_n(THETA, GAMMA)
    res = sprt(lambda k: (np.arange(k) % 10 < 7).astype(int), delta=0.7, half_width=THETA, max_n=40)
    assert res.truncated and res.estimate.n == 40


@pytest.mark.parametrize("name", ["theta", "gamma"])
@pytest.mark.parametrize("bad", [0.0, 1.0, 1.5, -0.1, float("nan")])
def test_theta_gamma_outside_unit_interval_are_rejected(name: str, bad: float) -> None:
    args = {"theta": THETA, "gamma": GAMMA, name: bad}
    match = rf"{name} must be in \(0, 1\), got {bad!r}"
    for fn in (chernoff_n, massart_n, clopper_pearson_n, sequential_scheme):
        with pytest.raises(ValueError, match=match):
            fn(**args)
    with pytest.raises(ValueError, match=match):
        chernoff(1, 10, **args)


def test_other_bad_arguments_are_rejected() -> None:
    with pytest.raises(ValueError, match=r"k must be an integer in \[0, n=10\], got 11"):
        clopper_pearson(11, 10, THETA, GAMMA)
    with pytest.raises(ValueError, match=r"rate_bound must be in \[0, 0.5\].*got 0.7"):
        massart_n(THETA, GAMMA, 0.7)
    with pytest.raises(ValueError, match=r"rate_bound must be in \[0, 0.5\].*got -0.1"):
        massart(1, 10, THETA, GAMMA, rate_bound=-0.1)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ValueError, match=rf"look_size must be an integer >= 1 .*got {bad!r}"):
            sequential(lambda k: np.ones(k), THETA, GAMMA, bad)
    with pytest.raises(ValueError, match=r"draw\(1\) must return 1 outcomes in \{0, 1\}"):
        sequential(lambda k: np.full(k, 2), THETA, GAMMA, 1)
    with pytest.raises(ValueError, match=r"half_width must be > 0 with 0 < delta ± half_width < 1, got 0.1"):
        sprt(lambda k: np.ones(k), delta=0.95, half_width=0.1)


def test_each_cell_estimator_is_chosen_by_its_name_and_records_it():
    from uqdrive.uq.schemes import CELL_ESTIMATORS, cell_estimator

    rng = np.random.default_rng(3)
    outcomes = (rng.random(5000) < 0.8).astype(np.int64)
    for name in ("chernoff", "clopper_pearson", "sequential"):
        method, taken = cell_estimator(name), []

        def draw(m, taken=taken):
            start = sum(taken)
            taken.append(m)
            return outcomes[start : start + m]

        est = method.estimate(draw, 0.1, 0.05, 4)
        assert est.scheme == name and est.n == sum(taken)
        assert method.least(0.1, 0.05, 4) <= est.n <= method.most(0.1, 0.05, 4)
        assert abs(est.value - 0.8) <= 0.1 and est.guaranteed
    assert cell_estimator("chernoff").most(0.1, 0.05, 4) == chernoff_n(0.1, 0.05)
    assert set(CELL_ESTIMATORS) == {"chernoff", "clopper_pearson", "sequential"}
    with pytest.raises(ValueError, match="scheme='wald'"):
        cell_estimator("wald")
