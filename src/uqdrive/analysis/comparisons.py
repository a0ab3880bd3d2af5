"""Findings "for these trained controllers": the controller-level family of paired comparisons, computed as tests
from the stages' records, never written by hand (the method-level claims: `uqdrive.analysis.method_claims`).

A fixed family of comparisons, each between two cells on the same rollout seeds, per training replicate:
- offline safety: method vs method at each condition; each condition vs the training condition, per method;
- collision avoidance: method vs method at each condition (warnings off); each unknown condition vs the known
  one (warnings off), per method; warnings on vs off, and calibrated vs off on the fresh seeds, per method and
  condition.
Each is decided for the average over these controllers (the mean of the replicates' controllers' gains, with a
betting interval valid however unlike they are; `uqdrive.uq.family`) with Bonferroni's correction over the whole
family (family-wise error ≤ α). Only the first k rollouts of a cell enter, k fixed in advance (`fixed_rollouts`), so the
exact tests hold whatever a sequential scheme did next.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Iterator

import numpy as np

from uqdrive.analysis.method_claims import ClaimRecord
from uqdrive.avoid.results import PAIRS, AvoidCell, AvoidResult, Mode
from uqdrive.records import flattened, record
from uqdrive.resolvers import condition_label
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.uq.family import Comparison, Finding, decide_findings

ComparedCell = SafetyCell | AvoidCell


@record
class FindingRecord:
    """One comparison of the controller-level family ("for these trained controllers"): "A vs B" (``a``, ``b``: the
    two cells' labels), decided (``finding``: its average gain over the controllers, the betting interval at level
    1 − ``level`` with α over the family's comparisons, the verdict and each replicate's discordant counts)."""

    experiment: str
    kind: str
    topic: str  # what the comparison is about beside the controller (a condition, a method pair): the report's rows
    a: str
    b: str
    finding: Finding = flattened()


@record
class Findings:
    """metrics/findings.json: both levels of answer. ``findings``: the controller-level family (a majority of these
    controllers, Bonferroni at ``alpha``); ``claims``: the method-level families (sign test and betting interval
    across training runs, Bonferroni at ``alpha`` within each; ``margin``: δ of equivalence)."""

    alpha: float
    comparisons: int
    supported: int
    findings: list[FindingRecord]
    margin: float = 0.1
    claims: list[ClaimRecord] = dataclasses.field(default_factory=list)


def _outcomes(a: ComparedCell, b: ComparedCell) -> tuple[np.ndarray, np.ndarray]:
    """The two cells' outcomes paired by seed, the first k of each (k fixed in advance: `fixed_rollouts`)."""
    k = min(a.fixed_rollouts, b.fixed_rollouts)
    if a.base_seed != b.base_seed:
        raise ValueError(f"cells on other rollout seeds ({a.base_seed}, {b.base_seed}) are not paired")
    return np.asarray(a.safe[:k], bool), np.asarray(b.safe[:k], bool)


def _comparison(name: str, pairs: dict[int, tuple[ComparedCell, ComparedCell]]) -> Comparison:
    return Comparison(name, {r: _outcomes(a, b) for r, (a, b) in pairs.items()})


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
    records = [FindingRecord(*labels, finding=f) for (*labels, _), f in zip(family, decided)]
    return Findings(alpha, len(records), sum(r.finding.supported for r in records), records)
