"""Findings over replicates: the sign rule, Holm over the family, and the rule's type-I error and interval coverage
computed exactly by enumerating every pair of replicate tables with its trinomial probability (here, not in the
code under test)."""

import itertools
import math

import numpy as np
import pytest

from uqdrive.uq.findings import Comparison, decide_findings
from uqdrive.uq.multiplicity import holm
from uqdrive.uq.paired import PairedTable, stratified_p


def test_a_finding_whose_replicates_disagree_in_sign_is_not_supported():
    disagree = Comparison(
        "mcd vs vi in fog", {0: PairedTable(50, 10, 0), 1: PairedTable(50, 12, 1), 2: PairedTable(50, 0, 2)}
    )
    tie = Comparison(
        "mcd vs hmc in fog", {0: PairedTable(50, 10, 0), 1: PairedTable(50, 12, 1), 2: PairedTable(50, 1, 1)}
    )
    first, second = decide_findings([disagree, tie], alpha=0.05)
    assert first.significant and not first.consistent and not first.supported
    assert first.agreeing == (0, 1) and first.opposing == (2,) and first.replicates == (0, 1, 2)
    assert first.effect == pytest.approx((22 - 3) / 150) and first.low <= first.effect <= first.high
    # a replicate with no difference neither contradicts nor supports
    assert second.supported and second.agreeing == (0, 1) and second.opposing == ()


def test_findings_are_decided_by_holm_over_the_whole_family():
    tables = [PairedTable(40, 9, 1), PairedTable(40, 7, 1), PairedTable(40, 3, 0), PairedTable(40, 2, 2)]
    family = [Comparison(f"c{i}", {0: t}) for i, t in enumerate(tables)]
    result = decide_findings(family, alpha=0.05)
    raw = [stratified_p([t]) for t in tables]
    assert [f.p_value for f in result] == raw and [f.adjusted_p for f in result] == pytest.approx(holm(raw))
    # c1's raw p (0.070) is above 0.05 already; c0 (0.021) survives alone but not as one of four (0.086)
    assert [f.significant for f in result] == [False] * 4 and raw[0] < 0.05
    alone = decide_findings(family[:1], alpha=0.05)[0]
    assert alone.significant and alone.supported
    with pytest.raises(ValueError, match="at least one comparison"):
        decide_findings([Comparison("empty", {})], alpha=0.05)


def trinomial(n: int, p_a: float, p_b: float) -> dict[tuple[int, int], float]:
    """P(a_only, b_only) for n pairs with P(only A safe) = p_a, P(only B safe) = p_b."""
    return {
        (a, b): math.comb(n, a) * math.comb(n - a, b) * p_a**a * p_b**b * (1 - p_a - p_b) ** (n - a - b)
        for a in range(n + 1)
        for b in range(n + 1 - a)
    }


def enumerate_findings(n: int, rates: list[tuple[float, float]], alpha: float):
    """Every pair of replicate tables, its exact probability and the finding `findings` makes of it."""
    for cells in itertools.product(*(trinomial(n, *r).items() for r in rates)):
        tables = {r: PairedTable(n, a, b) for r, ((a, b), _) in enumerate(cells)}
        yield math.prod(p for _, p in cells), decide_findings([Comparison("a vs b", tables)], alpha)[0]


@pytest.mark.parametrize("rates", [[(0.1, 0.1), (0.3, 0.3)], [(0.02, 0.02), (0.45, 0.45)]])
def test_the_combination_rule_rejects_a_true_null_with_probability_at_most_alpha_exactly(rates):
    """No difference in either replicate, with different discordance per replicate: every table pair is summed."""
    significant = supported = 0.0
    for p, finding in enumerate_findings(10, rates, 0.05):
        significant += p * finding.significant
        supported += p * finding.supported
    assert supported <= significant <= 0.05


def test_the_stratified_test_alone_is_exact_for_three_replicates():
    """The pooled discordant counts' distribution by convolving three replicates' trinomials (here)."""
    n, alpha, rates = 12, 0.05, [(0.05, 0.05), (0.2, 0.2), (0.4, 0.4)]
    pooled = {(0, 0): 1.0}
    for r in rates:
        step: dict[tuple[int, int], float] = {}
        for (a, b), p in pooled.items():
            for (da, db), q in trinomial(n, *r).items():
                step[a + da, b + db] = step.get((a + da, b + db), 0.0) + p * q
        pooled = step
    level = sum(p for (a, b), p in pooled.items() if stratified_p([PairedTable(3 * n, a, b)]) <= alpha)
    assert 0.02 < level <= alpha


def test_the_finding_interval_covers_the_pooled_difference_exactly():
    rates = [(0.3, 0.05), (0.1, 0.15)]  # differences 0.25 and −0.05: the pooled one is their mean, 0.1
    delta = float(np.mean([a - b for a, b in rates]))
    miss = sum(p for p, f in enumerate_findings(10, rates, 0.05) if not f.low <= delta <= f.high)
    assert miss <= 0.05
