"""Method claims across training runs: each verdict's error by simulation, 10,000 repetitions a design, at a claim's
level 0.05 and at 0.005, the 95 % Clopper–Pearson upper limit of each error below its stated level (level/2 per
verdict kind) — for the mean verdicts (the headline: `mean_verdicts`, the procedure `decide_claim` runs) and for the
sign verdicts, under uniform and Beta spreads of training runs, rates piled at 0 or 1, training runs that fail
outright with probability 0.05 and 0.1, and bimodal runs; at the equivalence margin ±δ as well as for superiority;
and where the means are equal but q ≠ ½ (there the sign test's verdict, read for the mean, is wrong most of the
time; the mean's is not). A mutant deciding by Student's t fails them; the sign test's planning count is checked by
exact sums; the family's split of α by exact sums. About 6 s of CPU."""

import math
from fractions import Fraction

import numpy as np
import pytest
from scipy import special, stats

from uqdrive.uq.claims import (
    CODES,
    MethodClaim,
    ScoreClaim,
    decide_claim,
    decide_claims,
    family_levels,
    mean_verdicts,
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


def mean_calls(diffs: np.ndarray, level: float, margin: float = MARGIN) -> dict[Verdict, np.ndarray]:
    codes = mean_verdicts(diffs, level, margin)
    return {v: codes == i for i, v in enumerate(CODES)}


def test_verdicts_here_are_decide_claims_and_its_interval():
    """The vectorised readings above and `decide_claim` agree on 1,500 random replicate sets; the mean verdict is
    exactly where the reported interval lies (above 0, below, inside ±δ)."""
    rng = np.random.default_rng(0)
    for _ in range(1_500):
        runs, n = int(rng.integers(2, 40)), int(rng.integers(5, 40))
        a, b = rng.integers(0, n + 1, runs), rng.integers(0, n + 1, runs)
        if rng.random() < 0.5:  # alike runs: where equivalence can be decided
            b = np.clip(a + rng.integers(-1, 2, runs), 0, n)
        tables = {r: PairedTable(n, max(0, x - y), max(0, y - x)) for r, (x, y) in enumerate(zip(a, b))}
        level = float(rng.choice([0.05, 0.005, 0.3]))
        result = decide_claim(MethodClaim("c", tables, MARGIN), level, level)
        diffs = np.array([[t.effect for t in tables.values()]])
        supported, refuted = sign_verdicts(diffs, level)
        assert (result.sign_verdict is Verdict.SUPPORTED) == bool(supported[0])
        assert (result.sign_verdict is Verdict.REFUTED) == bool(refuted[0])
        assert result.verdict is CODES[int(mean_verdicts(diffs, level, MARGIN)[0])]
        read = (
            Verdict.SUPPORTED
            if result.low > 0
            else Verdict.REFUTED
            if result.high < 0
            else Verdict.EQUIVALENT
            if -MARGIN < result.low and result.high < MARGIN
            else Verdict.UNDECIDED
        )
        assert result.verdict is read, (result.low, result.high, result.verdict)


@pytest.mark.parametrize("level", LEVELS)
@pytest.mark.parametrize("spread", list(SPREADS))
@pytest.mark.parametrize("n", [29, 87])
def test_no_difference_is_rarely_called_one(level, spread, n):
    """A and B exchangeable: a SUPPORTED or REFUTED is false for the mean and for q; each at most level/2."""
    rng = np.random.default_rng([n, len(spread), int(level * 1000)])
    diffs = differences(rng, SPREADS[spread], SPREADS[spread], n)
    supported, refuted = sign_verdicts(diffs, level)
    calls = mean_calls(diffs, level)
    counts = [int(supported.sum()), int(refuted.sum()), int(calls[Verdict.SUPPORTED].sum())]
    counts.append(int(calls[Verdict.REFUTED].sum()))
    assert max(upper(c) for c in counts) < level / 2, counts


@pytest.mark.parametrize("level", LEVELS)
@pytest.mark.parametrize("runs", [10, 20, 200])
def test_equal_means_with_q_above_half_are_not_called_safer_for_the_mean(level, runs):
    """A's run fails outright 1 in 20, else is always safe; B's is safe 0.95 per rollout; n 75. The means are equal
    (0.95), but A's run wins most pairs that differ (q ≈ 0.95), so the sign test supports "A safer" nearly always —
    read for the mean it would be wrong. The mean verdict is wrong (SUPPORTED or REFUTED) at most level/2 each."""
    diffs = differences(np.random.default_rng([runs, 5]), fails(0.05), constant(0.95), 75, runs)
    calls = mean_calls(diffs, level)
    counts = int(calls[Verdict.SUPPORTED].sum()), int(calls[Verdict.REFUTED].sum())
    assert max(upper(c) for c in counts) < level / 2, counts
    if runs == 20:
        supported, _ = sign_verdicts(diffs, level)
        assert supported.mean() > 0.5  # the sign test's verdict, read for the mean, wrong most of the time


@pytest.mark.parametrize("level", LEVELS)
def test_the_sign_test_holds_where_the_mean_and_the_median_part(level):
    """Per training run: A safe and B not (+1) with probability 0.4; else A at 0.95, B at 1 (A's η̂ lower or
    tied). P(A higher | differ) = 0.4 / (0.4 + 0.6 (1 − 0.95^29)) < ½ while the mean difference is +0.37: a
    sign SUPPORTED is false for q, and a mean REFUTED false for the mean."""
    rng = np.random.default_rng(9)
    first = rng.random((REPS, RUNS)) < 0.4
    eta_a, eta_b = np.where(first, 1.0, 0.95), np.where(first, 0.0, 1.0)
    diffs = (rng.binomial(29, eta_a) - rng.binomial(29, eta_b)) / 29
    supported, _ = sign_verdicts(diffs, level)
    calls = mean_calls(diffs, level)
    counts = [int(supported.sum()), int(calls[Verdict.REFUTED].sum())]
    assert max(upper(c) for c in counts) < level / 2, counts


# Designs whose mean difference is exactly the margin δ = 0.1 (or −δ): EQUIVALENT is false there; so is a
# verdict on the wrong side of 0.
AT_MARGIN = {
    "B fails outright 0.1, A never": (constant(1.0), fails(0.1), 0.1),
    "A fails outright 0.1, B never": (fails(0.1), constant(1.0), -0.1),
    "beta spreads 0.95 and 0.85, κ 2": (beta(0.95, 2), beta(0.85, 2), 0.1),
    "bimodal B": (constant(0.9), bimodal(0.6, 0.9, 1 / 3), 0.1),
    "piled at 0, B fails outright 0.1": (
        beta(0.03, 2),
        lambda rng, size: np.where(rng.random(size) < 0.1, 0.0, beta(0.03 / 0.9, 2)(rng, size)),
        0.0,
    ),
}


@pytest.mark.parametrize("level", LEVELS)
@pytest.mark.parametrize("design", list(AT_MARGIN))
@pytest.mark.parametrize("runs", [10, 200])
def test_a_difference_at_the_margin_is_rarely_called_equivalent(level, design, runs):
    """With 200 runs the interval is narrow enough to call equivalence often nearer 0, so these designs test it
    where it could err; with 10 it never can."""
    a, b, truth = AT_MARGIN[design]
    diffs = differences(np.random.default_rng([runs, len(design)]), a, b, 29, runs)
    calls = mean_calls(diffs, level)
    wrong = [int(calls[Verdict.REFUTED if truth >= 0 else Verdict.SUPPORTED].sum())]
    if abs(truth) >= MARGIN:
        wrong.append(int(calls[Verdict.EQUIVALENT].sum()))
    assert max(upper(c) for c in wrong) < level / 2, wrong


def test_equivalence_is_reached_with_enough_alike_runs():
    """The check above is not vacuous: 200 runs of two alike methods (rates near 0.97) decide equivalence
    within ±0.1 in most repetitions at 0.005."""
    same = beta(0.97, 50)
    diffs = differences(np.random.default_rng(2), same, same, 87, 200)
    assert mean_calls(diffs, 0.005)[Verdict.EQUIVALENT].mean() > 0.5


def students_t(diffs: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """The mutant: Student's t interval across the runs, as the claims used before."""
    mean, sd = diffs.mean(-1), diffs.std(-1, ddof=1)
    half = stats.t.ppf(1 - level / 2, diffs.shape[-1] - 1) * sd / math.sqrt(diffs.shape[-1])
    return mean - half, mean + half


def test_a_students_t_mutant_fails_these_checks():
    """The same designs under the t: its "mean above 0" where A's run fails outright 1 in 20, and its
    equivalence at the margin where B's fails outright 1 in 10, far above level/2."""
    diffs = differences(np.random.default_rng(5), fails(0.05), constant(0.95), 29)
    low, _ = students_t(diffs, 0.005)
    assert stats.beta.ppf(0.025, int(np.sum(low > 0)), REPS) > 0.0025
    a, b, _ = AT_MARGIN["B fails outright 0.1, A never"]
    diffs = differences(np.random.default_rng(6), a, b, 29)
    low, high = students_t(diffs, 0.005)
    false_equivalent = int(np.sum((low > -MARGIN) & (high < MARGIN)))
    assert stats.beta.ppf(0.025, false_equivalent, REPS) > 0.0025


def claim(effects: list[tuple[int, int]], n: int = 50) -> MethodClaim:
    return MethodClaim("a safer than b", {r: PairedTable(n, a, b) for r, (a, b) in enumerate(effects)}, MARGIN)


def test_ten_agreeing_runs_decide_q_and_not_the_mean_at_the_paper_level():
    agreeing = decide_claim(claim([(5, 0)] * 10), 0.0025, 0.005)
    assert agreeing.sign_verdict is Verdict.SUPPORTED and agreeing.ahead == 10 and agreeing.behind == 0
    assert agreeing.p_value == pytest.approx(2 / 1024) and agreeing.share_low > 0.5
    assert agreeing.differing_runs_needed is None and agreeing.rollouts == 50
    assert agreeing.verdict is Verdict.UNDECIDED and agreeing.reason is Reason.NOT_DECIDED and agreeing.low < 0
    forty = decide_claim(claim([(25, 0)] * 40), 0.0025, 0.005)
    assert forty.verdict is Verdict.SUPPORTED and forty.low > 0 and forty.reason is Reason.DECIDED
    nine = decide_claim(claim([(5, 0)] * 9 + [(0, 3)]), 0.0025, 0.005)
    assert nine.sign_verdict is Verdict.UNDECIDED and nine.differing_runs_needed == sign_runs_needed(0.005)
    assert nine.p_value == pytest.approx(2 * 11 / 1024) and nine.share_low <= 0.5 <= nine.share_high
    refuted = decide_claim(claim([(0, 25)] * 40), 0.0025, 0.005)
    assert refuted.verdict is Verdict.REFUTED and refuted.sign_verdict is Verdict.REFUTED
    alike = decide_claim(claim([(0, 0)] * 10), 0.0025, 0.005)
    assert alike.verdict is Verdict.UNDECIDED and alike.low < -0.4 and alike.high > 0.4  # ten runs bound no mean
    assert decide_claim(claim([(3, 0)]), 0.05, 0.05).reason is Reason.TOO_FEW_REPLICATES


@pytest.mark.parametrize("m", [1, 3, 10, 49])
def test_a_family_splits_alpha_between_the_estimands_and_holds_at_alpha_exactly(m):
    """The m mean verdicts and the m sign verdicts: 2m intervals whose levels sum (exactly, as stored) to at most α,
    so the union bound gives family-wise error ≤ α over both estimands, in every corner (q = ½ with |Δ| ≥ δ too)."""
    claims = [claim([(5, 0)] * 10)] * m
    mean, sign = family_levels(0.05, claims)
    assert Fraction(mean) * m + Fraction(sign) * m <= Fraction(0.05)
    assert mean == pytest.approx(0.025 / m) and sign == pytest.approx(0.025 / m)
    first = decide_claims(claims, 0.05)[0]
    assert (first.level, first.sign_level, first.alpha) == (mean, sign, 0.05)
    assert first.assumption == "none beyond i.i.d. training runs" and first.estimand.startswith("mean over")
    assert "rollouts per run" in first.sign_estimand
    with pytest.raises(ValueError, match="at least one claim"):
        decide_claims([], 0.05)


def test_a_score_claim_carries_the_sign_verdict_alone_with_the_whole_alpha():
    wider = ScoreClaim("vi keeps a wider margin", {r: np.array([0.3, 0.1, 0.2]) for r in range(10)}, MARGIN)
    (result,) = decide_claims([wider], 0.005)
    assert result.sign_verdict is Verdict.SUPPORTED and result.sign_level == pytest.approx(0.005)
    assert result.verdict is Verdict.UNDECIDED and result.reason is Reason.NO_BOUNDED_RANGE
    assert result.low is None and result.high is None and result.estimate == pytest.approx(0.2)
    assert result.runs_needed is None and result.runs_needed_worst is None


@pytest.mark.parametrize("level", LEVELS)
def test_the_sign_tests_runs_needed_reach_the_power_and_one_fewer_does_not(level):
    """Exact binomial sums, written here: the critical count, then the power at a share of 0.9."""

    def power(m: int) -> float:
        critical = next((k for k in range(m + 1) if 2 * stats.binom.sf(k - 1, m, 0.5) <= level), None)
        return 0.0 if critical is None else float(stats.binom.sf(critical - 1, m, 0.9))

    needed = sign_runs_needed(level)
    assert power(needed) >= 0.8 and all(power(m) < 0.8 for m in range(1, needed))
