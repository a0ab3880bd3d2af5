"""A method's answer at one condition (offline safety) or condition × warnings mode (collision avoidance) over its
training replicates: what the posterior family does, not what one
trained network did.

Replicate r (training seed r) gives η̂_r from its cell's first k rollouts, k fixed in advance (all of them for a
fixed-n scheme, a sequential scheme's earliest stop otherwise), so each η̂_r is an unbiased estimate of that
network's η_r, and the R of them are independent draws whose mean is the method's η1 = E[η_r] over training
runs. The interval is Hoeffding's relative-entropy bound for that mean (`uqdrive.uq.replicates`): it assumes
only that the replicates are independent training runs, so the spread between them and the rollout noise within
each are both in it; with few replicates it is wide, and that is how much the training runs leave unknown.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from uqdrive.analysis import paper
from uqdrive.analysis.paper import PaperNumbers
from uqdrive.avoid.results import AvoidResult, Mode, RuleRecord
from uqdrive.records import record
from uqdrive.resolvers import condition_label
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.uq.replicates import controllers_interval, replicate_bounded_interval

INTERVAL = "hoeffding over replicates (independent training runs; nothing else assumed)"


@record
class MethodAnswer:
    """One method at one condition: each replicate's η̂1 (from its first ``rollouts`` runs) and the interval for
    the method's η1 at level 1 − ``gamma``."""

    method: str
    condition: str
    replicates: list[int]
    rollouts: int
    estimates: list[float]
    value: float
    low: float
    high: float
    gamma: float
    interval: str


def method_answer(method: str, condition: str, cells: Sequence[tuple[int, np.ndarray]], gamma: float) -> MethodAnswer:
    """``cells``: (replicate, outcomes by rollout index) per replicate; every replicate is cut to the shortest."""
    rollouts = min(len(outcomes) for _, outcomes in cells)
    estimates = [float(np.mean(outcomes[:rollouts])) for _, outcomes in cells]
    bound = replicate_bounded_interval(estimates, gamma)
    replicates = [r for r, _ in cells]
    return MethodAnswer(
        method, condition, replicates, rollouts, estimates, bound.value, bound.low, bound.high, gamma, INTERVAL
    )


@record
class SafetySummary:
    """metrics/safety.json: every method's answer at every condition of the offline-safety sweep, and which
    guarantee the cells carry (``family_size`` 1: each cell on its own; m: all m cells at once)."""

    answers: list[MethodAnswer]
    family_size: int
    cell_gamma: float

    def answer(self, method: str, location: str, weather: str, noise: float) -> MethodAnswer:
        condition = condition_label(location, weather, noise)
        return next(a for a in self.answers if (a.method, a.condition) == (method, condition))


def summarise_methods(cells: Iterable[SafetyCell], methods: Sequence[str]) -> SafetySummary:
    """Each method's answer per condition over its replicates, at the cells' family level γ."""
    cells = list(cells)
    gamma = max(c.estimate.gamma * c.family_size for c in cells)
    conditions = list(dict.fromkeys(c.condition for c in cells))

    def replicates(method: str, condition: tuple) -> list[tuple[int, np.ndarray]]:
        members = [c for c in cells if (c.method, c.condition) == (method, condition)]
        return [(c.replicate, c.safe[: c.fixed_rollouts]) for c in members]

    answers = [
        method_answer(method, condition_label(*condition), replicates(method, condition), gamma)
        for method in methods
        for condition in conditions
    ]
    return SafetySummary(answers, max(c.family_size for c in cells), min(c.estimate.gamma for c in cells))


def pooled_answer(method: str, condition: str, answers: Sequence[MethodAnswer]) -> MethodAnswer:
    """The uniform mixture of ``answers``' conditions (one method's): each replicate's mean η̂1 over them, and the
    bound over replicates, so an average over conditions carries an interval as a single condition does."""
    first = answers[0]
    per_replicate = [float(np.mean([a.estimates[i] for a in answers])) for i in range(len(first.estimates))]
    bound = replicate_bounded_interval(per_replicate, first.gamma)
    rollouts = sum(a.rollouts for a in answers)
    return MethodAnswer(
        method,
        condition,
        first.replicates,
        rollouts,
        per_replicate,
        bound.value,
        bound.low,
        bound.high,
        first.gamma,
        first.interval,
    )


def controllers_bounds(answers: Sequence[MethodAnswer]) -> tuple[float, float]:
    """The interval for the mean η1 of these trained controllers over ``answers``' conditions (one method's; their
    uniform mixture, as `pooled_answer`), from the first-k runs each answer averages (``estimates`` × ``rollouts``
    are whole counts): the answer the rollouts support where the method's interval, bounded by the training runs,
    says little."""
    safe = [[round(e * a.rollouts) for e in a.estimates] for a in answers]
    return controllers_interval(safe, [a.rollouts for a in answers], answers[0].gamma)


UNKNOWN = "unknown mixture"


@record
class DeployedRule:
    """One controller's calibrated warning rule as deployed in its calibrated cells: its settings (thresholds,
    actions, draws, tier rule), what Learn-then-Test certified in words, the tier rule's exact wrong-tier error and
    whether its middle tier is guaranteed, and the fresh-seed test of its known-condition autonomy."""

    method: str
    replicate: int
    rule: RuleRecord
    guarantee: str
    tier_error: float
    middle_guaranteed: bool
    fresh_runs: int
    fresh_p_value: float
    target_met: bool


@record
class AvoidSummary:
    """metrics/avoid.json: every method's answer over its replicates per condition × warnings mode (and for the
    unknown conditions' mixture), which guarantee the cells carry, each controller's deployed rule, and the paper's
    numbers."""

    answers: list[MethodAnswer]
    family_size: int
    deployed: list[DeployedRule]
    paper: PaperNumbers

    def answer(self, method: str, condition: str, mode: Mode) -> MethodAnswer:
        return next(a for a in self.answers if (a.method, a.condition) == (method, f"{condition}/{mode}"))


def summarise_avoid(results: list[AvoidResult], methods: list[str]) -> AvoidSummary:
    """Each method's answer over its replicates, per condition × mode and for the unknown mixture (the unknown
    cells' first k runs each, one uniform mixture)."""
    first = results[0]
    off = first.cells[first.conditions[0]][Mode.OFF]
    gamma = off.estimate.gamma * off.family_size
    answers = []
    for method in methods:
        mine = [r for r in results if r.method == method]
        for mode in Mode:
            for condition in first.conditions:
                cells = [(r.replicate, r.cells[condition][mode]) for r in mine]
                outcomes = [(replicate, c.safe[: c.fixed_rollouts]) for replicate, c in cells]
                answers.append(method_answer(method, f"{condition}/{mode}", outcomes, gamma))
            mixtures = [
                (
                    r.replicate,
                    np.concatenate(
                        [r.cells[c][mode].safe[: r.cells[c][mode].fixed_rollouts] for c in r.conditions[1:]]
                    ),
                )
                for r in mine
            ]
            answers.append(method_answer(method, f"{UNKNOWN}/{mode}", mixtures, gamma))
    family = first.cells[first.conditions[0]][Mode.OFF].family_size
    return AvoidSummary(answers, family, [deployed_rule(r) for r in results], paper.numbers())


def deployed_rule(result: AvoidResult) -> DeployedRule:
    k, fresh = result.calibration.certificate, result.calibration.fresh_seed_check.check
    return DeployedRule(
        result.method,
        result.replicate,
        k.rule,
        k.guarantee,
        float(k.rule.tier.wrong_tier_error),
        k.middle_guaranteed,
        fresh.runs,
        fresh.p_value,
        fresh.target_met,
    )
