"""Phase two's guarantee, computed exactly: each region's test at its share γ_r errs with probability ≤ γ_r for every
η1 on the wrong side of τ (binomial dynamic programming over its looks, here, apart from the test's own
calibration), the shares sum to ≤ γ, and so the whole map's error, even with every region at its worst case, is
≤ γ."""

from fractions import Fraction

import numpy as np
import pytest
from scipy import stats

from uqdrive.envelope.certify import (
    CertifySettings,
    Decision,
    certify,
    clean_run_to_safe,
    decision_order,
    grid_cost,
    region_test,
    threshold_decision,
)
from uqdrive.envelope.partition import Region
from uqdrive.envelope.search import BoundaryModel
from uqdrive.schema import ConfigError, validate
from uqdrive.uq import clopper_pearson_interval
from uqdrive.uq.multiplicity import split_gamma


def exact_errors(test, eta: float) -> tuple[float, float]:
    """(P(safe), P(unsafe)) of a region's test at true η1 = eta: the distribution of the success count over the
    runs still going, carried from look to look by binomial convolution, each look's decided counts removed."""
    going, drawn = np.ones(1), 0
    safe = unsafe = 0.0
    for n in test.looks:
        going = np.convolve(going, stats.binom.pmf(np.arange(n - drawn + 1), n - drawn, eta))
        drawn = n
        for k in range(n + 1):
            decision = test.decide(k, n)
            if decision == "above":
                safe += going[k]
            elif decision == "below":
                unsafe += going[k]
            if decision is not None:
                going[k] = 0.0
    return safe, unsafe


QUICK = CertifySettings(threshold=0.9, gamma=0.05, theta=0.0, look_size=4, region_budget=64)
SETTINGS = [
    QUICK,
    CertifySettings(threshold=0.9, gamma=0.05, theta=0.05, look_size=8, region_budget=96),
    CertifySettings(threshold=0.8, gamma=0.1, theta=0.0, look_size=16, region_budget=128),
]


@pytest.mark.parametrize("settings", SETTINGS, ids=str)
@pytest.mark.parametrize("regions", [1, 4, 7, 13, 16])
def test_each_region_errs_at_most_its_share_for_every_rate_on_the_wrong_side(settings, regions):
    share = split_gamma(settings.gamma, regions)
    test = region_test(settings, share)
    tau, theta = settings.threshold, settings.theta
    below_tau = np.concatenate([np.linspace(0, tau - theta, 101), [np.nextafter(tau - theta, 0)]])
    above_tau = np.linspace(tau + theta, 1, 101)
    assert max(exact_errors(test, eta)[0] for eta in below_tau) <= share  # safe, when η1 < τ − θ (< τ at θ = 0)
    assert max(exact_errors(test, eta)[1] for eta in above_tau) <= share  # unsafe, when η1 ≥ τ + θ


@pytest.mark.parametrize("regions", [4, 13, 64])
def test_the_whole_map_errs_at_most_gamma_even_with_every_region_at_its_worst_case(regions):
    """Regions' draws are independent given the partition, so P(some verdict wrong) = 1 − Π(1 − e_r); with every
    region's η1 at the worst case for a wrong "safe" (just below τ) it is still ≤ Σ γ_r ≤ γ."""
    shares = (split_gamma(QUICK.gamma, regions),) * regions
    assert sum(map(Fraction, shares)) <= Fraction(QUICK.gamma)
    worst = [exact_errors(region_test(QUICK, g), np.nextafter(QUICK.threshold, 0))[0] for g in shares]
    assert 1 - np.prod(1 - np.array(worst)) <= sum(worst) <= QUICK.gamma
    worst_unsafe = [exact_errors(region_test(QUICK, g), QUICK.threshold)[1] for g in shares]
    assert 1 - np.prod(1 - np.array(worst_unsafe)) <= QUICK.gamma


def test_certify_hands_each_region_its_share_and_what_is_left_of_the_budget():
    regions = Region.cube(2).children()
    asked = []

    def decide(index, region, gamma, cap):
        asked.append((index, region, gamma, cap))
        return Decision(("safe", "unsafe", "undecided", "safe")[index], 10 + index, index)

    share = split_gamma(0.05, 4)
    results = certify(regions, 0.05, decide)
    assert asked == [(i, r, share, None) for i, r in enumerate(regions)]
    assert [(r.region, r.verdict, r.rollouts, r.safe, r.gamma) for r in results] == [
        (regions[0], "safe", 10, 0, share),
        (regions[1], "unsafe", 11, 1, share),
        (regions[2], "undecided", 12, 2, share),
        (regions[3], "safe", 13, 3, share),
    ]
    asked.clear()  # in order 2, 0, 3, 1 with 30 rollouts in all: 2 takes 12, 0 takes 10, 3 is asked with 8 left
    results = certify(regions, 0.05, decide, order=[2, 0, 3, 1], budget=30, first_look=4)
    assert [(i, cap) for i, _, _, cap in asked] == [(2, 30), (0, 18), (3, 8)]
    assert (results[1].verdict, results[1].rollouts) == ("undecided", 0)  # -5 left: never started


def test_a_region_ends_safe_unsafe_or_undecided_at_its_budget():
    share = split_gamma(QUICK.gamma, 13)
    drawn = []

    def constant(value):
        def draw(count):
            drawn.append(count)
            return np.full(count, value)

        return draw

    clean = clean_run_to_safe(QUICK, share)
    assert threshold_decision(QUICK, share, constant(1)) == Decision("safe", clean, clean)
    assert 0.9**clean <= share  # no sooner than a single fixed-n test could (P(all safe | η1 = τ) ≤ γ_r)
    assert set(drawn) == {4}  # one look every look_size rollouts
    assert threshold_decision(QUICK, share, constant(0)) == Decision("unsafe", 4, 0)
    pattern = np.tile([1] * 9 + [0], 7)  # η̂1 = 0.9 throughout: neither side is ever certified
    position = iter(range(0, 10**6))
    undecided = threshold_decision(QUICK, share, lambda count: pattern[[next(position) for _ in range(count)]])
    assert undecided == Decision("undecided", 64, int(pattern[:64].sum()))
    assert clean_run_to_safe(CertifySettings(threshold=0.9, gamma=0.05, region_budget=32), share) is None
    drawn.clear()  # a cap ends the same test sooner: undecided, never another verdict
    assert threshold_decision(QUICK, share, constant(1), cap=clean - 1) == Decision("undecided", clean - 4, clean - 4)


def test_regions_go_by_the_decisions_their_tests_are_expected_to_make_per_rollout():
    """Three bands of phase-one outcomes: always safe, 88 % safe (just below τ), half safe. A coin flip is certified
    unsafe in a few rollouts, the safe band in a clean run of about 50, the band just below τ hardly ever."""
    points = np.random.default_rng(0).random((3000, 2))
    i = np.arange(3000)
    outcomes = np.select([points[:, 0] < 1 / 3, points[:, 0] < 2 / 3], [1, (i % 25 < 22).astype(int)], i % 2)
    model = BoundaryModel(points, outcomes, QUICK.threshold, bandwidth=0.03)
    safe, near, coin = (Region((lo, 0.0), (lo + 0.26, 1.0)) for lo in (0.04, 0.37, 0.7))
    assert decision_order([safe, near, coin], model, QUICK) == [2, 0, 1]


def test_the_grid_cost_is_a_per_cell_exact_interval_at_each_cells_share():
    cost = grid_cost(dim=2, depth=2, theta=0.05, gamma=0.05)
    assert cost["cells"] == 16 and cost["gamma_per_cell"] == split_gamma(0.05, 16)
    n = cost["per_cell"]
    assert cost["rollouts"] == 16 * n
    k = np.arange(n + 1)  # at n every count's exact interval at level 1 − γ/16 fits in ±θ; at n − 1 one does not
    low, high = clopper_pearson_interval(k, n, cost["gamma_per_cell"])
    assert ((low >= k / n - 0.05) & (high <= k / n + 0.05)).all()
    k = np.arange(n)
    low, high = clopper_pearson_interval(k, n - 1, cost["gamma_per_cell"])
    assert not ((low >= k / (n - 1) - 0.05) & (high <= k / (n - 1) + 0.05)).all()
    assert cost["rollouts_per_cell_gamma"] < cost["rollouts"]


def test_settings_are_checked():
    with pytest.raises(ConfigError, match=r"^envelope.theta=0.2 must be < min\(threshold, 1 - threshold\) = 0.1$"):
        validate(CertifySettings, {"threshold": 0.9, "theta": 0.2}, "envelope")
    with pytest.raises(ConfigError, match=r"^envelope.region_budget=3 must be >= look_size \(4\)$"):
        validate(CertifySettings, {"region_budget": 3}, "envelope")
    assert CertifySettings(look_size=16, region_budget=40).looks == (16, 32, 40)
