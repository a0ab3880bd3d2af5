"""Controller-level findings over replicates: the agreement rule, Holm's levels, the interval that inverts each test,
and the test's size computed exactly here (every replicate table enumerated with its trinomial probability), both for
replicates on disjoint seed blocks (independent tables: exact) and on shared seeds (shared worlds: not)."""

import itertools
import math

import numpy as np
import pytest
from scipy import stats

from uqdrive.uq.family import Comparison, decide_findings, share_interval
from uqdrive.uq.multiplicity import holm
from uqdrive.uq.paired import PairedTable, stratified_p
from uqdrive.uq.verdict import Reason, Verdict


def test_a_finding_needs_every_replicate_to_show_a_difference_of_its_sign():
    disagree = {0: PairedTable(50, 10, 0), 1: PairedTable(50, 12, 1), 2: PairedTable(50, 0, 2)}
    silent = {0: PairedTable(50, 10, 0), 1: PairedTable(50, 12, 1), 2: PairedTable(50, 1, 1)}
    agree = {0: PairedTable(50, 10, 0), 1: PairedTable(50, 12, 1), 2: PairedTable(50, 2, 1)}
    first, second, third = decide_findings(
        [Comparison("mcd vs vi", disagree), Comparison("mcd vs hmc", silent), Comparison("vi vs hmc", agree)], 0.05
    )
    assert first.significant and not first.consistent and first.verdict is Verdict.UNDECIDED
    assert first.reason is Reason.REPLICATES_DISAGREE and first.agreeing == (0, 1) and first.opposing == (2,)
    assert first.effect == pytest.approx((22 - 3) / 150) and first.low <= first.effect <= first.high
    assert second.significant and second.reason is Reason.NO_DIFFERENCE_IN_A_REPLICATE and not second.supported
    assert third.supported and third.verdict == "supported" and third.reason == "" and third.consistent
    assert third.replicates == (0, 1, 2) and third.share == pytest.approx(24 / 26)


def test_findings_are_decided_by_holm_over_the_whole_family():
    tables = [PairedTable(40, 9, 1), PairedTable(40, 7, 1), PairedTable(40, 3, 0), PairedTable(40, 2, 2)]
    family = [Comparison(f"c{i}", {0: t}) for i, t in enumerate(tables)]
    result = decide_findings(family, alpha=0.05)
    raw = [stratified_p([t]) for t in tables]
    assert [f.p_value for f in result] == raw and [f.adjusted_p for f in result] == pytest.approx(holm(raw))
    # c0's raw p (0.021) is above 0.05 / 4, the level Holm grants it; every later one gets that level too
    assert [f.level for f in result] == [0.0125] * 4 and [f.significant for f in result] == [False] * 4
    assert [f.reason for f in result] == [Reason.NOT_SIGNIFICANT] * 4
    mixed = [PairedTable(40, 12, 0), PairedTable(40, 9, 0), PairedTable(40, 0, 8), PairedTable(40, 5, 2)]
    result = decide_findings([Comparison(f"m{i}", {0: t}) for i, t in enumerate(mixed)], alpha=0.05)
    # sorted p: 0.00049, 0.0039, 0.0078 (each within α / (m − j + 1)), then 0.45: each at the level Holm tested it
    assert [f.level for f in result] == pytest.approx([0.0125, 0.05 / 3, 0.025, 0.05])
    assert [f.significant for f in result] == [True, True, True, False]
    for finding, table in zip(result, mixed):
        expected = exact_cp(table.a_only, table.discordant, finding.level)
        assert (finding.share_low, finding.share_high) == pytest.approx(expected)
        assert (finding.low > 0 or finding.high < 0) == finding.significant
    alone = decide_findings(family[:1], alpha=0.05)[0]
    assert alone.level == 0.05 and alone.significant and alone.supported and alone.low > 0
    with pytest.raises(ValueError, match="at least one comparison"):
        decide_findings([Comparison("empty", {})], alpha=0.05)


def trinomial(n: int, p_a: float, p_b: float) -> dict[tuple[int, int], float]:
    """P(a_only, b_only) for n pairs with P(only A safe) = p_a, P(only B safe) = p_b."""
    return {
        (a, b): math.comb(n, a) * math.comb(n - a, b) * p_a**a * p_b**b * (1 - p_a - p_b) ** (n - a - b)
        for a in range(n + 1)
        for b in range(n + 1 - a)
    }


def tables(n: int) -> list[tuple[int, int]]:
    return [(a, b) for a in range(n + 1) for b in range(n + 1 - a)]


def exact_cp(k: int, m: int, level: float) -> tuple[float, float]:
    """Clopper–Pearson from the beta quantiles (scipy.stats), [0, 1] without trials."""
    if m == 0:
        return 0.0, 1.0
    low = stats.beta.ppf(level / 2, k, m - k + 1) if k > 0 else 0.0
    high = stats.beta.ppf(1 - level / 2, k + 1, m - k) if k < m else 1.0
    return low, high


def boundary_levels(p: float) -> list[float]:
    """A grid of levels, and the p-value itself with its floating-point neighbours (where the decision flips)."""
    grid = [0.01, 0.05, 0.2]
    return grid + ([p, float(np.nextafter(p, 0)), float(np.nextafter(p, 1))] if 0 < p < 1 else [])


@pytest.mark.parametrize("replicates, n", [(1, 12), (2, 5), (3, 3)])
def test_the_interval_excludes_zero_exactly_when_the_test_rejects_on_every_table(replicates, n):
    """Every tuple of replicate tables, at levels around its own p-value: the interval is the exact inversion."""
    for cells in itertools.product(tables(n), repeat=replicates):
        comparison = Comparison("a vs b", {r: PairedTable(n, a, b) for r, (a, b) in enumerate(cells)})
        a_only, discordant = sum(a for a, _ in cells), sum(a + b for a, b in cells)
        for level in boundary_levels(stratified_p(list(comparison.tables.values()))):
            finding = decide_findings([comparison], level)[0]
            assert finding.level == level and finding.significant == (finding.p_value <= level)
            assert (finding.share_low > 0.5 or finding.share_high < 0.5) == finding.significant, (cells, level)
            assert (finding.low > 0 or finding.high < 0) == finding.significant, (cells, level)
            assert (finding.share_low, finding.share_high) == pytest.approx(exact_cp(a_only, discordant, level))
            assert finding.low <= finding.effect <= finding.high


@pytest.mark.parametrize("level", [0.05, 0.2])
def test_the_share_interval_covers_a_common_share_at_its_level_exactly(level):
    """Two replicates with their own numbers of pairs and discordance, the same π = P(A alone | discordant): the
    pooled discordant count is the convolution of the replicates' binomials, A alone given it Bin(D, π); the miss
    probability summed over every (A, D), on a fine π grid and both sides of every interval end (where it jumps)."""
    pairs, discordance = (10, 14), (0.3, 0.6)
    law = np.convolve(*(stats.binom.pmf(np.arange(n + 1), n, d) for n, d in zip(pairs, discordance)))
    ends = {(a, d): share_interval(a, d, level) for d in range(sum(pairs) + 1) for a in range(d + 1)}
    jumps = np.array(list(ends.values())).ravel()
    shares = np.concatenate([np.linspace(0, 1, 1001), jumps - 1e-10, jumps + 1e-10])
    shares = shares[(shares >= 0) & (shares <= 1)]
    miss = np.zeros_like(shares)
    for (a, d), (low, high) in ends.items():
        miss += law[d] * stats.binom.pmf(a, d, shares) * ((shares < low) | (shares > high))
    assert level / 2 < miss.max() <= level


def pooled_size(decisions: dict, first: dict, second: dict | None) -> float:
    """P(significant) with replicate 1's table equal to replicate 0's (``second`` None: shared worlds) or drawn
    independently from ``second``."""
    if second is None:
        return sum(p * decisions[t, t] for t, p in first.items())
    return sum(p * q * decisions[s, t] for (s, p), (t, q) in itertools.product(first.items(), second.items()))


@pytest.fixture(scope="module")
def fourteen_pair_decisions() -> dict:
    """The finding's decision (alone in its family, α = 0.05) for every pair of two replicates' 14-pair tables."""
    return {
        (s, t): decide_findings([Comparison("a vs b", {0: PairedTable(14, *s), 1: PairedTable(14, *t)})], 0.05)[
            0
        ].significant
        for s, t in itertools.product(tables(14), repeat=2)
    }


def test_pooling_replicates_that_share_worlds_is_not_exact(fourteen_pair_decisions):
    """The null of the issue: each seed's world is "A alone safe in both replicates" or "B alone in both" with
    probability q/2 each, so A and B are equally safe in every replicate, but the replicates' tables coincide."""
    sizes = {q: pooled_size(fourteen_pair_decisions, trinomial(14, q / 2, q / 2), None) for q in (0.5, 1.0)}
    assert sizes[0.5] == pytest.approx(0.1310, abs=5e-5) and sizes[1.0] == pytest.approx(0.1796, abs=5e-5)


@pytest.mark.parametrize("q", [0.1, 0.25, 0.5, 0.75, 1.0])
def test_the_pooled_test_is_exact_for_replicates_on_disjoint_seeds(fourteen_pair_decisions, q):
    """The same per-replicate marginals, the replicates independent (disjoint seed blocks)."""
    cells = trinomial(14, q / 2, q / 2)
    assert pooled_size(fourteen_pair_decisions, cells, cells) <= 0.05


@pytest.mark.parametrize("rates", [[(0.1, 0.1), (0.3, 0.3)], [(0.02, 0.02), (0.45, 0.45)]])
def test_a_supported_finding_is_a_false_claim_with_probability_at_most_alpha_exactly(rates):
    """No difference in either replicate, with different discordance per replicate: every table pair is summed."""
    significant = supported = 0.0
    for (s, p), (t, q) in itertools.product(*(trinomial(10, *r).items() for r in rates)):
        finding = decide_findings([Comparison("a vs b", {0: PairedTable(10, *s), 1: PairedTable(10, *t)})], 0.05)[0]
        significant += p * q * finding.significant
        supported += p * q * finding.supported
    assert supported <= significant <= 0.05


def test_the_stratified_test_is_exact_for_three_distinct_replicates():
    """Three replicates with their own numbers of pairs and discordance, each table drawn independently: the
    probability that the test of all three tables rejects, summed over every triple of tables."""
    alpha, shapes = 0.05, [(4, 0.5), (7, 0.8), (9, 1.0)]  # (pairs, P(discordant)); half of each A alone
    laws = [trinomial(n, d / 2, d / 2) for n, d in shapes]
    level = 0.0
    for cells in itertools.product(*(law.items() for law in laws)):
        replicate_tables = [PairedTable(n, *t) for (n, _), (t, _) in zip(shapes, cells)]
        if stratified_p(replicate_tables) <= alpha:
            level += math.prod(p for _, p in cells)
    assert 0.025 < level <= alpha  # 0.0321
