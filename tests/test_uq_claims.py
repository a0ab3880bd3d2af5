"""Method claims across training runs: each verdict's error and the mean interval's misses by simulation, 10,000
repetitions a design, at a claim's level 0.05 and at the paper family's (0.05 over 10 claims: 0.005), the 95 %
Clopper–Pearson upper limit of each error below its stated level (level/2 per verdict kind and per end) — under
uniform and Beta spreads of training runs, rates piled at 0 or 1, training runs that fail outright with probability
0.05 and 0.1, and bimodal runs; at the equivalence margin ±δ as well as for superiority. A mutant deciding by
Student's t fails them; the sign test's and Hoeffding's planning counts are checked by exact sums."""

import math

import numpy as np
import pytest
from scipy import special, stats

from uqdrive.uq.betting import mean_interval
from uqdrive.uq.claims import (
    MethodClaim,
    ScoreClaim,
    decide_claim,
    decide_claims,
    equivalence_runs_needed,
    sign_runs_needed,
)
from uqdrive.uq.paired import PairedTable
from uqdrive.uq.verdict import Reason, Verdict

REPS, MARGIN, RUNS = 10_000, 0.1, 10
LEVELS = (0.05, 0.005)


def upper(count: int, reps: int = REPS) -> float:
    """Top of the 95 % Clopper–Pearson interval of a simulated rate."""
    return float(stats.beta.ppf(0.975, count + 1, reps - count)) if count < reps else 1.0


def beta(mean: float, concentration: float):
    return lambda rng, size: rng.beta(concentration * mean, concentration * (1 - mean), size)


def fails(probability: float, otherwise: float = 1.0):
    """A training run that fails outright (rate 0) with ``probability``, else drives at rate ``otherwise``."""
    return lambda rng, size: np.where(rng.random(size) < probability, 0.0, otherwise)


def bimodal(low: float, high: float, share_low: float):
    return lambda rng, size: np.where(rng.random(size) < share_low, low, high)


def constant(rate: float):
    return lambda rng, size: np.full(size, rate)


# Designs where A and B are exchangeable: P(A's run higher) = ½ and the mean difference 0, both exactly.
SPREADS = {
    "uniform": lambda rng, size: rng.uniform(size=size),
    "beta 0.9, κ 2": beta(0.9, 2),
    "piled at 1": beta(0.97, 2),
    "piled at 0": beta(0.03, 2),
    "fails outright 0.05": fails(0.05),
    "fails outright 0.1": fails(0.1, 0.95),
    "bimodal": bimodal(0.34, 1.0, 0.3),
}


def differences(rng, a, b, n: int, runs: int = RUNS) -> np.ndarray:
    """Each replicate's paired η̂_A − η̂_B from n rollouts a side: [REPS, runs]."""
    eta_a, eta_b = a(rng, (REPS, runs)), b(rng, (REPS, runs))
    return (rng.binomial(n, eta_a) - rng.binomial(n, eta_b)) / n


def sign_verdicts(diffs: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """SUPPORTED and REFUTED of every repetition, through `decide_claim`'s own sign test on each."""
    ahead, behind = np.sum(diffs > 0, -1), np.sum(diffs < 0, -1)
    tail = special.bdtrc(np.maximum(ahead, behind) - 1, ahead + behind, 0.5)
    rejects = (ahead + behind > 0) & (np.minimum(1, 2 * tail) <= level)
    return rejects & (ahead > behind), rejects & (behind > ahead)


def test_sign_verdicts_here_are_decide_claims():
    """The vectorised reading above and `decide_claim` agree on 2,000 random replicate sets."""
    rng = np.random.default_rng(0)
    for _ in range(2_000):
        runs, n = int(rng.integers(2, 12)), int(rng.integers(5, 40))
        a, b = rng.integers(0, n + 1, runs), rng.integers(0, n + 1, runs)
        tables = {r: PairedTable(n, max(0, x - y), max(0, y - x)) for r, (x, y) in enumerate(zip(a, b))}
        level = float(rng.choice([0.05, 0.005, 0.3]))
        result = decide_claim(MethodClaim("c", tables, MARGIN), level)
        supported, refuted = sign_verdicts(np.array([[t.effect for t in tables.values()]]), level)
        assert (result.verdict is Verdict.SUPPORTED) == bool(supported[0])
        assert (result.verdict is Verdict.REFUTED) == bool(refuted[0])


@pytest.mark.parametrize("level", LEVELS)
@pytest.mark.parametrize("spread", list(SPREADS))
@pytest.mark.parametrize("n", [29, 87])
def test_no_difference_is_rarely_called_one(level, spread, n):
    """A and B exchangeable: a SUPPORTED (or REFUTED) is false, and either end of the mean's interval past 0 is
    a miss; each at most level/2."""
    rng = np.random.default_rng([n, len(spread), int(level * 1000)])
    diffs = differences(rng, SPREADS[spread], SPREADS[spread], n)
    supported, refuted = sign_verdicts(diffs, level)
    mean = mean_interval(diffs, -1.0, 1.0, level)
    counts = [int(supported.sum()), int(refuted.sum()), int(np.sum(mean.low > 0)), int(np.sum(mean.high < 0))]
    assert max(upper(c) for c in counts) < level / 2, counts


# Skewed designs: (A's runs, B's runs, the mean difference)
SKEWED = {
    # A's run fails outright 1 in 20, else never fails; B's always 0.95: the mean difference is 0, A's run the
    # higher most of the time (so SUPPORTED is right for the sign estimand; the mean's interval must hold 0)
    "A fails outright 0.05, B 0.95": (fails(0.05), constant(0.95), 0.0),
}


@pytest.mark.parametrize("level", LEVELS)
def test_a_run_that_fails_outright_leaves_the_mean_interval_valid(level):
    a, b, truth = SKEWED["A fails outright 0.05, B 0.95"]
    diffs = differences(np.random.default_rng(5), a, b, 29)
    mean = mean_interval(diffs, -1.0, 1.0, level)
    counts = int(np.sum(mean.low > truth)), int(np.sum(mean.high < truth))
    assert max(upper(c) for c in counts) < level / 2, counts


@pytest.mark.parametrize("level", LEVELS)
def test_the_sign_test_holds_where_the_mean_and_the_median_part(level):
    """Per training run: A safe and B not (+1) with probability 0.4; else A at 0.95, B at 1 (A's η̂ lower or
    tied). P(A higher | differ) = 0.4 / (0.4 + 0.6 (1 − 0.95^29)) < ½ while the mean difference is +0.37: a
    SUPPORTED is false for the sign estimand, and the mean's interval must still cover +0.37."""
    rng = np.random.default_rng(9)
    first = rng.random((REPS, RUNS)) < 0.4
    eta_a, eta_b = np.where(first, 1.0, 0.95), np.where(first, 0.0, 1.0)
    diffs = (rng.binomial(29, eta_a) - rng.binomial(29, eta_b)) / 29
    supported, _ = sign_verdicts(diffs, level)
    truth = 0.4 - 0.6 * 0.05
    mean = mean_interval(diffs, -1.0, 1.0, level)
    counts = [int(supported.sum()), int(np.sum(mean.low > truth)), int(np.sum(mean.high < truth))]
    assert max(upper(c) for c in counts) < level / 2, counts


def equivalent(diffs: np.ndarray, level: float) -> np.ndarray:
    """EQUIVALENT as `decide_claim` reads it (the sign test decided nothing, the mean's interval in ±δ)."""
    supported, refuted = sign_verdicts(diffs, level)
    mean = mean_interval(diffs, -1.0, 1.0, level)
    return ~supported & ~refuted & (mean.low > -MARGIN) & (mean.high < MARGIN)


# Designs whose mean difference is exactly the margin δ = 0.1 (or −δ): EQUIVALENT is false there.
AT_MARGIN = {
    "B fails outright 0.1, A never": (constant(1.0), fails(0.1), 0.1),
    "A fails outright 0.1, B never": (fails(0.1), constant(1.0), -0.1),
    "beta spreads 0.95 and 0.85, κ 2": (beta(0.95, 2), beta(0.85, 2), 0.1),
    "bimodal B": (constant(0.9), bimodal(0.6, 0.9, 1 / 3), 0.1),
}


@pytest.mark.parametrize("level", LEVELS)
@pytest.mark.parametrize("design", list(AT_MARGIN))
@pytest.mark.parametrize("runs", [10, 200])
def test_a_difference_at_the_margin_is_rarely_called_equivalent(level, design, runs):
    """With 200 runs the interval is narrow enough to call equivalence often nearer 0, so these designs test it
    where it could err; with 10 it never can."""
    a, b, _ = AT_MARGIN[design]
    diffs = differences(np.random.default_rng([runs, len(design)]), a, b, 29, runs)
    count = int(equivalent(diffs, level).sum())
    assert upper(count) < level / 2, count


def test_equivalence_is_reached_with_enough_alike_runs():
    """The check above is not vacuous: 200 runs of two alike methods (rates near 0.97) decide equivalence
    within ±0.1 in most repetitions at 0.005."""
    same = beta(0.97, 50)
    diffs = differences(np.random.default_rng(2), same, same, 87, 200)
    assert equivalent(diffs, 0.005).mean() > 0.5


def students_t(diffs: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """The mutant: Student's t interval across the runs, as the claims used before."""
    mean, sd = diffs.mean(-1), diffs.std(-1, ddof=1)
    half = stats.t.ppf(1 - level / 2, diffs.shape[-1] - 1) * sd / math.sqrt(diffs.shape[-1])
    return mean - half, mean + half


def test_a_students_t_mutant_fails_these_checks():
    """The same designs under the t: its "mean above 0" where A's run fails outright 1 in 20, and its
    equivalence at the margin where B's fails outright 1 in 10, far above level/2."""
    a, b, truth = SKEWED["A fails outright 0.05, B 0.95"]
    diffs = differences(np.random.default_rng(5), a, b, 29)
    low, _ = students_t(diffs, 0.005)
    assert stats.beta.ppf(0.025, int(np.sum(low > truth)), REPS) > 0.0025
    a, b, _ = AT_MARGIN["B fails outright 0.1, A never"]
    diffs = differences(np.random.default_rng(6), a, b, 29)
    low, high = students_t(diffs, 0.005)
    false_equivalent = int(np.sum((low > -MARGIN) & (high < MARGIN)))
    assert stats.beta.ppf(0.025, false_equivalent, REPS) > 0.0025


def claim(effects: list[tuple[int, int]], n: int = 50) -> MethodClaim:
    return MethodClaim("a safer than b", {r: PairedTable(n, a, b) for r, (a, b) in enumerate(effects)}, MARGIN)


def test_ten_agreeing_runs_decide_a_claim_and_nine_of_ten_do_not_at_the_paper_level():
    agreeing = decide_claim(claim([(5, 0)] * 10), 0.005)
    assert agreeing.verdict is Verdict.SUPPORTED and agreeing.ahead == 10 and agreeing.behind == 0
    assert agreeing.p_value == pytest.approx(2 / 1024) and agreeing.share_low > 0.5
    assert agreeing.differing_runs_needed is None and agreeing.equivalence_runs_needed is None
    nine = decide_claim(claim([(5, 0)] * 9 + [(0, 3)]), 0.005)
    assert nine.verdict is Verdict.UNDECIDED and nine.reason is Reason.NOT_DECIDED
    assert nine.p_value == pytest.approx(2 * 11 / 1024) and nine.share_low <= 0.5 <= nine.share_high
    assert nine.differing_runs_needed == sign_runs_needed(0.005) and nine.equivalence_runs_needed > 1000
    refuted = decide_claim(claim([(0, 4)] * 10), 0.005)
    assert refuted.verdict is Verdict.REFUTED and refuted.share_high < 0.5
    alike = decide_claim(claim([(0, 0)] * 10), 0.005)
    assert alike.verdict is Verdict.UNDECIDED and alike.low < -0.4 and alike.high > 0.4  # ten runs bound no mean
    assert decide_claim(claim([(3, 0)]), 0.05).reason is Reason.TOO_FEW_REPLICATES


def test_a_family_puts_each_claim_at_alpha_over_m():
    claims = [claim([(5, 0)] * 10), claim([(0, 0)] * 10)]
    first, second = decide_claims(claims, 0.05)
    assert first.level == second.level == pytest.approx(0.025) and first.verdict is Verdict.SUPPORTED
    assert first.assumption == "none beyond i.i.d. training runs" and "P(a run of A" in first.estimand
    with pytest.raises(ValueError, match="at least one claim"):
        decide_claims([], 0.05)


def test_a_score_claim_is_decided_by_the_sign_test_alone():
    wider = ScoreClaim("vi keeps a wider margin", {r: np.array([0.3, 0.1, 0.2]) for r in range(10)}, MARGIN)
    result = decide_claim(wider, 0.005)
    assert result.verdict is Verdict.SUPPORTED and result.low is None and result.high is None
    assert result.estimate == pytest.approx(0.2) and "mean over training runs" not in result.estimand
    level = decide_claim(ScoreClaim("alike", {r: np.zeros(3) for r in range(10)}, MARGIN), 0.005)
    assert level.verdict is Verdict.UNDECIDED and level.equivalence_runs_needed is None  # never equivalent


@pytest.mark.parametrize("level", LEVELS)
def test_the_sign_tests_runs_needed_reach_the_power_and_one_fewer_does_not(level):
    """Exact binomial sums, written here: the critical count, then the power at a share of 0.9."""

    def power(m: int) -> float:
        critical = next((k for k in range(m + 1) if 2 * stats.binom.sf(k - 1, m, 0.5) <= level), None)
        return 0.0 if critical is None else float(stats.binom.sf(critical - 1, m, 0.9))

    needed = sign_runs_needed(level)
    assert power(needed) >= 0.8 and all(power(m) < 0.8 for m in range(1, needed))


def test_hoeffdings_runs_decide_equivalence_whatever_the_spread():
    """At the runs needed, the widest spread on [−1, 1] (runs at ±1, mean 0) keeps Hoeffding's interval inside
    ±δ with probability ≥ 0.8 by Hoeffding's own bound; the number grows as 1/δ²."""
    runs = equivalence_runs_needed(0.1, 0.005)
    half = math.sqrt(2 * math.log(2 / 0.005) / runs)
    excursion = 0.1 - half
    assert excursion > 0 and 2 * math.exp(-runs * excursion**2 / 2) <= 0.2
    assert equivalence_runs_needed(0.2, 0.005) == pytest.approx(runs / 4, rel=0.01)
