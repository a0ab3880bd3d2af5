"""The exact paired test and its interval, checked against computations written here: the permutation distribution
of within-pair swaps enumerated with exact fractions, and the interval's coverage summed over every table."""

import itertools
import math
from fractions import Fraction

import numpy as np
import pytest

from uqdrive.uq.paired import (
    PairedTable,
    difference_interval,
    mcnemar_p,
    non_inferior,
    paired_table,
    paired_test,
)


def outcomes(table: PairedTable, both: int) -> tuple[list[int], list[int]]:
    """Paired 0/1 outcomes with the table's discordant pairs, ``both`` pairs safe in both, the rest in neither."""
    a = [1] * table.a_only + [0] * table.b_only + [1] * both
    b = [0] * table.a_only + [1] * table.b_only + [1] * both
    rest = table.n - len(a)
    return a + [0] * rest, b + [0] * rest


def swap_p(pairs: list[tuple[int, int]]) -> Fraction:
    """Two-sided p of Σ(a − b) under H0, by enumerating all 2^n within-pair swaps (each equally likely)."""
    observed = abs(sum(a - b for a, b in pairs))
    extreme = 0
    for swaps in itertools.product((False, True), repeat=len(pairs)):
        stat = sum((b - a) if s else (a - b) for (a, b), s in zip(pairs, swaps))
        extreme += abs(stat) >= observed
    return Fraction(extreme, 2 ** len(pairs))


@pytest.mark.parametrize(
    "table, both",
    [
        (PairedTable(12, 5, 0), 4),
        (PairedTable(12, 3, 3), 2),
        (PairedTable(12, 0, 0), 6),
        (PairedTable(14, 7, 2), 1),
        (PairedTable(10, 1, 6), 0),
        (PairedTable(13, 9, 4), 0),
    ],
)
def test_mcnemar_p_equals_the_enumerated_swap_distribution(table, both):
    a, b = outcomes(table, both)
    assert paired_table(a, b) == table
    assert mcnemar_p(table) == pytest.approx(float(swap_p(list(zip(a, b)))), abs=1e-12)


def test_p_value_convention_on_known_tables():
    assert mcnemar_p(PairedTable(20, 0, 0)) == 1.0 and mcnemar_p(PairedTable(20, 4, 4)) == 1.0
    assert mcnemar_p(PairedTable(20, 6, 0)) == pytest.approx(2 / 64)  # both tails: 2 · ½^6
    assert mcnemar_p(PairedTable(20, 1, 9)) == pytest.approx(2 * 11 / 1024)  # 2 · P(X ≤ 1), X ~ Bin(10, ½)


def exact_miss(n: int, p_a_only: float, p_b_only: float, gamma: float) -> float:
    """P(Δ outside the interval), summing the trinomial probability of every (a_only, b_only)."""
    delta, p_same = p_a_only - p_b_only, 1 - p_a_only - p_b_only
    miss = 0.0
    for a_only in range(n + 1):
        for b_only in range(n + 1 - a_only):
            low, high = difference_interval(PairedTable(n, a_only, b_only), gamma)
            if not low <= delta <= high:
                ways = math.comb(n, a_only) * math.comb(n - a_only, b_only)
                miss += ways * p_a_only**a_only * p_b_only**b_only * p_same ** (n - a_only - b_only)
    return miss


@pytest.mark.parametrize("n", [10, 30])
@pytest.mark.parametrize(
    "p_a_only, p_b_only", [(0.0, 0.0), (0.05, 0.0), (0.1, 0.1), (0.3, 0.05), (0.02, 0.4), (0.5, 0.5), (0.9, 0.05)]
)
def test_difference_interval_covers_with_probability_at_least_its_level_exactly(n, p_a_only, p_b_only):
    assert exact_miss(n, p_a_only, p_b_only, 0.05) <= 0.05


def exact_false_non_inferiority(n: int, p_a_only: float, p_b_only: float, margin: float, gamma: float) -> float:
    """P(A declared non-inferior), summing the trinomial probability of every (a_only, b_only) it is declared at."""
    p_same, declared = 1 - p_a_only - p_b_only, 0.0
    for a_only in range(n + 1):
        for b_only in range(n + 1 - a_only):
            if non_inferior(PairedTable(n, a_only, b_only), margin, gamma):
                ways = math.comb(n, a_only) * math.comb(n - a_only, b_only)
                declared += ways * p_a_only**a_only * p_b_only**b_only * p_same ** (n - a_only - b_only)
    return declared


@pytest.mark.parametrize("n", [14, 40, 120])
@pytest.mark.parametrize("margin", [0.05, 0.1, 0.2])
def test_non_inferiority_is_wrongly_declared_with_probability_at_most_gamma_at_every_boundary_law(n, margin):
    """At Δ = −margin (A worse by exactly the margin), over every joint law: the share of discordant pairs swept
    from the least it can be (only B safe) to all of them."""
    worst = 0.0
    for p_b_only in np.linspace(margin, 1.0, 19):
        p_a_only = p_b_only - margin
        if p_a_only + p_b_only <= 1:
            worst = max(worst, exact_false_non_inferiority(n, p_a_only, p_b_only, margin, 0.05))
    assert worst <= 0.05


def test_non_inferiority_is_declared_when_the_pairs_show_it_and_refuses_a_bad_margin():
    assert non_inferior(PairedTable(400, 0, 0), 0.05, 0.05)  # 400 concordant pairs: Δ ≥ −0.01 or so
    assert not non_inferior(PairedTable(14, 0, 0), 0.1, 0.05)  # 14 pairs cannot bound Δ above −0.1
    with pytest.raises(ValueError, match="margin"):
        non_inferior(PairedTable(14, 0, 0), 0.0, 0.05)


def test_paired_test_reports_effect_interval_and_p_and_refuses_bad_input():
    result = paired_test(paired_table(np.array([1, 1, 1, 0, 1]), np.array([0, 0, 1, 0, 1])), 0.1)
    assert result.table == PairedTable(5, 2, 0) and result.effect == 0.4 and result.p_value == 0.5
    assert -1 <= result.low <= result.effect <= result.high <= 1 and result.gamma == 0.1
    with pytest.raises(ValueError, match="two equal, non-empty 1-d sequences"):
        paired_table([1, 0], [1])
    with pytest.raises(ValueError, match="0 <= a_only \\+ b_only <= n"):
        PairedTable(3, 2, 2)
