"""The η2 tier of a frame by two sequential threshold tests on one stream (or the paper's point estimate): its
per-frame error is computed exactly, by dynamic programming over the stopping rule written here (independent of
the rules' own computation, which runs when a rule is built), at every η2 of a fine grid and at the thresholds and
the edges of both indifference zones; the rules' own numbers must agree, and a rule above γ is refused."""

import itertools

import numpy as np
import pytest

from uqdrive.uq.threshold import ThresholdTest, doubling_looks
from uqdrive.uq.tier import CONFIDENT, DOUBTFUL, UNDECIDED, UNSURE, FixedTier, TierTest, tier_rule


def tier_probabilities(test, etas: np.ndarray) -> np.ndarray:
    """[tier, η] probability that a frame ends in each tier: the mass of the running paths over the count k is
    carried draw by draw; at each look the counts the rule stops at move to their tier."""
    cap = test.looks[-1]
    running = np.zeros((cap + 1, etas.size))
    running[0] = 1.0
    ended = np.zeros((3, etas.size))
    n = 0
    for look in test.looks:
        while n < look:  # counts above n carry no mass yet
            running[1 : n + 2] = running[1 : n + 2] * (1 - etas) + running[: n + 1] * etas
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


_RATES: dict[tuple, tuple[float, float]] = {}


def wrong_tier_rate(test, theta: float) -> tuple[float, float]:
    """Cached `_wrong_tier_rate` (the paper's setting is checked twice)."""
    key = (type(test).__name__, test.delta1, test.delta2, test.looks, theta, getattr(test, "gamma", None))
    if key not in _RATES:
        _RATES[key] = _wrong_tier_rate(test, theta)
    return _RATES[key]


def _wrong_tier_rate(test, theta: float) -> tuple[float, float]:
    """(worst P(wrong tier) over η2 at least θ from both thresholds, worst P(a tier no η2' within θ has) anywhere),
    over 2001 grid points plus the thresholds and the zones' edges. The tiers acceptable near η are found by
    scanning η' over a fine grid of (η − θ, η + θ), not from the tier regions' geometry."""
    d1, d2 = test.delta1, test.delta2
    edges = np.clip([d + s * theta for d in (d1, d2) for s in (-1, 0, 1)], 0, 1)
    etas = np.union1d(np.linspace(0, 1, 2001), edges)
    probs = tier_probabilities(test, etas)
    assert np.allclose(probs.sum(0), 1.0)
    outside = (np.abs(etas - d1) >= theta - 1e-12) & (np.abs(etas - d2) >= theta - 1e-12)
    wrong = 1 - probs[true_tier(etas, d1, d2), np.arange(etas.size)]
    near = etas[:, None] + np.linspace(-theta, theta, 4001)[1:-1][None]
    near = np.where((near >= 0) & (near <= 1), near, etas[:, None])  # η' stays in [0, 1]
    tiers = true_tier(near, d1, d2)
    tiers[outside] = true_tier(etas[outside], d1, d2)[:, None]  # the scan's float steps may reach past an edge
    ok = np.stack([(tiers == t).any(1) for t in (CONFIDENT, UNSURE, DOUBTFUL)])
    return float(wrong[outside].max(initial=0.0)), float((probs * ~ok).sum(0).max())


class DocumentedRule:
    """The sequential tier rule as `uqdrive.uq.tier` documents it, from its two threshold tests at γ/2 (not
    `TierTest`'s code), for settings `TierTest` refuses to build."""

    def __init__(self, delta1: float, delta2: float, gamma: float, theta: float, look: int, cap: int):
        self.delta1, self.delta2, self.looks = delta1, delta2, doubling_looks(look, cap)
        self.upper, self.lower = (ThresholdTest(d, gamma / 2, self.looks, theta) for d in (delta1, delta2))

    def decide(self, k: int, n: int) -> int | None:
        upper, lower = self.upper.decide(k, n), self.lower.decide(k, n)
        if upper == "above":
            return CONFIDENT
        if lower == "below":
            return DOUBTFUL
        return UNSURE if (upper, lower) == ("below", "above") else None


# as the profiles deploy them (test_safety_draws composes them): the first look is the first head call's 24 draws
QUICK = (0.7, 0.6, 0.05, 0.1, 24, 185)  # conf/profile/quick.yaml: θ = 0.1, cap chernoff_n(0.1, 0.05) = 185
PAPER = (0.7, 0.6, 0.05, 0.05, 24, 738)  # the paper's thresholds, θ = γ = 0.05, at most 738 draws


@pytest.mark.parametrize(
    ("delta1", "delta2", "gamma", "theta", "look", "cap"),
    [
        PAPER,
        QUICK,
        (0.7, 0.6, 0.05, 0.05, 8, 738),  # the paper's, looks from 8
        (0.85, 0.5, 0.05, 0.1, 8, 200),  # a wide unsure tier
        (0.75, 0.75, 0.02, 0.1, 4, 400),  # one threshold: warning 1 never fires
        (0.95, 0.5, 0.05, 0.1, 8, 300),  # δ1's zone clipped at 1
        (0.7, 0.05, 0.05, 0.1, 8, 300),  # δ2's zone clipped at 0
        (0.8, 0.6, 0.05, 0.1, 8, 185),  # the quick profile's θ with thresholds 2θ apart: the middle tier guaranteed
        (1.0, 0.9, 0.05, 0.05, 8, 738),  # δ1 = 1: confident only when every draw to the cap agrees
        (0.6, 0.0, 0.05, 0.1, 8, 185),  # δ2 = 0: never doubtful
        (0.733, 0.517, 0.05, 0.071, 8, 250),  # zone edges off any round grid
    ],
)
def test_the_exact_error_a_rule_computes_when_built_is_the_error_and_at_most_gamma(
    delta1, delta2, gamma, theta, look, cap
):
    test = TierTest(delta1, delta2, gamma, theta, look, cap)
    outside, anywhere = wrong_tier_rate(test, theta)
    print(f"TierTest{(delta1, delta2, gamma, theta, look, cap)}: exact wrong-tier error {anywhere:.5f}")
    assert test.error == pytest.approx(anywhere, abs=1e-9)
    assert outside <= anywhere + 1e-12 and anywhere <= gamma
    if 0 < delta2 < delta1 < 1:
        assert anywhere > gamma / 10  # the budget is used, not squandered


def test_the_paper_s_fixed_draws_compute_their_tier_error_too():
    fixed = FixedTier(0.7, 0.6, 0.05, 0.1, 185)
    assert fixed.looks == (185,) and fixed.decide(130, 185) == CONFIDENT and fixed.decide(129, 185) == UNSURE
    assert fixed.error == pytest.approx(wrong_tier_rate(fixed, 0.1)[1], abs=1e-9) and fixed.error <= 0.05


def test_the_quick_and_paper_settings_are_accepted_and_say_whether_the_middle_tier_is_guaranteed():
    """Quick: δ1 − δ2 = 0.1 < 2θ = 0.2, so every η2 of the middle tier lies within θ of a threshold: no η2 is owed
    warning 1. The paper: 0.7 − 0.6 = 2θ (in floating point 0.0999…), guaranteed at η2 = 0.65 only."""
    quick, paper = TierTest(*QUICK), TierTest(*PAPER)
    print(f"quick: exact wrong-tier error {quick.error:.5f}; paper: {paper.error:.5f}")
    assert not quick.middle_guaranteed and paper.middle_guaranteed
    assert quick.settings() == {
        "scheme": "sequential",
        "delta1": 0.7,
        "delta2": 0.6,
        "theta": 0.1,
        "gamma": 0.05,
        "looks": [24, 48, 96, 185],
        "wrong_tier_error": quick.error,
        "middle_guaranteed": False,
    }
    assert TierTest(0.8, 0.6, 0.05, 0.1, 24, 185).middle_guaranteed


def test_a_setting_whose_exact_error_exceeds_gamma_is_refused_in_one_line():
    """Thresholds 2θ apart at γ = 0.3 with a small cap: at η2 = 0.7 both tests sit at their zones' edges, each
    errs up to γ/2, and inside the rule a test that answered may later answer the other way: 0.334 > 0.3."""
    outside, _ = wrong_tier_rate(DocumentedRule(0.8, 0.6, 0.3, 0.1, 4, 40), 0.1)
    assert outside == pytest.approx(0.33446, abs=1e-5)
    with pytest.raises(ValueError) as err:
        TierTest(0.8, 0.6, 0.3, 0.1, 4, 40)
    assert str(err.value) == (
        "sequential tier rule delta1=0.8, delta2=0.6, theta=0.1, gamma=0.3, looks 4/8/16/32/40: its exact "
        "wrong-tier error is 0.3345 > gamma=0.3; widen theta, raise the cap or set the thresholds further apart"
    )


@pytest.mark.parametrize(("theta", "cap"), [(0.1, 185), (0.05, 738)])
def test_every_threshold_pair_the_calibration_may_choose_has_a_rule_within_gamma(theta, cap):
    """The avoid stage's candidate grid (conf/avoid.yaml, with the never-firing 0) at the quick and paper settings:
    each pair's rule, built as a calibrated cell builds it, computes its own exact error (the independent DP
    checks the worst)."""
    grid = [0.0, 0.5, 0.6, 0.7, 0.75, 0.8, 0.85, 0.9, 0.95, 0.97, 0.98, 0.99, 0.995, 1.0]
    pairs = [(d1, d2) for d1, d2 in itertools.product(grid, grid) if d2 <= d1]
    worst = max((tier_rule(TierTest, d1, d2, 0.05, theta, 24, cap) for d1, d2 in pairs), key=lambda r: r.error)
    print(f"theta={theta}, cap={cap}: worst exact wrong-tier error {worst.error:.5f}, {worst.describe()}")
    assert worst.error <= 0.05 and wrong_tier_rate(worst, theta)[1] == pytest.approx(worst.error, abs=1e-9)


@pytest.mark.parametrize(
    "rule",
    [
        TierTest(0.7, 0.6, 0.05, 0.1, 8, 185),
        TierTest(1.0, 0.6, 0.05, 0.1, 24, 185),
        FixedTier(0.7, 0.6, 0.05, 0.1, 185),
    ],
)
def test_recorded_counts_give_the_tier_the_rule_decides_on_the_same_stream(rule):
    """The calibration replays a rule from the counts a warnings-off frame records at every look; the controller
    runs it on the stream. Streams of rates 0 … 1; counts at every look, or only up to the stopping look."""
    rng = np.random.default_rng(0)
    streams = (rng.random((400, rule.looks[-1])) < rng.random((400, 1))).astype(np.int64)
    counts = np.cumsum(streams, 1)[:, np.array(rule.looks) - 1]
    ran = []
    for stream in streams:
        served = iter(np.split(stream, rule.looks[:-1]))
        ran.append(rule.run(lambda m, s=served: next(s)))
    assert rule.tiers(counts).tolist() == [r.tier for r in ran]
    assert {r.tier for r in ran} == {CONFIDENT, UNSURE, DOUBTFUL}
    read = np.array([[k if n <= r.n else UNDECIDED for k, n in zip(row, rule.looks)] for row, r in zip(counts, ran)])
    assert rule.tiers(read).tolist() == [r.tier for r in ran]


def test_a_frame_whose_draws_all_agree_settles_at_the_second_look():
    test = TierTest(0.7, 0.6, 0.05, 0.05, 8, 738)
    assert test.looks[:2] == (8, 16)
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


def test_thresholds_out_of_order_are_refused():
    with pytest.raises(ValueError, match="tiers need 0 <= delta2 <= delta1 <= 1, got delta1=0.7, delta2=0.8"):
        TierTest(0.7, 0.8, 0.05, 0.05, 8, 738)


def test_thresholds_of_0_and_1_have_rules_and_the_never_firing_one_reads_no_draw():
    """The calibration's grid holds 0 (never warn) and 1 (warn at any disagreement): the deployed rule must decide
    them too. δ1 = δ2 = 0 is confident on no draw; δ1 = 1 is confident only when all 185 draws agree."""
    never = TierTest(0.0, 0.0, 0.05, 0.1, 8, 185)
    assert not never.reads_draws and never.error == 0
    assert never.run(lambda m: pytest.fail("a rule that reads no draw drew")).n == 0
    strict = TierTest(1.0, 0.6, 0.05, 0.1, 8, 185)
    assert strict.decide(128, 128) is None and strict.decide(185, 185) == CONFIDENT
    assert strict.decide(15, 16) == UNSURE and strict.decide(2, 16) == DOUBTFUL
