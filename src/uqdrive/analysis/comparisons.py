"""Findings "for these trained controllers": the controller-level family of paired comparisons, computed as tests
from the stages' records, never written by hand (the method-level claims: `uqdrive.analysis.method_claims`).

A fixed family of comparisons, each between two cells on the same rollout seeds, per training replicate:
- offline safety: method vs method at each condition; each condition vs the training condition, per method;
- collision avoidance: method vs method at each condition (warnings off); each unknown condition vs the known
  one (warnings off), per method; warnings on vs off, and calibrated vs off on the fresh seeds, per method and
  condition.
Each is decided by the stratified exact McNemar test over its replicates (exact: replicates drive disjoint seed
blocks, so their tables are independent), Holm's correction over the whole family (family-wise error ≤ α), and the
agreement rule: a finding needs every replicate to show a non-zero difference of its sign (`uqdrive.uq.family`).
Only the first k rollouts of a cell enter, k fixed in advance (`fixed_rollouts`), so the
exact tests hold whatever a sequential scheme did next.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Iterator

from uqdrive.analysis.method_claims import ClaimRecord
from uqdrive.records import record
from uqdrive.resolvers import condition_label
from uqdrive.safety.cell_records import PAIRS, AvoidCell, AvoidResult, Mode, SafetyCell
from uqdrive.uq.family import Comparison, decide_findings
from uqdrive.uq.paired import PairedTable, paired_table
from uqdrive.uq.verdict import Reason, Verdict

Cell = SafetyCell | AvoidCell


@record
class FindingRecord:
    """One comparison of the controller-level family ("for these trained controllers"): "A vs B" (``a``, ``b``: the
    two cells' labels), η̂_A − η̂_B over the replicates' paired runs (``effect``); the stratified exact test's raw
    and Holm-adjusted p-values and the ``level`` Holm grants it; ``share_low``/``share_high``: the inversion of that
    test at that level, for π (the share of discordant pairs in which A alone is safe), and ``low``/``high`` the
    same on the difference scale at the observed ``discordance`` — either excludes 0 (½) exactly when the test
    rejects (``significant``); ``supported``: significant and every replicate shows a non-zero difference of the
    pooled sign (``verdict``, and the ``reason`` where undecided); per replicate the discordant counts."""

    name: str
    experiment: str
    kind: str
    topic: str  # what the comparison is about beside the controller (a condition, a method pair): the report's rows
    a: str
    b: str
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
    replicates: list[int]
    agreeing: list[int]
    opposing: list[int]
    pairs: int
    a_only: dict[int, int]
    b_only: dict[int, int]


@record
class Findings:
    """metrics/findings.json: both levels of answer. ``findings``: the controller-level family (exact tests across
    the replicates' paired runs, Holm at ``alpha``); ``claims``: the method-level families (t across replicates,
    Bonferroni at ``alpha`` within each; ``margin``: δ of equivalence)."""

    alpha: float
    comparisons: int
    supported: int
    findings: list[FindingRecord]
    margin: float = 0.1
    claims: list[ClaimRecord] = dataclasses.field(default_factory=list)


def _table(a: Cell, b: Cell) -> PairedTable:
    k = min(a.fixed_rollouts, b.fixed_rollouts)
    if a.base_seed != b.base_seed:
        raise ValueError(f"cells on other rollout seeds ({a.base_seed}, {b.base_seed}) are not paired")
    return paired_table(a.safe[:k], b.safe[:k])


def _comparison(name: str, pairs: dict[int, tuple[Cell, Cell]]) -> Comparison:
    return Comparison(name, {r: _table(a, b) for r, (a, b) in pairs.items()})


def safety_comparisons(
    cells: list[SafetyCell], methods: list[str], training: tuple, experiment: str = "offline"
) -> Iterator[tuple]:
    """(experiment, kind, topic, a, b, comparison) of the offline-safety sweep (``experiment``: whose controllers
    drove it: the offline one, or a Gymnasium world's)."""
    by = {(c.method, c.replicate, c.condition): c for c in cells}
    replicates = sorted({c.replicate for c in cells})
    conditions = list(dict.fromkeys(c.condition for c in cells))
    for condition in conditions:
        label = condition_label(*condition)
        for x, y in itertools.combinations(methods, 2):
            pairs = {r: (by[x, r, condition], by[y, r, condition]) for r in replicates}
            comparison = _comparison(f"{x} vs {y} at {label}", pairs)
            yield experiment, "method", f"{x} vs {y}", f"{x} {label}", f"{y} {label}", comparison
    for method in methods if training in conditions else ():
        for condition in conditions:
            if condition == training:
                continue
            label, base = condition_label(*condition), condition_label(*training)
            pairs = {r: (by[method, r, condition], by[method, r, training]) for r in replicates}
            name = f"{method}: {label} vs the training condition"
            topic = condition[0] if condition[0] != training[0] else label  # another location: one topic, all weathers
            yield experiment, "condition", topic, f"{method} {label}", f"{method} {base}", _comparison(name, pairs)


def avoid_comparisons(results: list[AvoidResult], methods: list[str]) -> Iterator[tuple]:
    """(experiment, kind, topic, a, b, comparison) of collision avoidance (none without results); the experiment is
    the results' (whose controllers drove: the obstacle road's, or a Gymnasium world's)."""
    by = {(r.method, r.replicate): r for r in results}
    experiment = results[0].experiment if results else ""
    replicates = sorted({r.replicate for r in results})
    conditions = results[0].conditions if results else []
    for condition in conditions:
        for x, y in itertools.combinations(methods, 2):
            pairs = {r: (by[x, r].cells[condition][Mode.OFF], by[y, r].cells[condition][Mode.OFF]) for r in replicates}
            name = f"{x} vs {y} at {condition}, warnings off"
            a, b = f"{x} {condition} off", f"{y} {condition} off"
            yield experiment, "method", f"{x} vs {y}", a, b, _comparison(name, pairs)
    for method in methods:
        for condition in conditions[1:]:
            pairs = {
                r: (by[method, r].cells[condition][Mode.OFF], by[method, r].cells[conditions[0]][Mode.OFF])
                for r in replicates
            }
            name = f"{method}: {condition} vs {conditions[0]}, warnings off"
            a, b = f"{method} {condition} off", f"{method} {conditions[0]} off"
            yield experiment, "condition", condition, a, b, _comparison(name, pairs)
        for with_warnings, without in PAIRS:
            for condition in conditions:
                cells = {r: by[method, r].cells[condition] for r in replicates}
                pairs = {r: (c[with_warnings], c[without]) for r, c in cells.items()}
                name = f"{method}: {with_warnings} vs {without} at {condition}"
                a, b = f"{method} {condition} {with_warnings}", f"{method} {condition} {without}"
                yield (
                    experiment,
                    "warnings",
                    f"{with_warnings} vs {without} at {condition}",
                    a,
                    b,
                    _comparison(name, pairs),
                )


def decide(family: list[tuple], alpha: float) -> Findings:
    decided = decide_findings([c for *_, c in family], alpha)
    records = [
        FindingRecord(
            name=f.name,
            experiment=experiment,
            kind=kind,
            topic=topic,
            a=a,
            b=b,
            effect=f.effect,
            low=f.low,
            high=f.high,
            share=f.share,
            share_low=f.share_low,
            share_high=f.share_high,
            discordance=f.discordance,
            p_value=f.p_value,
            adjusted_p=f.adjusted_p,
            level=f.level,
            significant=f.significant,
            consistent=f.consistent,
            supported=f.supported,
            verdict=f.verdict,
            reason=f.reason,
            alpha=f.alpha,
            replicates=list(f.replicates),
            agreeing=list(f.agreeing),
            opposing=list(f.opposing),
            pairs=sum(t.n for t in f.tables.values()),
            a_only={r: t.a_only for r, t in f.tables.items()},
            b_only={r: t.b_only for r, t in f.tables.items()},
        )
        for (experiment, kind, topic, a, b, _), f in zip(family, decided)
    ]
    return Findings(alpha, len(records), sum(r.supported for r in records), records)
