"""Sample sizes, exact intervals and empirical coverage of the Bernoulli-rate estimators."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq import (
    SequentialPlan,
    chernoff,
    chernoff_n,
    clopper_pearson,
    clopper_pearson_interval,
    clopper_pearson_n,
    massart,
    massart_n,
    sequential,
    sequential_operating_characteristics,
    sequential_plan,
    simulate_sequential,
    simulate_sprt,
    sprt,
    wilson,
)
from uqdrive.uq.bounds import massart_h

THETA = GAMMA = 0.05
RATES = (0.0, 0.01, 0.1, 0.5, 0.9, 0.99, 1.0)
REPS = 2000
# Monte-Carlo slack on a coverage estimate from REPS runs: 3 binomial standard errors at 1 - gamma.
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


def test_default_sequential_plan() -> None:
    plan = sequential_plan(THETA, GAMMA)
    assert plan.looks == (119, 206, 561)
    assert plan.gammas == pytest.approx((0.025, 0.005, 0.02))
    assert sum(plan.gammas) <= GAMMA + 1e-15
    assert plan.looks[-1] <= 1.05 * chernoff_n(THETA, GAMMA)


def test_sequential_error_is_below_gamma_exactly() -> None:
    """Exact DP over counts (no Monte-Carlo slack) on a fine grid of rates plus the jump points."""
    plan = sequential_plan(THETA, GAMMA)
    jumps = np.array([k / n + s * THETA for n in plan.looks for k in range(n + 1) for s in (-1, 1)])
    grid = np.concatenate([np.linspace(0, 1, 101), jumps - 1e-9, jumps + 1e-9])
    grid = np.unique(grid[(grid >= 0) & (grid <= 1)])
    worst = max(sequential_operating_characteristics(plan, eta)[1] for eta in grid)
    assert worst <= GAMMA


def _fixed_n_values(rng: np.random.Generator, rate: float, n: int, estimator, **kw) -> tuple[np.ndarray, bool]:
    ests = [estimator(int(k), n, THETA, GAMMA, **kw) for k in rng.binomial(n, rate, size=REPS)]
    return np.array([e.value for e in ests]), all(e.guaranteed for e in ests)


@pytest.mark.parametrize("rate", RATES)
def test_coverage_of_every_guaranteed_scheme(rate: float) -> None:
    rng = np.random.default_rng(12345 + int(rate * 1000))
    plan = sequential_plan(THETA, GAMMA)
    runs = {
        "chernoff": _fixed_n_values(rng, rate, chernoff_n(THETA, GAMMA), chernoff),
        "clopper_pearson": _fixed_n_values(rng, rate, clopper_pearson_n(THETA, GAMMA), clopper_pearson),
        "massart": _fixed_n_values(
            rng, rate, massart_n(THETA, GAMMA, min(rate, 1 - rate)), massart, rate_bound=min(rate, 1 - rate)
        ),
        "sequential": (simulate_sequential(rate, REPS, rng, plan)[0], True),
    }
    for name, (values, guaranteed) in runs.items():
        assert guaranteed, name
        coverage = np.mean(np.abs(values - rate) <= THETA)
        assert coverage >= 1 - GAMMA - SLACK, (name, rate, coverage)


def test_sequential_draws_in_look_sized_batches_and_stops_early() -> None:
    plan = sequential_plan(THETA, GAMMA)
    sizes: list[int] = []

    def all_ones(k: int) -> np.ndarray:
        sizes.append(k)
        return np.ones(k, dtype=np.int8)

    est = sequential(all_ones, THETA, GAMMA)
    assert sizes == [119] and est.n == 119 and est.value == 1.0 and est.guaranteed
    assert est.value - THETA <= est.low <= est.high <= 1.0

    rng = np.random.default_rng(7)
    sizes.clear()

    def coin(k: int) -> np.ndarray:
        sizes.append(k)
        return (rng.random(k) < 0.5).astype(int)

    est = sequential(coin, THETA, GAMMA, plan)
    assert sizes == [119, 206 - 119, 561 - 206] and est.n == 561
    assert est.value - THETA <= est.low <= est.high <= est.value + THETA


def test_sequential_saves_samples_near_one() -> None:
    plan = sequential_plan(THETA, GAMMA)
    n = chernoff_n(THETA, GAMMA)
    assert sequential_operating_characteristics(plan, 0.99)[0] <= n / 5
    assert max(sequential_operating_characteristics(plan, r)[0] for r in RATES) <= 1.05 * n


def test_schemes_without_the_guarantee_say_so() -> None:
    assert not wilson(380, 400, THETA, GAMMA).guaranteed
    assert not chernoff(90, 100, THETA, GAMMA).guaranteed
    assert not massart(90, 100, THETA, GAMMA, rate_bound=0.5).guaranteed
    assert massart(90, 100, THETA, GAMMA, rate_bound=0.01).method == "massart(rate_bound=0.01)"
    res = sprt(lambda k: np.ones(k, dtype=int), delta=0.7, half_width=THETA)
    assert res.accept and not res.truncated and not res.estimate.guaranteed and res.estimate.method == "sprt"


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
    for fn in (chernoff_n, massart_n, clopper_pearson_n, sequential_plan):
        with pytest.raises(ValueError, match=match):
            fn(**args)
    with pytest.raises(ValueError, match=match):
        chernoff(1, 10, **args)


def test_other_bad_arguments_are_rejected() -> None:
    with pytest.raises(ValueError, match=r"k must be an integer in \[0, n=10\], got 11"):
        clopper_pearson(11, 10, THETA, GAMMA)
    with pytest.raises(ValueError, match=r"rate_bound must be in \[0, 0.5\].*got 0.7"):
        massart_n(THETA, GAMMA, 0.7)
    with pytest.raises(ValueError, match=r"final look n=300 .* not complete"):
        SequentialPlan(THETA, GAMMA, (100, 300), (0.025, 0.025))
    with pytest.raises(ValueError, match=r"gammas must .* sum to at most gamma=0.05"):
        SequentialPlan(THETA, GAMMA, (100, 700), (0.03, 0.03))
    with pytest.raises(ValueError, match=r"looks must be strictly increasing"):
        SequentialPlan(THETA, GAMMA, (700, 700), (0.01, 0.01))
    with pytest.raises(ValueError, match=r"plan is for theta=0.05"):
        sequential(lambda k: np.ones(k), 0.1, GAMMA, sequential_plan(THETA, GAMMA))
    with pytest.raises(ValueError, match=r"draw\(119\) must return 119 outcomes in \{0, 1\}"):
        sequential(lambda k: np.full(k, 2), THETA, GAMMA)
    with pytest.raises(ValueError, match=r"half_width must be > 0 with 0 < delta ± half_width < 1, got 0.1"):
        sprt(lambda k: np.ones(k), delta=0.95, half_width=0.1)
