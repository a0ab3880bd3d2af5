"""Collision avoidance, from a stage's finished cells to its answers: each cell's metrics (η̂1 with its interval,
autonomy, where hand-overs happened, warning counts), the unknown conditions as one mixture, what the calibration
certified with its replay and fresh-seed checks, and the variants no threshold catches: the stage's record."""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np

from uqdrive.avoid.calibration import Calibration
from uqdrive.avoid.cells import AvoidRun, Cell, handed_over, handover_distances, levels
from uqdrive.avoid.course import Course
from uqdrive.avoid.results import AvoidCell, AvoidResult, CalibrationSummary, FreshSeedRecord, MixtureEstimate, Mode
from uqdrive.policy.warnings import LEVELS
from uqdrive.safety.rollout_metrics import summarise
from uqdrive.sim.condition import Condition, Mixture
from uqdrive.uq.pooled import pooled


def avoid_result(run: AvoidRun) -> AvoidResult:
    """metrics/avoid/<method>-<replicate>.json from the stage's run: every cell's metrics, the unknown conditions'
    mixture per mode, the calibration with its replay and fresh-seed checks."""
    settings, names, cells = run.settings, run.names, run.cells
    fixed, family, cruise = settings.fixed_rollouts(), settings.family_size, settings.spec.speed
    table = {name: {} for name in names}
    for (condition, mode), cell in cells.items():
        table[condition][mode] = cell_metrics(cell, cruise, run.geometries[condition], fixed, family)
    mixture = {
        mode: unknown_mixture(
            [cells[name, mode] for name in names[1:]],
            [table[name][mode] for name in names[1:]],
            settings.estimator.gamma,
            settings.unknown[0],
            fixed,
        )
        for mode in Mode
    }
    known, check = table[names[0]][Mode.CALIBRATED], run.fresh_check
    autonomy, unknown = check.autonomous / check.runs, mixture[Mode.CALIBRATED].eta1
    fresh = FreshSeedRecord(check, autonomy, known.estimate.value, unknown, settings.validation_seed)
    uncaught = uncaught_variants(run.calibration, cells, names[1:])
    return AvoidResult(
        method=settings.method,
        replicate=settings.seed,
        experiment=settings.stage.experiment.name,
        cells=table,
        unknown=mixture,
        calibration=CalibrationSummary(run.calibration.certificate, fresh, uncaught, run.replay_check),
        warning=settings.rule.to_dict(),
        samples_per_frame=settings.rule.cap,
        conditions=names,
        horizon_s=settings.horizon_s,
        speed=settings.spec.speed,
        seconds=run.seconds,
    )


def cell_metrics(
    cell: Cell,
    cruise: float,
    course: Course,
    fixed_rollouts: int,
    family_size: int,
) -> AvoidCell:
    """η̂1 with its interval, autonomy, passed and timeout rates, hand-over distances, warning counts, each run's
    verdict in rollout order (``fixed_rollouts``: how many every cell runs whatever the outcomes) and its
    failures."""
    results, est = cell.results, cell.estimate
    per_run = [levels(cell, r) for r in results]
    handed = handed_over(cell)
    steps = sum(r.steps for r in results)
    full = sum(int(np.sum(r.command_speed >= cruise - 1e-9)) for r in results)
    where = handover_distances(cell, course)
    metrics = {
        "handover_rate": float(np.mean(handed)),
        "autonomy": 1 - float(np.mean(handed)),
        "full_speed_fraction": full / max(steps, 1),
        **summarise(results, ("collision_rate", "off_road_rate")),
        "passed_rate": summarise(results, ("reached_goal_rate",))["reached_goal_rate"],
        # ran out of time before passing the obstacle without having stopped: no answer, never safe (a Gymnasium
        # world has no goal beyond its horizon: a timeout there is unsafe only if its safe_if failed)
        "timeout_before_obstacle_rate": float(
            np.mean([r.termination == "timeout" and not r.verdict.reached_goal for r in results])
        ),
        "handover_distance_min": min(where, default=None),  # None (JSON null): no hand-over
        "handover_distance_median": float(np.median(where)) if where else None,
        "handover_distances": [round(d, 2) for d in where],
        "mean_steps": steps / len(results),
        "seconds": cell.seconds,
        "reused": cell.reused,
    }
    for level in LEVELS:
        metrics[f"warning{level}_frames"] = int(sum(int(np.sum(lv == level)) for lv in per_run))
        metrics[f"warning{level}_runs"] = int(sum(bool(np.any(lv == level)) for lv in per_run))
    return AvoidCell(
        **metrics,
        terminations=dict(sorted(Counter(r.termination for r in results).items())),
        estimate=dataclasses.replace(est, condition=""),
        family_size=family_size,
        fixed_rollouts=fixed_rollouts,
        thresholds={"delta1": cell.rule.config.delta1, "delta2": cell.rule.config.delta2, "tau": cell.rule.config.tau},
        base_seed=cell.base_seed,
        outcomes="".join("1" if r.verdict.safe else "0" for r in results),
        failures=cell.failures,
    )


def unknown_mixture(
    cells: list[Cell], metrics: list[AvoidCell], gamma: float, mixture: Condition | Mixture, fixed_rollouts: int
) -> MixtureEstimate:
    """η̂1 of the unknown conditions as one uniform mixture: of their cells (Hoeffding interval, fixed n), or the
    mixture cell's own estimate (its rollouts drew their variant: ``mixture``, the first unknown condition) with
    each variant's share of its ``fixed_rollouts``."""
    if mixture.single is None:  # a mixture cell: its rollouts drew their variant
        (cell,), est, variants = cells, cells[0].estimate, mixture.variants
        first = cell.results[:fixed_rollouts]
        drawn = [mixture.variant(cell.base_seed + i) for i in range(len(first))]
        shares = {
            item.name: {"runs": drawn.count(v), "safe": sum(r.verdict.safe for r, d in zip(first, drawn) if d == v)}
            for v, item in enumerate(variants)
        }
        interval = f"{est.scheme} (one cell, each rollout's variant drawn from its seed)"
        return MixtureEstimate(
            est.value, est.low, est.high, est.theta, est.gamma, est.n, metrics[0].autonomy, interval, shares
        )
    p = pooled([sum(r.verdict.safe for r in c.results) for c in cells], [len(c.results) for c in cells], gamma)
    autonomy = float(np.mean([m.autonomy for m in metrics]))
    return MixtureEstimate(
        p.value, p.low, p.high, p.theta, gamma, p.n, autonomy, "hoeffding (uniform mixture of the cells)"
    )


def uncaught_variants(calib: Calibration, cells: dict[tuple[str, str], Cell], names: list[str]) -> list[dict]:
    """Unknown conditions with unsafe warnings-off runs that no candidate's replay saves at all: a confident
    controller that does not see the danger. Named in the report as a finding."""
    out = []
    for name in names:
        off = cells[name, Mode.OFF]
        observed = float(np.mean([r.verdict.safe for r in off.results]))
        best = float(np.max(calib.table[f"eta1_{name}"]))
        if observed < 1.0 and best <= observed:
            out.append(
                {
                    "condition": name,
                    "eta1_off": observed,
                    "min_eta2_median": float(np.median([r.eta2.min() for r in off.results if r.steps])),
                    "max_mutual_information_median": float(
                        np.median([r.mutual_information.max() for r in off.results if r.steps])
                    ),
                }
            )
    return out
