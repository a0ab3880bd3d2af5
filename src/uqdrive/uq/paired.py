"""Exact paired comparison of two cells run on the same rollout seeds (exact McNemar test, the sign test's interval).

Rollout i of every cell uses seed base_seed + i, so cells A and B pair their 0/1 outcomes by seed. Only the
discordant pairs carry the difference: with ``a_only`` pairs where only A is safe and ``b_only`` where only B
is, the difference of rates is (a_only − b_only) / n, and under H0 "P(only A safe) = P(only B safe)"
a_only ~ Binomial(a_only + b_only, ½) given the discordant count, whatever the concordant pairs do. The
test is therefore exact for every n; the pairs must be independent of each other (distinct seeds) and the
number of pairs fixed before the outcomes were seen (not a sequential stopping time).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from scipy import special

from uqdrive.uq.bounds import check_unit, clopper_pearson_interval


@dataclasses.dataclass(frozen=True)
class PairedTable:
    """n paired outcomes of cells A and B: ``a_only`` pairs with only A safe, ``b_only`` with only B safe."""

    n: int
    a_only: int
    b_only: int

    def __post_init__(self) -> None:
        if self.n < 1 or self.a_only < 0 or self.b_only < 0 or self.a_only + self.b_only > self.n:
            raise ValueError(f"need n >= 1 and 0 <= a_only + b_only <= n, got {self}")

    @property
    def discordant(self) -> int:
        return self.a_only + self.b_only

    @property
    def effect(self) -> float:
        """η̂_A − η̂_B: the concordant pairs cancel."""
        return (self.a_only - self.b_only) / self.n


def paired_table(a: Sequence[bool] | np.ndarray, b: Sequence[bool] | np.ndarray) -> PairedTable:
    """The table of two cells' outcomes paired by position (rollout i of each uses the same seed)."""
    a, b = np.asarray(a, bool), np.asarray(b, bool)
    if a.shape != b.shape or a.ndim != 1 or a.size == 0:
        raise ValueError(f"paired outcomes need two equal, non-empty 1-d sequences, got shapes {a.shape}, {b.shape}")
    return PairedTable(int(a.size), int(np.sum(a & ~b)), int(np.sum(b & ~a)))


def sign_test_p(k: int, m: int) -> float:
    """Two-sided exact p-value of k successes in m fair coin flips: P(|X − m/2| ≥ |k − m/2|), X ~ Bin(m, ½).

    Bin(m, ½) is symmetric, so this is twice the smaller tail, capped at 1 (and 1 when m = 0).
    """
    if m == 0:
        return 1.0
    tail = min(special.bdtr(k, m, 0.5), special.bdtrc(k - 1, m, 0.5))  # P(X ≤ k), P(X ≥ k)
    return float(min(1.0, 2 * tail))


ABOVE_HALF, BELOW_HALF = float(np.nextafter(0.5, 1.0)), float(np.nextafter(0.5, 0.0))


def share_interval(a_only: int, discordant: int, level: float) -> tuple[float, float]:
    """Interval for π, the share of discordant pairs in which A alone is safe: the inversion of the exact test.

    The equal-tailed Clopper–Pearson interval at level 1 − ``level`` ([0, 1] without discordant pairs) holds
    the π the equal-tailed exact binomial test at ``level`` does not reject; at π = ½ that test is the sign
    test (`sign_test_p`). The end next to ½ is reconciled with the sign test's own p-value — the two agree but
    for rounding, and where the exact tail equals the level (the test rejects) the end is put one
    floating-point step past ½ — so the interval excludes ½ exactly when p ≤ ``level``.
    """
    if discordant == 0:
        return 0.0, 1.0
    low, high = (float(v) for v in clopper_pearson_interval(a_only, discordant, level))
    rejects = sign_test_p(a_only, discordant) <= level
    if 2 * a_only > discordant:
        low = max(low, ABOVE_HALF) if rejects else min(low, 0.5)
    elif 2 * a_only < discordant:
        high = min(high, BELOW_HALF) if rejects else max(high, 0.5)
    return low, high


def mcnemar_p(table: PairedTable) -> float:
    """Exact two-sided McNemar p-value: the sign test on the discordant pairs."""
    return sign_test_p(table.a_only, table.discordant)


def difference_interval(table: PairedTable, gamma: float) -> tuple[float, float]:
    """Interval for Δ = η_A − η_B with coverage ≥ 1 − ``gamma`` for every joint distribution of the pairs.

    Δ = d (2π − 1) with d = P(discordant) and π = P(only A safe | discordant). Two exact Clopper–Pearson
    intervals at level 1 − γ/2 each, d from discordant/n and π from a_only/discordant (conditionally exact
    given the discordant count; [0, 1] when there is none), hold together with probability ≥ 1 − γ (union
    bound); Δ's range over that rectangle (its corners, Δ being monotone in each) is the interval.
    Conservative by construction, never below its level.
    """
    gamma = check_unit("gamma", gamma)
    d_low, d_high = (float(v) for v in clopper_pearson_interval(table.discordant, table.n, gamma / 2))
    if table.discordant:
        pi_low, pi_high = (float(v) for v in clopper_pearson_interval(table.a_only, table.discordant, gamma / 2))
    else:
        pi_low, pi_high = 0.0, 1.0
    corners = [d * (2 * pi - 1) for d in (d_low, d_high) for pi in (pi_low, pi_high)]
    return min(corners), max(corners)


def non_inferior(table: PairedTable, margin: float, gamma: float) -> bool:
    """Is A worse than B by less than ``margin`` (Δ = η_A − η_B > −margin)? Declared when the lower end of
    `difference_interval` at level 1 − ``gamma`` lies above −margin. Wrongly declared (Δ ≤ −margin) only where the
    interval misses Δ, so with probability ≤ ``gamma`` for every joint law of the pairs; tests/test_uq_paired.py
    sums that error over every table at the boundary Δ = −margin."""
    if not 0 < margin <= 1:
        raise ValueError(f"margin must lie in (0, 1], got {margin}")
    return difference_interval(table, gamma)[0] > -margin


@dataclasses.dataclass(frozen=True)
class PairedTest:
    """One paired comparison: Δ̂ = η̂_A − η̂_B, its interval at level 1 − ``gamma``, the exact McNemar p-value."""

    table: PairedTable
    effect: float
    low: float
    high: float
    p_value: float
    gamma: float


def paired_test(table: PairedTable, gamma: float) -> PairedTest:
    low, high = difference_interval(table, gamma)
    return PairedTest(table, table.effect, low, high, mcnemar_p(table), float(gamma))
