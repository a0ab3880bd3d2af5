"""Findings: a family of paired comparisons, each over training replicates, decided with Holm's correction.

A comparison ("MCD vs VI in fog", "fog vs the training weather", "warnings on vs off") has one paired
table per replicate (the two cells of that replicate on the same rollout seeds). Its p-value is the
stratified exact McNemar test of "no difference in any replicate"; Holm's correction over the whole family
keeps the probability of any false significant finding ≤ α under any dependence between comparisons.

A finding is *supported* when it is significant after the correction and its replicates agree in sign:
no replicate's own difference (a_only − b_only) is non-zero and opposite to the pooled one. A replicate
with no difference neither contradicts nor supports it. The sign rule only removes claims, so the
family-wise error stays ≤ α.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np

from uqdrive.uq.bounds import check_unit
from uqdrive.uq.multiplicity import holm
from uqdrive.uq.paired import PairedTable, difference_interval, stratified_p


@dataclasses.dataclass(frozen=True)
class Comparison:
    """A vs B: ``tables[r]`` pairs replicate r's cell A with its cell B on the same seeds."""

    name: str
    tables: Mapping[int, PairedTable]


@dataclasses.dataclass(frozen=True)
class Finding:
    """One comparison's outcome; the interval is for the pooled difference, at level 1 − α, not adjusted.

    ``effect``: Σ_r (a_only − b_only) / Σ_r n, η̂_A − η̂_B over all the replicates' pairs (their mean
    difference when each has the same n). ``low``, ``high``: every replicate's exact paired interval at
    level 1 − α/R holds at once with probability ≥ 1 − α, so their n-weighted mean bounds the pooled
    difference of these R trained networks. ``agreeing``/``opposing``: replicates whose own difference has
    the pooled sign / the opposite one.
    """

    name: str
    effect: float
    low: float
    high: float
    p_value: float
    adjusted_p: float
    significant: bool
    consistent: bool
    supported: bool
    alpha: float
    replicates: tuple[int, ...]
    agreeing: tuple[int, ...]
    opposing: tuple[int, ...]
    tables: dict[int, PairedTable]


def _pooled_interval(tables: Sequence[PairedTable], alpha: float) -> tuple[float, float]:
    bounds = np.array([difference_interval(t, alpha / len(tables)) for t in tables])
    weights = np.array([t.n for t in tables], float) / sum(t.n for t in tables)
    return float(weights @ bounds[:, 0]), float(weights @ bounds[:, 1])


def decide_findings(comparisons: Sequence[Comparison], alpha: float) -> list[Finding]:
    """Decide a whole family at family-wise error α (Holm over the stratified exact p-values)."""
    alpha = check_unit("alpha", alpha)
    if not comparisons or any(not c.tables for c in comparisons):
        raise ValueError("findings need at least one comparison, each with at least one replicate's table")
    raw = [stratified_p(list(c.tables.values())) for c in comparisons]
    adjusted = holm(raw)
    out = []
    for comparison, p, adj in zip(comparisons, raw, adjusted):
        tables = dict(comparison.tables)
        difference = sum(t.a_only - t.b_only for t in tables.values())
        sign = np.sign(difference)
        own = {r: np.sign(t.a_only - t.b_only) for r, t in tables.items()}
        agreeing = tuple(r for r, s in own.items() if s != 0 and s == sign)
        opposing = tuple(r for r, s in own.items() if s != 0 and s == -sign)
        significant, consistent = bool(adj <= alpha), bool(sign != 0 and not opposing)
        low, high = _pooled_interval(list(tables.values()), alpha)
        out.append(
            Finding(
                comparison.name,
                difference / sum(t.n for t in tables.values()),
                low,
                high,
                float(p),
                float(adj),
                significant,
                consistent,
                significant and consistent,
                alpha,
                tuple(tables),
                agreeing,
                opposing,
                tables,
            )
        )
    return out
