"""The η2 tier of a frame by two sequential threshold tests on one stream: its per-frame error is computed exactly,
by dynamic programming over the stopping rule (written here, independent of the tests' own calibration), at every
η2 of a fine grid and at the edges of both indifference zones."""

import numpy as np
import pytest

from uqdrive.uq.tier import CONFIDENT, DOUBTFUL, UNSURE, TierTest


def tier_probabilities(test: TierTest, etas: np.ndarray) -> np.ndarray:
    """[tier, η] probability that a frame ends in each tier: the mass of the running paths over the count k is
    carried draw by draw; at each look the counts the rule stops at move to their tier."""
    cap = test.looks[-1]
    running = np.zeros((cap + 1, etas.size))
    running[0] = 1.0
    ended = np.zeros((3, etas.size))
    n = 0
    for look in test.looks:
        while n < look:
            running[1:] = running[1:] * (1 - etas) + running[:-1] * etas
            running[0] *= 1 - etas
            n += 1
        for k in range(n + 1):
            tier = test.decide(k, n)
            if tier is not None:
                ended[tier] += running[k]
                running[k] = 0.0
    assert running.max() < 1e-12  # every run ends by the cap
    return ended


def true_tier(eta: np.ndarray, delta1: float, delta2: float) -> np.ndarray:
    return np.where(eta >= delta1, CONFIDENT, np.where(eta >= delta2, UNSURE, DOUBTFUL))


@pytest.mark.parametrize(
    ("delta1", "delta2", "gamma", "theta", "look", "cap"),
    [
        (0.7, 0.6, 0.05, 0.05, 8, 738),  # the paper's thresholds, θ = γ = 0.05, at most 738 draws
        (0.85, 0.5, 0.05, 0.1, 8, 200),  # a wide unsure tier
        (0.75, 0.75, 0.02, 0.1, 4, 400),  # one threshold: warning 1 never fires
        (0.95, 0.5, 0.05, 0.1, 8, 300),  # δ1's zone clipped at 1
        (0.7, 0.05, 0.05, 0.1, 8, 300),  # δ2's zone clipped at 0
    ],
)
def test_wrong_tier_is_rarer_than_gamma_wherever_eta2_is_theta_from_both_thresholds(
    delta1, delta2, gamma, theta, look, cap
):
    test = TierTest(delta1, delta2, gamma, theta, look, cap)
    edges = [d + s * theta for d in (delta1, delta2) for s in (-1, 1)]
    etas = np.union1d(np.linspace(0, 1, 1001), edges)
    outside = (np.abs(etas - delta1) >= theta - 1e-12) & (np.abs(etas - delta2) >= theta - 1e-12)
    probs = tier_probabilities(test, etas)
    assert np.allclose(probs.sum(0), 1.0)
    wrong = 1 - probs[true_tier(etas, delta1, delta2), np.arange(etas.size)]
    assert wrong[outside].max() <= gamma
    assert wrong[outside].max() > gamma / 10  # the budget is used, not squandered


def test_a_frame_whose_draws_all_agree_settles_at_the_second_look():
    test = TierTest(0.7, 0.6, 0.05, 0.05, 8, 738)
    assert test.looks[:2] == (8, 16) and test.first_draws == 16
    assert test.decide(8, 8) is None and test.decide(16, 16) == CONFIDENT and test.decide(0, 16) == DOUBTFUL
    drawn = []

    def draw(m: int) -> np.ndarray:
        drawn.append(m)
        return np.ones(m, dtype=np.int64)

    result = test.run(draw)
    assert (result.tier, result.n, result.k, drawn) == (CONFIDENT, 16, 16, [8, 8])


def test_the_cap_decides_every_frame_by_its_point_estimate():
    test = TierTest(0.7, 0.6, 0.05, 0.05, 8, 738)
    assert [test.decide(k, 738) for k in (int(0.59 * 738), int(0.65 * 738), int(0.71 * 738))] == [
        DOUBTFUL,
        UNSURE,
        CONFIDENT,
    ]


@pytest.mark.parametrize(("delta1", "delta2"), [(0.7, 0.8), (1.0, 0.6), (0.7, 0.0)])
def test_thresholds_out_of_order_or_at_0_or_1_are_refused(delta1, delta2):
    with pytest.raises(ValueError, match="sequential tiers need 0 < delta2 <= delta1 < 1"):
        TierTest(delta1, delta2, 0.05, 0.05, 8, 738)
