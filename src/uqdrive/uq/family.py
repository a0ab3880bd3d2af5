"""A family of controller-level findings ("for these trained controllers"): paired comparisons over replicates, each
with an interval that covers what it names, decided with Bonferroni's correction.

A comparison ("MCD vs VI in fog", "warnings on vs off") pairs, for each replicate r, controller r's two cells run
on the same rollout seeds: pair i gives X_ri = safe_A − safe_B ∈ {−1, 0, 1}, with mean Δ_r = η_A,r − η_B,r.
Replicates drive disjoint seed blocks, so every pair is independent of every other.

**Estimand: the average gain over these R controllers**, Δ̄ = (1/R) Σ_r Δ_r, each controller weighted by the
same number of runs (the first k of each, k fixed in advance). Its interval is the betting interval for the mean
of the strata's means (`betting.mean_interval` with one block per rollout index: pair i of every controller),
valid for any gains the controllers have, however unlike: each end misses with probability ≤ level/2 (Ville's
inequality), which `tests/test_uq_family.py` measures by simulation for alike and unlike controllers, and exactly
by enumerating every sequence of small designs. SUPPORTED
"A is safer than B on average over these controllers" ⇔ the interval lies above 0 (B: below) ⇔ the betting test's
p ≤ level, by construction. More replicates give more runs to one interval, so more power.

Each of the family's m comparisons gets α/m (Bonferroni): with probability ≥ 1 − α every interval of the family
holds at once, under any dependence between comparisons (they share cells).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np

from uqdrive.uq.betting import mean_interval
from uqdrive.uq.bounds import check_unit
from uqdrive.uq.multiplicity import split_gamma
from uqdrive.uq.paired import PairedTable, paired_table
from uqdrive.uq.verdict import Reason, Verdict

ESTIMAND = "the average gain η_A − η_B over these trained controllers"


@dataclasses.dataclass(frozen=True)
class Comparison:
    """A vs B: ``outcomes[r]``: replicate r's two cells' 0/1 outcomes (A's, B's), paired by seed, in seed order."""

    name: str
    outcomes: Mapping[int, tuple[np.ndarray, np.ndarray]]

    def runs(self) -> int:
        """k: the runs each controller contributes (the fewest any has, so every controller weighs the same)."""
        return min(len(a) for a, _ in self.outcomes.values())

    def tables(self) -> dict[int, PairedTable]:
        k = self.runs()
        return {r: paired_table(a[:k], b[:k]) for r, (a, b) in self.outcomes.items()}

    def blocks(self) -> np.ndarray:
        """The paired differences in blocks of one per controller: pair 0 of every controller, then pair 1, …"""
        k = self.runs()
        diffs = [np.asarray(a[:k], float) - np.asarray(b[:k], float) for a, b in self.outcomes.values()]
        return np.stack(diffs, -1).reshape(-1)


@dataclasses.dataclass(frozen=True)
class Finding:
    """One comparison's outcome for these trained controllers: ``effect``, the average of the controllers'
    η̂_A − η̂_B over their first ``runs`` runs each; ``low``/``high``: its interval at level 1 − ``level``;
    ``p_value``: the betting test of "no gain on average" — supported ⇔ p ≤ level ⇔ the interval excludes 0;
    ``a_only``/``b_only``: per replicate, the runs where only A's, only B's was safe (its paired table of ``runs``)."""

    name: str
    effect: float
    low: float
    high: float
    p_value: float
    level: float
    supported: bool
    verdict: Verdict
    reason: Reason
    alpha: float
    runs: int
    replicates: tuple[int, ...]
    a_only: dict[int, int]
    b_only: dict[int, int]
    estimand: str = ESTIMAND


def decide_finding(comparison: Comparison, level: float, alpha: float) -> Finding:
    """One comparison decided at ``level`` (its share α/m of the family's α)."""
    interval = mean_interval(comparison.blocks(), -1.0, 1.0, level, block=len(comparison.outcomes))
    supported = bool(interval.p_value <= level)
    tables = comparison.tables()
    return Finding(
        comparison.name,
        float(interval.estimate),
        float(interval.low),
        float(interval.high),
        float(interval.p_value),
        float(level),
        supported,
        Verdict.SUPPORTED if supported else Verdict.UNDECIDED,
        Reason.DECIDED if supported else Reason.NOT_SIGNIFICANT,
        float(alpha),
        comparison.runs(),
        tuple(tables),
        {r: t.a_only for r, t in tables.items()},
        {r: t.b_only for r, t in tables.items()},
    )


def decide_findings(comparisons: Sequence[Comparison], alpha: float) -> list[Finding]:
    """Decide a whole family at family-wise error α: each comparison at α/m (Bonferroni), so with probability
    ≥ 1 − α every interval of the family holds at once, and so every supported finding is right."""
    alpha = check_unit("alpha", alpha)
    if not comparisons or any(not c.outcomes or not c.runs() for c in comparisons):
        raise ValueError("findings need at least one comparison, each with at least one replicate's runs")
    level = split_gamma(alpha, len(comparisons))
    return [decide_finding(c, level, alpha) for c in comparisons]
