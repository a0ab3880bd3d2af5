"""Choosing the warning thresholds (δ1, δ2, τ) by replaying recorded warnings-off rollouts, with a guarantee.

What is replayed is the rule that will be deployed (`WarningRule`: the thresholds, the tier rule that decides
η2's tier from a frame's draws, the actions): each candidate is the deployed rule at its thresholds, reading the
recorded η2 streams as its controller reads them (`uqdrive.avoid.trace_replay`), and the chosen candidate is the
object the calibrated cells deploy.

The paper sets δ1 = 0.7, δ2 = 0.6, τ = 0.45 by looking at how uncertainty behaves as the car
approaches the obstacle, and asks of the result two things at once: safety in unknown
conditions, and full autonomy in the known one. Calibration makes that joint claim the
objective, and certifies the constraint by Learn-then-Test (`uqdrive.uq.ltt`): every candidate's null
is "its known-condition hand-over rate exceeds 1 − target" (and, where configured, "its missed-collision
rate in some unknown condition exceeds the limit"), tested with exact binomial p-values on the
calibration runs, by fixed-sequence testing along an order fixed before those runs are seen. With
probability ≥ 1 − γ every certified candidate meets the target, so the choice among them (the most
replayed unknown-condition safety) needs no further correction. Checking each candidate's own bound and
then choosing among the 729 would not do: the bound that was checked is not the bound that holds for
the one chosen. "Always hand over" is safe and useless; the autonomy constraint rules it out. The
never-firing candidate (δ1 = δ2 = 0, τ = 10 nats) is always on the grid and first in the default order;
where nothing is certified the calibration falls back to it and says so. A candidate whose tier rule is refused
(its exact wrong-tier error above γ, `uqdrive.uq.tier`) cannot be deployed and is left out.

The certificate is the replayed one: exact up to each run's first warning action, approximate after it (the
replay keeps the recorded path). The closed-loop claim is the fresh-seed check's (`fresh_seed_check`): the
deployed rule's known-condition autonomy on runs it never saw, by one exact test fixed in advance.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import special

from uqdrive.avoid.results import Certificate, FreshSeedCheck
from uqdrive.avoid.trace_replay import Replay, Traces, replay
from uqdrive.policy.warnings import WarningConfig, WarningRule
from uqdrive.schema import ConfigError
from uqdrive.uq import clopper_pearson_interval
from uqdrive.uq.ltt import fixed_sequence, interleaved_split, pareto_order, rate_above_p


@dataclasses.dataclass(frozen=True)
class Calibration:
    """The chosen rule, what Learn-then-Test certified, and every candidate's replayed outcome.

    ``rule``: the chosen candidate, the `WarningRule` object the calibrated cells deploy; ``certificate``: what
    Learn-then-Test certified for it, as the stage's record keeps it; ``configured_safe``: each run's replayed
    outcome at the thresholds ``calibrate`` was given (the configured ones, which the closed-loop warnings-on
    cells drive: `replay_check`), replayed with the candidates.

    ``table`` columns per candidate: delta1, delta2, tau; autonomy (known runs with no hand-over) and
    autonomy_low (its own exact lower bound at level 1 − γ: descriptive, it does not account for the
    choice); full_speed (known runs' share of frames at full speed); eta1_<group> (replayed η̂1 per
    condition); eta1_unknown (pooled over the unknown conditions); pareto (not beaten in both autonomy and
    eta1_unknown); p_autonomy, p_missed (where a limit is set) and p_value (the larger: the candidate's
    null is their union); sequence (position in the testing order, −1 if not in it); certified (its null
    rejected); feasible (the same as certified, the column the trade-off figure marks).
    """

    rule: WarningRule
    table: dict[str, np.ndarray]
    chosen: int
    certificate: Certificate
    configured_safe: np.ndarray  # [R]


def guarantee(
    rule: WarningRule,
    table: dict[str, np.ndarray],
    known_runs: int,
    certified: int,
    *,
    gamma: float,
    order: str,
    target: float,
    max_target: float,
    missed_limit: float | None,
) -> str:
    """The claim in words, naming the rule it holds for, or why there is none (``certified`` 0: nothing was, and
    ``rule`` is the never-firing candidate; ``known_runs``: the known condition's calibration runs)."""
    runs = f"{known_runs} known-condition calibration runs"
    if not certified:
        first = table["p_value"][table["sequence"] == 0]
        return (
            f"Nothing certified at gamma={gamma:g}: the first candidate of the {order} order has "
            f"p = {first[0] if first.size else 1.0:.3g}. {runs} can certify known-condition autonomy "
            f"≥ {max_target:.3f} at most (no hand-over in any); fell back to the never-firing thresholds "
            f"(no warnings): {rule.describe()}."
        )
    missed = (
        ""
        if missed_limit is None
        else (f" and a replayed missed-collision rate ≤ {missed_limit:g} in every unknown condition")
    )
    return (
        f"With probability ≥ {1 - gamma:g}, each of the {certified} certified candidates, the chosen "
        f"one among them, keeps the replayed known-condition autonomy ≥ {target:g}{missed} "
        f"(Learn-then-Test: exact binomial p-values on {runs}, fixed-sequence testing along the {order} "
        f"order). Chosen and deployed rule: {rule.describe()}. The replay reads each run's recorded η2 "
        "draws as this rule's controller reads them, so it is exact up to a run's first warning action; after "
        "a slow-down the closed-loop path departs from the recorded one, which the replay keeps (an "
        "approximation). It assumes independent runs whose number was fixed before they ran. The closed-loop "
        "claim is the fresh-seed check's."
    )


def fresh_seed_check(handed_over: Sequence[bool] | np.ndarray, target: float, level: float) -> FreshSeedCheck:
    """The test of `FreshSeedCheck` on ``handed_over`` (one entry per fresh run; their number fixed before they
    ran, e.g. a cell's fixed rollouts): the same exact binomial p-value as the calibration's nulls."""
    handed = np.asarray(handed_over, bool)
    if handed.ndim != 1 or not handed.size:
        raise ValueError(f"the fresh-seed check needs one hand-over flag per run, got shape {handed.shape}")
    if not 0 < level < 1:
        raise ValueError(f"the fresh-seed check's level must be in (0, 1), got {level!r}")
    p = float(rate_above_p(int(handed.sum()), handed.size, 1 - target))
    return FreshSeedCheck(handed.size, int((~handed).sum()), float(target), float(level), p, p <= level)


def fresh_check_runs(target: float, autonomy: float, level: float, power: float) -> int:
    """Fewest fresh runs at which `fresh_seed_check` at ``level`` declares ``target`` met with probability ≥
    ``power`` when the rule's true autonomy is ``autonomy`` (exact binomial sums: the smallest count of autonomous
    runs the test accepts, then its probability at ``autonomy``)."""
    if not target < autonomy:
        raise ValueError(f"the fresh-seed check is sized at an autonomy above its target {target}, got {autonomy}")
    for runs in range(1, 100_000):
        autonomous = np.arange(runs + 1)
        met = rate_above_p(runs - autonomous, runs, 1 - target) <= level
        if met.any() and special.bdtrc(int(np.argmax(met)) - 1, runs, autonomy) >= power:
            return runs
    raise ValueError(f"no run count up to 100000 reaches power {power} at autonomy {autonomy} (level {level})")


NEVER_FIRES = (0.0, 0.0, 10.0)  # η2 < 0 is impossible and MI ≤ ln C < 10 nats: no warning, full autonomy
ORDERS = ("firing", "learned")


def candidates(deltas: list[float], taus: list[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every (δ1, δ2, τ) on the grids with δ2 ≤ δ1, plus the candidate that never fires."""
    rows = [(d1, d2, t) for d1 in deltas for d2 in deltas if d2 <= d1 for t in taus]
    rows = [*dict.fromkeys([*rows, NEVER_FIRES])]
    d1, d2, t = (np.array(c, float) for c in zip(*rows))
    return d1, d2, t


def candidate_rules(
    rule: WarningRule, deltas: list[float], taus: list[float]
) -> tuple[list[WarningRule], dict[tuple[float, float], str]]:
    """The deployed ``rule`` at every candidate's thresholds (`candidates`), and the (δ1, δ2) pairs left out
    because their tier rule is refused (exact wrong-tier error above γ), with the reason."""
    rules, refused = [], {}
    for d1, d2, t in zip(*candidates(deltas, taus)):
        if (d1, d2) in refused:
            continue
        try:
            rules.append(rule.with_thresholds(d1, d2, t))
        except ConfigError as err:
            refused[float(d1), float(d2)] = str(err)
    return rules, refused


def pareto(autonomy: np.ndarray, safety: np.ndarray) -> np.ndarray:
    """Candidates no other beats in both autonomy and safety (ties count as not beaten)."""
    better = (
        (autonomy[None] >= autonomy[:, None])
        & (safety[None] >= safety[:, None])
        & ((autonomy[None] > autonomy[:, None]) | (safety[None] > safety[:, None]))
    )
    return ~better.any(1)


def min_calibration_runs(target: float, gamma: float, calibration_fraction: float = 1.0) -> int:
    """Fewest known-condition runs whose calibration share, with no hand-over in any, certifies ``target``:
    the p-value target^n must reach γ (n = 14 for 0.8 at γ = 0.05, 59 for 0.95)."""
    needed = 1
    while float(rate_above_p(0, needed, 1 - target)) > gamma:
        needed += 1
    runs = needed
    while interleaved_split(runs, calibration_fraction).sum() < needed:
        runs += 1
    return runs


def firing_order(delta1: np.ndarray, delta2: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Candidates from the least to the most eager to hand over, fixed before any run is seen: δ2 ascending
    (a hand-over is warning 2, η2 < δ2, so with the default actions a larger δ2 hands over on every run a
    smaller one does, and candidates sharing δ2 hand over alike), then δ1 ascending, τ descending. Any fixed
    order keeps the guarantee; this one makes the hand-over risk grow along it, which is what lets
    fixed-sequence testing go far."""
    return np.lexsort((-np.asarray(tau), delta1, delta2))


def run_index(group: np.ndarray) -> np.ndarray:
    """Each run's index within its condition: rollout i of every cell (seed base_seed + i)."""
    index = np.zeros(group.size, np.int64)
    for g in np.unique(group):
        members = group == g
        index[members] = np.arange(int(members.sum()))
    return index


def null_p_values(
    out: Replay, group: np.ndarray, runs: np.ndarray, target: float, missed_limit: float | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Exact p-values from the replayed runs selected by ``runs`` (a mask): "hand-over rate > 1 − target" on the
    known ones (group 0) and, with a limit, "missed-collision rate > limit in some unknown condition" (the
    largest of the per-condition p-values: the union of the conditions' nulls, tested with no correction)."""
    known = runs & (group == 0)
    p_autonomy = rate_above_p(out.handover[:, known].sum(1), int(known.sum()), 1 - target)
    if missed_limit is None:
        return p_autonomy, None
    per_condition = [
        rate_above_p((~out.safe[:, runs & (group == g)]).sum(1), int(np.sum(runs & (group == g))), missed_limit)
        for g in np.unique(group[group > 0])
    ]
    return p_autonomy, np.max(per_condition, axis=0)


def union_p(p_autonomy: np.ndarray, p_missed: np.ndarray | None) -> np.ndarray:
    """A candidate's null is the union of its constraints' nulls; the larger p-value is valid for it."""
    return p_autonomy if p_missed is None else np.maximum(p_autonomy, p_missed)


def testing_order(
    order: str, table: dict[str, np.ndarray], out: Replay, group: np.ndarray, learn: np.ndarray, **nulls: float | None
) -> np.ndarray:
    """The fixed sequence: ``firing`` (a priori) or ``learned`` (Pareto Testing: the candidates not beaten in
    p-value and replayed unknown-condition η̂1, both on the learn split's runs only, by p-value)."""
    if order == "firing":
        return firing_order(table["delta1"], table["delta2"], table["tau"])
    unknown = learn & (group > 0)
    utility = out.safe[:, unknown].mean(1) if unknown.any() else np.zeros(len(table["delta1"]))
    return pareto_order(union_p(*null_p_values(out, group, learn, **nulls)), utility)


def replayed_table(
    out: Replay, traces: Traces, groups: list[str], thresholds: tuple[np.ndarray, ...], gamma: float
) -> dict[str, np.ndarray]:
    """Every candidate's replayed outcome on all runs (the columns before the tests')."""
    known = traces.group == 0
    kept = (~out.handover[:, known]).sum(1)
    table = dict(zip(("delta1", "delta2", "tau"), thresholds))
    table["autonomy"] = kept / known.sum()
    table["autonomy_low"] = clopper_pearson_interval(kept, int(known.sum()), gamma)[0]
    table["full_speed"] = out.full_speed[:, known].mean(1)
    for g, name in enumerate(groups):
        table[f"eta1_{name}"] = out.safe[:, traces.group == g].mean(1)
    table["eta1_unknown"] = out.safe[:, traces.group > 0].mean(1)
    table["pareto"] = pareto(table["autonomy"], table["eta1_unknown"])
    return table


def _check_calibration(traces: Traces, groups: list[str], order: str, calibration_fraction: float) -> None:
    counts = [int(np.sum(traces.group == g)) for g in range(len(groups))]
    if len(groups) < 2 or min(counts) == 0:
        raise ValueError(
            f"calibration needs runs of the known and at least one unknown condition, got {dict(zip(groups, counts))}"
        )
    if order not in ORDERS or (order == "learned" and calibration_fraction >= 1):
        raise ValueError(f"order={order!r} must be one of {ORDERS}; 'learned' needs calibration_fraction < 1")


def calibrate(
    traces: Traces,
    groups: list[str],
    rule: WarningRule,
    deltas: list[float],
    taus: list[float],
    target: float,
    gamma: float,
    *,
    missed_limit: float | None = None,
    calibration_fraction: float = 1.0,
    order: str = "firing",
    **replay_args: float,
) -> Calibration:
    """The deployed ``rule`` at thresholds certified by Learn-then-Test at family-wise error ``gamma`` to keep the
    replayed known-condition autonomy ≥ ``target`` (and each unknown condition's replayed missed-collision rate
    ≤ ``missed_limit``, if given); among the certified, the most replayed unknown-condition η̂1.

    ``groups[0]`` is the known condition, the others the unknown ones (``traces.group`` indexes ``groups``;
    each condition's runs in rollout order). Run index i calibrates iff ⌊(i + 1) f⌋ > ⌊i f⌋ with f =
    ``calibration_fraction``; the other indices form the learn split, which ``order="learned"`` ranks the
    candidates on (it needs f < 1; the default ``"firing"`` order needs no runs, so f = 1 tests on every run).
    The choice among the certified uses every run: the guarantee holds for all of them at once. Ties go to
    more autonomy, then more time at full speed, then the candidate closest to ``rule``'s thresholds. With
    nothing certified it returns the never-firing candidate with ``feasible`` False.
    """
    _check_calibration(traces, groups, order, calibration_fraction)
    rules, refused = candidate_rules(rule, deltas, taus)
    thresholds = tuple(np.array([getattr(r.config, k) for r in rules]) for k in ("delta1", "delta2", "tau"))
    both = replay(traces, [*rules, rule], **replay_args)  # the configured rule beside, for the replay check
    out = Replay(both.safe[:-1], both.handover[:-1], both.full_speed[:-1])
    index = run_index(traces.group)
    calibrating = interleaved_split(int(index.max()) + 1, calibration_fraction)[index]
    table = replayed_table(out, traces, groups, thresholds, gamma)
    table |= certify(out, traces.group, calibrating, table, target, gamma, missed_limit, order)
    best = choose(table, rule.config)
    split, learn = (
        {name: int(np.sum(part & (traces.group == g))) for g, name in enumerate(groups)}
        for part in (calibrating, ~calibrating)
    )
    claim = dict(target=float(target), gamma=float(gamma), order=order, missed_limit=missed_limit)
    certificate = certificate_of(rules[best], table, best, split, learn, refused, **claim)
    return Calibration(rules[best], table, best, certificate, both.safe[-1])


def certificate_of(
    chosen: WarningRule,
    table: dict[str, np.ndarray],
    best: int,
    split: dict[str, int],
    learn: dict[str, int],
    refused: dict[tuple[float, float], str],
    **claim: Any,
) -> Certificate:
    """The record of what `calibrate` certified for the ``chosen`` candidate (row ``best`` of ``table``; ``split``
    and ``learn``: runs per condition, the known one first; ``claim``: target, gamma, order, missed_limit)."""
    known = next(iter(split.values()))
    certified = int(table["certified"].sum())
    max_target = float(claim["gamma"] ** (1 / known)) if known else 0.0
    return Certificate(
        **{k: getattr(chosen.config, k) for k in ("delta1", "delta2", "tau")},
        feasible=bool(table["certified"][best]),
        certified=certified,
        guarantee=guarantee(chosen, table, known, certified, max_target=max_target, **claim),
        autonomy_target=claim["target"],
        max_certifiable_target=max_target,
        gamma=claim["gamma"],
        missed_limit=claim["missed_limit"],
        order=claim["order"],
        calibration_runs=split,
        learn_runs=learn,
        candidates=len(table["delta1"]),
        replayed={k: v[best].item() for k, v in table.items() if k not in ("delta1", "delta2", "tau")},
        rule=chosen.to_dict(),
        middle_guaranteed=chosen.tier.middle_guaranteed,
        refused={f"{d1:g}/{d2:g}": why for (d1, d2), why in refused.items()},
    )


def replay_check(calib: Calibration, group: np.ndarray, names: list[str], closed_loop: list[list[bool]]) -> dict:
    """The replay at the configured thresholds (``calib.configured_safe``) against the warnings-on cells on the same
    seeds (``closed_loop``: each condition's outcomes, in ``names``' order): how well the approximation predicts
    closed loop, run by run."""
    check = {}
    for g, name in enumerate(names):
        replayed = calib.configured_safe[group == g]
        safe = np.array(closed_loop[g][: len(replayed)])
        check[name] = {
            "replayed_eta1": float(replayed.mean()),
            "closed_loop_eta1": float(safe.mean()),
            "agreement": float(np.mean(replayed == safe)),
        }
    return check


def certify(
    out: Replay,
    group: np.ndarray,
    calibrating: np.ndarray,
    table: dict[str, np.ndarray],
    target: float,
    gamma: float,
    missed_limit: float | None,
    order: str,
) -> dict[str, np.ndarray]:
    """Learn-then-Test over the candidates: p-values on the calibrating runs, fixed-sequence testing along the
    ``order`` (learned, if so, on the other runs). Returns the table's test columns."""
    nulls = {"target": target, "missed_limit": missed_limit}
    p_autonomy, p_missed = null_p_values(out, group, calibrating, **nulls)
    p_value = union_p(p_autonomy, p_missed)
    sequence = testing_order(order, table, out, group, ~calibrating, **nulls)
    certified = fixed_sequence(p_value, sequence, gamma)
    position = np.full(len(certified), -1)
    position[sequence] = np.arange(len(sequence))
    columns = {"p_autonomy": p_autonomy} | ({} if p_missed is None else {"p_missed": p_missed})
    return columns | {"p_value": p_value, "sequence": position, "certified": certified, "feasible": certified}


def choose(table: dict[str, np.ndarray], config: WarningConfig) -> int:
    """The most replayed unknown-condition η̂1 among the certified (ties as `calibrate` says), else never-firing."""
    d1, d2, t = table["delta1"], table["delta2"], table["tau"]
    if not table["certified"].any():
        return list(zip(d1, d2, t)).index(NEVER_FIRES)
    distance = np.abs(d1 - config.delta1) + np.abs(d2 - config.delta2) + np.abs(t - config.tau)
    keys = (distance, -table["full_speed"], -table["autonomy"], -table["eta1_unknown"], ~table["certified"])
    return int(np.lexsort(keys)[0])
