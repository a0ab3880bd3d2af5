"""Findings: the conclusions the report and the README state, computed as tests from the stages' records, never
written by hand.

A fixed family of comparisons, each between two cells on the same rollout seeds, per training replicate:
- offline safety: method vs method at each condition; each condition vs the training condition, per method;
- collision avoidance: method vs method at each condition (warnings off); each unknown condition vs the known
  one (warnings off), per method; warnings on vs off, and calibrated vs off on the fresh seeds, per method and
  condition.
Each is decided by the stratified exact McNemar test over its replicates, Holm's correction over the whole family
(family-wise error ≤ α), and the sign rule: a finding whose replicates disagree in sign is not supported
(`uqdrive.uq.family`). Only the first k rollouts of a cell enter, k fixed in advance (`fixed_rollouts`), so the
exact tests hold whatever a sequential scheme did next.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator

from uqdrive.records import record
from uqdrive.resolvers import condition_label
from uqdrive.safety.cell_records import PAIRS, AvoidCell, AvoidResult, Mode, SafetyCell
from uqdrive.uq.family import Comparison, decide_findings
from uqdrive.uq.paired import PairedTable, paired_table

Cell = SafetyCell | AvoidCell


@record
class FindingRecord:
    """One comparison of the family: "A vs B" (``a``, ``b``: the two cells' labels), the effect η̂_A − η̂_B over the
    replicates' paired runs with its interval (level 1 − α, not adjusted), the raw and Holm-adjusted p-values,
    whether it is supported (significant and no replicate opposing), and per replicate the discordant counts."""

    name: str
    experiment: str
    kind: str
    a: str
    b: str
    effect: float
    low: float
    high: float
    p_value: float
    adjusted_p: float
    significant: bool
    consistent: bool
    supported: bool
    alpha: float
    replicates: list[int]
    agreeing: list[int]
    opposing: list[int]
    pairs: int
    a_only: dict[int, int]
    b_only: dict[int, int]


@record
class Findings:
    """metrics/findings.json: the whole family, in a fixed order."""

    alpha: float
    comparisons: int
    supported: int
    findings: list[FindingRecord]


def _table(a: Cell, b: Cell) -> PairedTable:
    k = min(a.fixed_rollouts, b.fixed_rollouts)
    if a.base_seed != b.base_seed:
        raise ValueError(f"cells on other rollout seeds ({a.base_seed}, {b.base_seed}) are not paired")
    return paired_table(a.safe[:k], b.safe[:k])


def _comparison(name: str, pairs: dict[int, tuple[Cell, Cell]]) -> Comparison:
    return Comparison(name, {r: _table(a, b) for r, (a, b) in pairs.items()})


def safety_comparisons(cells: list[SafetyCell], methods: list[str], training: tuple) -> Iterator[tuple]:
    """(experiment, kind, a, b, comparison) of the offline-safety sweep."""
    by = {(c.method, c.replicate, c.condition): c for c in cells}
    replicates = sorted({c.replicate for c in cells})
    conditions = list(dict.fromkeys(c.condition for c in cells))
    for condition in conditions:
        label = condition_label(*condition)
        for x, y in itertools.combinations(methods, 2):
            pairs = {r: (by[x, r, condition], by[y, r, condition]) for r in replicates}
            yield "offline", "method", f"{x} {label}", f"{y} {label}", _comparison(f"{x} vs {y} at {label}", pairs)
    for method in methods if training in conditions else ():
        for condition in conditions:
            if condition == training:
                continue
            label, base = condition_label(*condition), condition_label(*training)
            pairs = {r: (by[method, r, condition], by[method, r, training]) for r in replicates}
            name = f"{method}: {label} vs the training condition"
            yield "offline", "condition", f"{method} {label}", f"{method} {base}", _comparison(name, pairs)


def avoid_comparisons(results: list[AvoidResult], methods: list[str]) -> Iterator[tuple]:
    """(experiment, kind, a, b, comparison) of collision avoidance."""
    by = {(r.method, r.replicate): r for r in results}
    replicates = sorted({r.replicate for r in results})
    conditions = results[0].conditions
    for condition in conditions:
        for x, y in itertools.combinations(methods, 2):
            pairs = {r: (by[x, r].cells[condition][Mode.OFF], by[y, r].cells[condition][Mode.OFF]) for r in replicates}
            name = f"{x} vs {y} at {condition}, warnings off"
            yield "avoid", "method", f"{x} {condition} off", f"{y} {condition} off", _comparison(name, pairs)
    for method in methods:
        for condition in conditions[1:]:
            pairs = {
                r: (by[method, r].cells[condition][Mode.OFF], by[method, r].cells[conditions[0]][Mode.OFF])
                for r in replicates
            }
            name = f"{method}: {condition} vs {conditions[0]}, warnings off"
            a, b = f"{method} {condition} off", f"{method} {conditions[0]} off"
            yield "avoid", "condition", a, b, _comparison(name, pairs)
        for with_warnings, without in PAIRS:
            for condition in conditions:
                cells = {r: by[method, r].cells[condition] for r in replicates}
                pairs = {r: (c[with_warnings], c[without]) for r, c in cells.items()}
                name = f"{method}: {with_warnings} vs {without} at {condition}"
                a, b = f"{method} {condition} {with_warnings}", f"{method} {condition} {without}"
                yield "avoid", "warnings", a, b, _comparison(name, pairs)


def decide(family: list[tuple], alpha: float) -> Findings:
    decided = decide_findings([c for *_, c in family], alpha)
    records = [
        FindingRecord(
            name=f.name,
            experiment=experiment,
            kind=kind,
            a=a,
            b=b,
            effect=f.effect,
            low=f.low,
            high=f.high,
            p_value=f.p_value,
            adjusted_p=f.adjusted_p,
            significant=f.significant,
            consistent=f.consistent,
            supported=f.supported,
            alpha=f.alpha,
            replicates=list(f.replicates),
            agreeing=list(f.agreeing),
            opposing=list(f.opposing),
            pairs=sum(t.n for t in f.tables.values()),
            a_only={r: t.a_only for r, t in f.tables.items()},
            b_only={r: t.b_only for r, t in f.tables.items()},
        )
        for (experiment, kind, a, b, _), f in zip(family, decided)
    ]
    return Findings(alpha, len(records), sum(r.supported for r in records), records)
