"""The gate's interval, floor, operating characteristic and error spending, each checked exactly by code
independent of `uqdrive.uq.gate`: a draw-by-draw forward recursion over the counts (the stopping rule read
through `ThresholdTest.decide`) gives P(low > η1) and P(high < η1) at the stopping time at a fine grid and just
below (above) every end the interval takes; the verdict and the interval agree at every stop point; the ledger's
union over attempts is summed from each attempt's exact worst error."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from uqdrive.uq import ThresholdTest, clopper_pearson_interval
from uqdrive.uq.gate import (
    attempt_gamma,
    budget_floor,
    certifies_all_safe,
    looks_for,
    near_target,
    stop_interval,
    zero_failure_floor,
)

ROOT = Path(__file__).resolve().parents[1]
CASES = [(0.8, 0.0, 0.1, 4, 40), (0.8, 0.05, 0.1, 4, 40), (0.9, 0.0, 0.05, 4, 120), (0.6, 0.1, 0.05, 5, 60)]


def stops(test: ThresholdTest) -> dict[tuple[int, int], int]:
    """Every (n, k) a run can stop at → decision code, by walking the counts look by look through `decide`."""
    out, running, n0 = {}, {0}, 0
    for n in test.looks:
        reach = {k + j for k in running for j in range(n - n0 + 1)}
        running = set()
        for k in sorted(reach):
            decision = test.decide(k, n)
            if decision is not None or n == test.looks[-1]:
                out[(n, k)] = {"above": 1, "below": -1, None: 0}[decision]
            else:
                running.add(k)
        n0 = n
    return out


def miss(test: ThresholdTest, ends: dict[tuple[int, int], tuple[float, float]], etas: np.ndarray):
    """Exact (P(low > η), P(high < η)) at the stopping time, draw by draw."""
    dist = np.zeros((test.looks[-1] + 1, etas.size))
    dist[0] = 1.0
    low_miss, high_miss = np.zeros(etas.size), np.zeros(etas.size)
    for n in range(1, test.looks[-1] + 1):
        dist[1:] = dist[1:] * (1 - etas) + dist[:-1] * etas
        dist[0] *= 1 - etas
        if n not in test.looks:
            continue
        for k in range(n + 1):
            if (n, k) in ends:
                low, high = ends[(n, k)]
                low_miss += dist[k] * (low > etas)
                high_miss += dist[k] * (high < etas)
                dist[k] = 0.0
    assert np.allclose(dist, 0.0)  # every run stopped
    return low_miss, high_miss


@pytest.mark.parametrize("eta,theta,gamma,look,budget", CASES)
def test_the_interval_covers_at_the_stopping_time_and_agrees_with_the_verdict(eta, theta, gamma, look, budget):
    test = ThresholdTest(eta, gamma, looks_for(look, budget), theta=theta, forced=False)
    codes = stops(test)
    ends = {}
    for (n, k), code in codes.items():
        interval = stop_interval(test, k, n)
        ends[(n, k)] = (interval.low, interval.high)
        assert (interval.low >= test.low_edge) == (code == 1), (n, k, interval)  # certified exactly when low ≥ η−θ
        assert (interval.high <= test.high_edge) == (code == -1), (n, k, interval)
        assert 0 <= interval.low <= k / n <= interval.high <= 1
        shown_low, shown_high = (float(x) for x in interval.shown().strip("[]").split(", "))
        assert (shown_low >= test.low_edge) == (code == 1) and (shown_high <= test.high_edge) == (code == -1)
    jumps = np.array(sorted({e for pair in ends.values() for e in pair} - {0.0, 1.0}))
    etas = np.concatenate([np.linspace(0, 1, 2001), jumps - 1e-12, jumps + 1e-12])
    low_miss, high_miss = miss(test, ends, etas)
    assert low_miss.max() <= gamma + 1e-12 and high_miss.max() <= gamma + 1e-12
    assert max(low_miss.max(), high_miss.max()) >= 0.3 * gamma  # exact inversion: not a sliver of γ
    # the check can fail: Clopper–Pearson at the stop, one-sided γ each end, blind to the stopping rule, misses more
    naive = {nk: tuple(map(float, clopper_pearson_interval(nk[1], nk[0], 2 * gamma))) for nk in codes}
    assert max(m.max() for m in miss(test, naive, etas)) > gamma


def test_the_certify_default_interval_agrees_with_its_verdict_at_every_stop():
    """η 0.9, γ 0.05, a look every 4 up to 400 (the CLI's default): consistency at every reachable stop point."""
    test = ThresholdTest(0.9, 0.05, looks_for(4, 400), forced=False)
    for (n, k), code in stops(test).items():
        if code == 0 and k % 7:  # the cap's undecided counts: a sample of them (each is two bisections)
            continue
        interval = stop_interval(test, k, n)
        assert (interval.low >= 0.9) == (code == 1) and (interval.high <= 0.9) == (code == -1)


def test_a_point_that_is_no_stop_is_refused():
    test = ThresholdTest(0.8, 0.1, looks_for(4, 40), forced=False)
    with pytest.raises(ValueError, match="does not stop"):
        stop_interval(test, 10, 12)


@pytest.mark.parametrize("eta,theta,gamma", [(0.9, 0.0, 0.05), (0.99, 0.0, 0.01), (0.95, 0.02, 0.05)])
def test_the_floor_is_the_least_budget_that_can_certify(eta, theta, gamma):
    """Below ⌈ln γ / ln(η−θ)⌉ no calibrated test certifies all-safe (its error at η−θ would exceed γ); the budget
    `budget_floor` names does, and 20 % less does not (within a few steps of the least)."""
    floor = zero_failure_floor(eta, theta, gamma)
    assert (eta - theta) ** floor <= gamma < (eta - theta) ** (floor - 1)
    budget = budget_floor(eta, theta, gamma, 4)
    assert budget >= floor and budget % 4 == 0
    test = ThresholdTest(eta, gamma, looks_for(4, budget), theta=theta, forced=False)
    assert certifies_all_safe(test) and test.worst_errors()[0] <= gamma
    less = 4 * math.floor(0.8 * budget / 4)
    if less >= 4:
        try:
            assert not certifies_all_safe(ThresholdTest(eta, gamma, looks_for(4, less), theta=theta, forced=False))
        except ValueError:  # too small to build at all
            pass


def test_near_target_at_the_default_is_what_help_and_readme_say():
    """The numbers `uqdrive certify --help` and the README quote, exactly (η 0.9, θ 0, budget 400, a first attempt
    at γ_1 of γ 0.05), and at the full γ 0.05 the issue's (0.90 undecided at η1 = η, the band (0.836, 0.950))."""
    from uqdrive.pipeline.certify_stage import NEAR_DEFAULT

    near = near_target(ThresholdTest(0.9, attempt_gamma(0.05, 1), looks_for(4, 400), forced=False))
    assert " ".join(near.said().split()) in " ".join(NEAR_DEFAULT.split())
    assert (ROOT / "README.md").read_text().count("(0.827, 0.955)") >= 1
    full = near_target(ThresholdTest(0.9, 0.05, looks_for(4, 400), forced=False))
    assert round(full.undecided_at_eta, 2) == 0.90 and full.band == (0.836, 0.95)


def test_the_error_spent_over_any_number_of_attempts_stays_within_gamma():
    """An adversary resubmits a changed policy after every failure, each time at the worst η1 (the low edge, where
    P(certified) is largest, by monotonicity), each attempt on seeds no earlier one used: the attempts are
    independent, so P(some attempt certifies) = 1 − Π(1 − e_k) with e_k each attempt's exact worst error (the
    independent forward recursion at γ_k), ≤ γ over 12 attempts and, bounding the rest by Σ_{k>12} γ_k, for ever."""
    from test_uq_threshold import decisions, forward

    gamma, eta = 0.05, 0.9
    survive, errors = 1.0, []
    for k in range(1, 13):
        test = ThresholdTest(eta, attempt_gamma(gamma, k), looks_for(4, 400), forced=False)
        above, _, _ = forward(decisions(test), np.array([eta]))
        errors.append(float(above[0]))
        survive *= 1 - errors[-1]
    tail = gamma - sum(attempt_gamma(gamma, k) for k in range(1, 13))
    assert 1 - survive + tail <= gamma
    assert all(e <= attempt_gamma(gamma, k + 1) for k, e in enumerate(errors))
    # the same adversary against a gate that gives every attempt the full γ: certified wrongly far more often
    flat = forward(decisions(ThresholdTest(eta, gamma, looks_for(4, 400), forced=False)), np.array([eta]))[0][0]
    assert 1 - (1 - flat) ** 12 > 5 * gamma
    assert math.isclose(sum(attempt_gamma(gamma, k) for k in range(1, 200_001)), gamma, rel_tol=1e-5)
