"""A family of controller-level findings ("for these trained controllers"): paired comparisons over replicates,
decided with Holm's correction, each with the interval that inverts its own test.

A comparison ("MCD vs VI in fog", "fog vs the training weather", "warnings on vs off") has one paired table
per replicate (the two cells of that replicate on the same rollout seeds). Replicates drive disjoint blocks of
rollout seeds, so their tables are independent; the stratified exact McNemar test of "no difference in any
replicate" is then exact (`paired.stratified_p`). Were the replicates to share seeds, their pairs would share
worlds and the pooled test would not be exact (`tests/test_uq_family.py` computes how far it is off).

Holm's procedure over the whole family keeps the probability of any false significant finding ≤ α under any
dependence between comparisons, and grants each finding a level (`multiplicity.holm_levels`): significant ⇔
p ≤ level. The finding's interval is the inversion of its test at that level, so it excludes 0 exactly when
the finding is significant. A significant finding is *supported* when every replicate shows a non-zero
difference of the pooled sign; the agreement rule only removes claims, so the family-wise error stays ≤ α.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence

import numpy as np

from uqdrive.uq.bounds import check_unit, clopper_pearson_interval
from uqdrive.uq.multiplicity import holm, holm_levels
from uqdrive.uq.paired import PairedTable, sign_test_p, stratified_p
from uqdrive.uq.verdict import Reason, Verdict

ABOVE_HALF, BELOW_HALF = float(np.nextafter(0.5, 1.0)), float(np.nextafter(0.5, 0.0))


@dataclasses.dataclass(frozen=True)
class Comparison:
    """A vs B: ``tables[r]`` pairs replicate r's cell A with its cell B on the same seeds."""

    name: str
    tables: Mapping[int, PairedTable]


def share_interval(a_only: int, discordant: int, level: float) -> tuple[float, float]:
    """Interval for π, the share of discordant pairs in which A alone is safe: the inversion of the exact test.

    The equal-tailed Clopper–Pearson interval at level 1 − ``level`` ([0, 1] without discordant pairs) holds
    the π the equal-tailed exact binomial test at ``level`` does not reject; at π = ½ that test is the sign
    test (`paired.sign_test_p`). The end next to ½ is reconciled with the sign test's own p-value — the two
    agree but for rounding, and where the exact tail equals the level (the test rejects) the end is put one
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


@dataclasses.dataclass(frozen=True)
class Finding:
    """One comparison's outcome for these trained controllers.

    ``effect``: Σ_r (a_only − b_only) / Σ_r n, η̂_A − η̂_B over all the replicates' pairs. ``share``,
    ``share_low``, ``share_high``: π̂ = Σ a_only / Σ discordant (½ without discordant pairs) and its interval
    at level 1 − ``level`` (the level Holm grants this finding); ``low``, ``high``: that interval mapped to the
    difference scale at the observed discordance, d̂ (2π − 1) with d̂ = ``discordance`` = Σ discordant / Σ n —
    a picture of π's interval, not an unconditional interval for Δ (d is estimated, not known). Either
    excludes 0 (½) exactly when ``significant`` (p ≤ level). ``agreeing``/``opposing``: replicates whose own
    difference has the pooled sign / the opposite one; ``consistent``: every replicate agrees.
    """

    name: str
    effect: float
    low: float
    high: float
    share: float
    share_low: float
    share_high: float
    discordance: float
    p_value: float
    adjusted_p: float
    level: float
    significant: bool
    consistent: bool
    supported: bool
    verdict: Verdict
    reason: Reason
    alpha: float
    replicates: tuple[int, ...]
    agreeing: tuple[int, ...]
    opposing: tuple[int, ...]
    tables: dict[int, PairedTable]


def _verdict(significant: bool, opposing: bool, silent: bool) -> tuple[Verdict, Reason]:
    if not significant:
        return Verdict.UNDECIDED, Reason.NOT_SIGNIFICANT
    if opposing:
        return Verdict.UNDECIDED, Reason.REPLICATES_DISAGREE
    if silent:
        return Verdict.UNDECIDED, Reason.NO_DIFFERENCE_IN_A_REPLICATE
    return Verdict.SUPPORTED, Reason.DECIDED


def decide_finding(comparison: Comparison, p_value: float, adjusted_p: float, level: float, alpha: float) -> Finding:
    """One comparison decided at the level its family granted it (``p_value``: its stratified p)."""
    tables = dict(comparison.tables)
    a_only, discordant = sum(t.a_only for t in tables.values()), sum(t.discordant for t in tables.values())
    pairs = sum(t.n for t in tables.values())
    sign = np.sign(2 * a_only - discordant)
    own = {r: np.sign(t.a_only - t.b_only) for r, t in tables.items()}
    agreeing = tuple(r for r, s in own.items() if s != 0 and s == sign)
    opposing = tuple(r for r, s in own.items() if s != 0 and s == -sign)
    significant = bool(p_value <= level)
    share_low, share_high = share_interval(a_only, discordant, level)
    discordance = discordant / pairs
    verdict, reason = _verdict(significant, bool(opposing), len(agreeing) + len(opposing) < len(tables))
    return Finding(
        comparison.name,
        (2 * a_only - discordant) / pairs,
        discordance * (2 * share_low - 1),
        discordance * (2 * share_high - 1),
        a_only / discordant if discordant else 0.5,
        share_low,
        share_high,
        discordance,
        float(p_value),
        float(adjusted_p),
        float(level),
        significant,
        len(agreeing) == len(tables),
        verdict is Verdict.SUPPORTED,
        verdict,
        reason,
        float(alpha),
        tuple(tables),
        agreeing,
        opposing,
        tables,
    )


def decide_findings(comparisons: Sequence[Comparison], alpha: float) -> list[Finding]:
    """Decide a whole family at family-wise error α (Holm over the stratified exact p-values)."""
    alpha = check_unit("alpha", alpha)
    if not comparisons or any(not c.tables for c in comparisons):
        raise ValueError("findings need at least one comparison, each with at least one replicate's table")
    raw = [stratified_p(list(c.tables.values())) for c in comparisons]
    levels, adjusted = holm_levels(raw, alpha), holm(raw)
    return [decide_finding(c, p, adj, lv, alpha) for c, p, adj, lv in zip(comparisons, raw, adjusted, levels)]
