"""Method claims across training replicates: the paired t's numbers against scipy, its floors, power and planning,
and the verdicts' error rates by simulation: training runs whose rates spread by a beta distribution (A and B
correlated through a shared training run), paired Bernoulli rollouts in each replicate, 10,000 repetitions a design,
each error rate's exact (Clopper–Pearson) upper bound below α."""

import itertools

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq.claims import (
    MarginClaim,
    MethodClaim,
    claim_verdicts,
    decide_claim,
    decide_claims,
    detectable_difference,
    replicate_t,
    replicate_t_means,
    replicates_needed,
)
from uqdrive.uq.multiplicity import split_gamma
from uqdrive.uq.paired import PairedTable
from uqdrive.uq.verdict import Reason, Verdict

ALPHA, MARGIN, REPS = 0.05, 0.1, 10_000


def upper(count: int, reps: int = REPS) -> float:
    """Top of the 95 % Clopper–Pearson interval of a simulated rate."""
    return float(stats.beta.ppf(0.975, count + 1, reps - count)) if count < reps else 1.0


def replicate_rates(rng, shape, mean_a, mean_b, concentration, shared=0.5):
    """η_A,r ~ Beta(κ m_A, κ (1 − m_A)) and η_B,r likewise, correlated: each is G/(G + H) of gamma variables, a
    ``shared`` fraction of the smaller shapes' gamma parts common to both (one training run's trunk)."""
    shapes = [(concentration * m, concentration * (1 - m)) for m in (mean_a, mean_b)]
    common = [shared * min(s[i] for s in shapes) for i in (0, 1)]
    g, h = rng.gamma(common[0], size=shape), rng.gamma(common[1], size=shape)
    rates = []
    for alpha, beta in shapes:
        own_g, own_h = rng.gamma(alpha - common[0], size=shape), rng.gamma(beta - common[1], size=shape)
        rates.append((g + own_g) / (g + own_g + h + own_h))
    return rates


def tables(rng, replicates, n, mean_a, mean_b, concentration, same_world=0.5):
    """Each replicate's (a_only, b_only) from n paired rollouts: a rollout's two outcomes share its world with
    probability ``same_world`` (then they fail together as far as the rates allow), else are independent."""
    eta_a, eta_b = replicate_rates(rng, (REPS, replicates), mean_a, mean_b, concentration)
    p_a = same_world * np.maximum(eta_a - eta_b, 0) + (1 - same_world) * eta_a * (1 - eta_b)
    p_b = same_world * np.maximum(eta_b - eta_a, 0) + (1 - same_world) * eta_b * (1 - eta_a)
    a_only = rng.binomial(n, p_a)
    b_only = rng.binomial(n - a_only, np.clip(p_b / np.maximum(1 - p_a, 1e-12), 0, 1))
    return a_only, b_only


def verdict_counts(rng, replicates, n, mean_a, mean_b, concentration, same_world=0.5) -> dict[str, int]:
    a_only, b_only = tables(rng, replicates, n, mean_a, mean_b, concentration, same_world)
    verdicts = claim_verdicts(replicate_t(a_only, b_only, n, ALPHA, MARGIN), MARGIN)
    return {v: int(np.sum(verdicts == v)) for v in Verdict}


DESIGNS = list(itertools.product((14, 50, 100), (2, 4, 8)))


@pytest.mark.parametrize("mean", [0.5, 0.9, 0.97])
def test_no_difference_is_rarely_called_one(mean):
    """A and B equally safe over training runs: runs spread wide and piling at 0 and 1 (κ = 2), moderately (30),
    or hardly at all (1000: every replicate's difference is rollout noise, many coincide). A claim's SUPPORTED
    (and, for the claim the other way, REFUTED) is wrong here; each is one tail of the interval (nominal α/2)."""
    rng = np.random.default_rng(int(mean * 100))
    for (n, replicates), concentration in itertools.product(DESIGNS, (2, 30, 1000)):
        counts = verdict_counts(rng, replicates, n, mean, mean, concentration)
        design = (n, replicates, concentration, counts)
        assert upper(counts[Verdict.SUPPORTED]) < ALPHA and upper(counts[Verdict.REFUTED]) < ALPHA, design


@pytest.mark.parametrize("mean", [0.5, 0.9, 0.97])
def test_a_difference_at_the_margin_is_rarely_called_equivalent(mean):
    """True mean difference +δ and −δ (δ = 0.1; A's mean rate ``mean``, B's δ lower, then the other way round):
    EQUIVALENT is wrong, and so is the verdict against the true sign; both lie in one tail of the interval.
    Training runs spread moderately (κ = 30) with rollouts sharing half their worlds, or hardly at all with
    nested worlds (the less safe fails wherever the safer does): there, at 14 rollouts, both replicates often
    show no discordant pair at all, which only the margin's variance floor keeps from reading as equivalence."""
    rng = np.random.default_rng(int(mean * 1000))
    for (n, replicates), (concentration, same_world) in itertools.product(DESIGNS, ((30, 0.5), (1000, 1.0))):
        plus = verdict_counts(rng, replicates, n, mean, mean - MARGIN, concentration, same_world)
        minus = verdict_counts(rng, replicates, n, mean - MARGIN, mean, concentration, same_world)
        wrong_plus = plus[Verdict.EQUIVALENT] + plus[Verdict.REFUTED]
        wrong_minus = minus[Verdict.EQUIVALENT] + minus[Verdict.SUPPORTED]
        assert upper(wrong_plus) < ALPHA and upper(wrong_minus) < ALPHA, (n, replicates, concentration, plus, minus)


def test_the_t_assumption_is_what_the_equivalence_rests_on():
    """Where training runs pile at 1 and rarely fail (rates Beta(1.94, 0.06) against Beta(1.74, 0.26)), most
    replicates show no difference and the mean difference rests on the rare failures: EQUIVALENT at the margin
    is then far more frequent than α — the verdict is only as good as the assumption it states."""
    counts = verdict_counts(np.random.default_rng(3), 4, 100, 0.97, 0.97 - MARGIN, 2)
    assert counts[Verdict.EQUIVALENT] / REPS > 2 * ALPHA


def test_a_family_split_by_bonferroni_makes_no_false_verdict_with_probability_at_most_alpha():
    """Four claims with no difference, on independent data: any SUPPORTED or REFUTED among them is false."""
    rng = np.random.default_rng(4)
    level = split_gamma(ALPHA, 4)
    wrong = np.zeros(REPS, bool)
    for mean in (0.5, 0.7, 0.9, 0.97):
        a_only, b_only = tables(rng, 8, 100, mean, mean, 30)
        verdicts = claim_verdicts(replicate_t(a_only, b_only, 100, level, MARGIN), MARGIN)
        wrong |= (verdicts == Verdict.SUPPORTED) | (verdicts == Verdict.REFUTED)
    assert upper(int(wrong.sum())) < ALPHA


def claim(effects_a_only: list[tuple[int, int]], n: int = 50, margin: float = MARGIN) -> MethodClaim:
    return MethodClaim("a vs b", {r: PairedTable(n, a, b) for r, (a, b) in enumerate(effects_a_only)}, margin)


def test_the_interval_and_p_value_are_students_paired_t():
    counts = [(12, 2), (9, 4), (15, 1), (8, 5)]
    result = decide_claim(claim(counts), ALPHA)
    differences = [(a - b) / 50 for a, b in counts]
    reference = stats.ttest_1samp(differences, 0.0)
    low, high = reference.confidence_interval(1 - ALPHA)
    assert (result.estimate, result.low, result.high) == pytest.approx((np.mean(differences), low, high))
    assert result.p_value == pytest.approx(reference.pvalue) and result.sd == pytest.approx(np.std(differences, ddof=1))
    assert result.verdict is Verdict.SUPPORTED and result.reason is Reason.DECIDED and "normal" in result.assumption
    assert result.detectable == detectable_difference(result.sd, 4, ALPHA)
    assert result.needed == replicates_needed(result.sd, MARGIN, ALPHA)
    assert decide_claim(claim([(b, a) for a, b in counts]), ALPHA).verdict is Verdict.REFUTED


def test_replicates_that_coincide_are_floored_by_their_rollout_noise():
    """Two replicates each with one pair A alone safe: the sample variance is 0, the interval is not a point."""
    result = decide_claim(claim([(1, 0), (1, 0)], n=14), ALPHA)
    within = (1 / 14 - (1 / 14) ** 2) / 14
    assert result.sd == pytest.approx(np.sqrt(within)) and result.low < 0 < result.high
    assert result.verdict is Verdict.UNDECIDED and result.reason is Reason.INTERVAL_TOO_WIDE


def test_every_cell_at_one_is_equivalent_only_when_the_margin_floor_allows():
    """Every cell 1.00: no difference anywhere, the interval [0, 0]; EQUIVALENT needs the equivalence interval, its
    variance at least δ(1 − δ)/n, inside ±δ: 8 replicates of 100 rollouts, not 2 of 14."""
    many = decide_claim(claim([(0, 0)] * 8, n=100), ALPHA)
    few = decide_claim(claim([(0, 0)] * 2, n=14), ALPHA)
    assert (many.low, many.high, many.p_value) == (0.0, 0.0, 1.0) and many.verdict is Verdict.EQUIVALENT
    half = stats.t.ppf(1 - ALPHA / 2, 7) * np.sqrt(MARGIN * (1 - MARGIN) / 100 / 8)
    assert many.equivalence_high == pytest.approx(half)
    assert few.verdict is Verdict.UNDECIDED and few.equivalence_high > MARGIN


def test_one_replicate_decides_nothing():
    result = decide_claim(claim([(20, 0)]), ALPHA)
    assert (result.low, result.high, result.p_value) == (-1.0, 1.0, 1.0) and result.detectable == np.inf
    assert result.needed is None
    assert result.verdict is Verdict.UNDECIDED and result.reason is Reason.TOO_FEW_REPLICATES


def test_a_family_puts_each_claim_at_alpha_over_m():
    family = [claim([(12, 2), (9, 4), (15, 1)]), claim([(3, 2), (4, 4), (5, 1)]), claim([(1, 9), (0, 4), (2, 8)])]
    results = decide_claims(family, ALPHA)
    assert [r.level for r in results] == [ALPHA / 3] * 3
    assert [(r.low, r.high) for r in results] == [(r.low, r.high) for r in (decide_claim(c, ALPHA / 3) for c in family)]
    with pytest.raises(ValueError, match="at least one claim"):
        decide_claims([], ALPHA)


@pytest.mark.parametrize("replicates, sd", [(3, 0.1), (5, 0.2), (10, 0.05)])
def test_the_detectable_difference_is_detected_with_80_percent_power(replicates, sd):
    """Normal replicate differences at the detectable mean: the paired t rejects on their side 80 % of the time."""
    difference = detectable_difference(sd, replicates, ALPHA)
    draws = np.random.default_rng(replicates).normal(difference, sd, (REPS, replicates))
    reference = stats.ttest_1samp(draws, 0.0, axis=1)
    power = np.mean((reference.pvalue <= ALPHA) & (reference.statistic > 0))
    assert power == pytest.approx(0.8, abs=0.015)


def test_replicates_needed_is_the_fewest_that_detect_the_target():
    needed = replicates_needed(0.1, 0.1, ALPHA)
    assert detectable_difference(0.1, needed, ALPHA) <= 0.1 < detectable_difference(0.1, needed - 1, ALPHA)
    assert needed == 10 and replicates_needed(0.01, 0.5, ALPHA) == 2
    assert detectable_difference(0.0, 4, ALPHA) == 0.0 and detectable_difference(0.1, 1, ALPHA) == np.inf


def test_margin_claims_keep_their_size_under_a_spread_of_training_runs():
    """The continuous version (per-run margin differences): replicate means spread between training runs, runs
    within a replicate noisy, equal means. 10,000 repetitions per design: the CP upper end of each kind's error
    rate stays below α (each verdict kind is one tail: nominal α/2)."""
    rng = np.random.default_rng(7)
    for replicates, runs, spread in ((4, 14, 0.2), (8, 50, 0.05), (8, 14, 1.0)):
        shifts = rng.normal(0.0, spread, (REPS, replicates, 1))
        draws = shifts + rng.standard_t(5, (REPS, replicates, runs)) * 0.3  # heavy-tailed runs
        above = below = 0
        for repetition in draws:
            result = replicate_t_means(list(repetition), ALPHA)
            above, below = above + bool(result.low > 0), below + bool(result.high < 0)
        assert upper(above) < ALPHA and upper(below) < ALPHA, (replicates, runs, spread, above, below)


def test_a_margin_claim_is_decided_from_the_replicates_means():
    rng = np.random.default_rng(3)
    ahead = {r: rng.normal(0.3, 0.1, 20) for r in range(8)}  # A keeps 0.3 more of its lane than B, every replicate
    (result,) = decide_claims([MarginClaim("A vs B margin", ahead, margin=0.1)], 0.05)
    assert result.verdict == Verdict.SUPPORTED and result.replicates == tuple(range(8))
    level = [MarginClaim("same", {r: rng.normal(0.0, 0.01, 20) for r in range(8)}, margin=0.1)]
    assert decide_claims(level, 0.05)[0].verdict == Verdict.EQUIVALENT
    with pytest.raises(ValueError, match="at least two finite paired differences"):
        replicate_t_means([np.array([0.1]), np.array([0.2, 0.3])], 0.05)
