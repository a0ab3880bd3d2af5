"""Collision avoidance, from a stage's finished cells to its answers: each cell's metrics (η̂1 with its interval,
autonomy, where hand-overs happened, warning counts), the unknown conditions as one mixture, what the calibration
certified with its replay and fresh-seed checks, and the variants no threshold catches: the stage's record."""

from __future__ import annotations

from collections import Counter

import numpy as np

from uqdrive.avoid.calibration import Calibration, fresh_seed_check
from uqdrive.avoid.cells import Cell, Course, handed_over, handover_distances, levels
from uqdrive.avoid.plan import AvoidSettings
from uqdrive.avoid.results import AvoidCell, AvoidResult, CalibrationSummary, FreshSeedRecord, MixtureEstimate, Mode
from uqdrive.avoid.trace_replay import Traces, replay
from uqdrive.policy.warnings import LEVELS
from uqdrive.safety.failures import RolloutFailure, job_failures
from uqdrive.sim.condition import Mixture
from uqdrive.uq.pooled import pooled


def avoid_result(
    settings: AvoidSettings,
    cells: dict[tuple[str, Mode], Cell],
    calib: Calibration,
    traces: Traces,
    geometries: dict[str, Course],
    seconds: float,
) -> AvoidResult:
    """metrics/avoid/<method>-<replicate>.json from the stage's finished cells and calibration: every cell's
    metrics, the unknown conditions' mixture per mode, the calibration with its replay and fresh-seed checks."""
    names = [c.name for c in settings.conditions]
    unknown = names[1:]
    fixed, family = settings.fixed_rollouts(), settings.family_size
    table = {name: {} for name in names}
    where = {c.name: c for c in settings.conditions}
    for (condition, mode), cell in cells.items():
        failures = job_failures(settings.job(where[condition], None, cell.base_seed), cell.results)
        table[condition][mode] = cell_metrics(cell, settings.spec.speed, geometries[condition], fixed, family, failures)
    mixture = {
        mode: unknown_mixture(
            [cells[name, mode] for name in unknown],
            [table[name][mode] for name in unknown],
            settings.estimator.gamma,
            settings,
        )
        for mode in Mode
    }
    known = table[names[0]][Mode.CALIBRATED]
    sizing = settings.calibration
    handed = handed_over(cells[names[0], Mode.CALIBRATED])[: sizing.fresh_runs()]
    test = fresh_seed_check(handed, sizing.fresh_check.target, sizing.fresh_level())
    fresh = FreshSeedRecord(
        test.runs,
        test.autonomous,
        test.target,
        test.level,
        test.p_value,
        test.met,
        test.autonomous / test.runs,
        known.eta1,
        mixture[Mode.CALIBRATED].eta1,
        settings.validation_seed,
    )
    check = replay_check(cells, names, settings, traces)
    calibration = calibration_summary(calib, uncaught_variants(calib, cells, unknown), check, fresh)
    return AvoidResult(
        method=settings.method,
        replicate=settings.seed,
        experiment=settings.stage.experiment.name,
        cells=table,
        unknown=mixture,
        calibration=calibration,
        warning=settings.rule.to_dict(),
        samples_per_frame=settings.rule.cap,
        conditions=names,
        horizon_s=settings.horizon_s,
        speed=settings.spec.speed,
        seconds=seconds,
    )


def cell_metrics(
    cell: Cell,
    cruise: float,
    course: Course,
    fixed_rollouts: int,
    family_size: int,
    failures: list[RolloutFailure] | None = None,
) -> AvoidCell:
    """η̂1 with its interval, autonomy, passed and timeout rates, hand-over distances, warning counts, each run's
    verdict in rollout order (``fixed_rollouts``: how many every cell runs whatever the outcomes) and its
    ``failures`` (`uqdrive.safety.failures.job_failures`)."""
    results, est = cell.results, cell.estimate
    per_run = [levels(cell, r) for r in results]
    handed = handed_over(cell)
    steps = sum(r.steps for r in results)
    full = sum(int(np.sum(r.command_speed >= cruise - 1e-9)) for r in results)
    where = handover_distances(cell, course)
    metrics = {
        "eta1": est.value,
        "eta1_low": est.low,
        "eta1_high": est.high,
        "n": est.n,
        "handover_rate": float(np.mean(handed)),
        "autonomy": 1 - float(np.mean(handed)),
        "full_speed_fraction": full / max(steps, 1),
        "collision_rate": float(np.mean([r.collision for r in results])),
        "off_road_rate": float(np.mean([r.off_road for r in results])),
        "passed_rate": float(np.mean([r.reached_goal for r in results])),
        # ran out of time before passing the obstacle without having stopped: no answer, never safe (a Gymnasium
        # world has no goal beyond its horizon: a timeout there is unsafe only if its safe_if failed)
        "timeout_before_obstacle_rate": float(
            np.mean([r.termination == "timeout" and not r.reached_goal for r in results])
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
        guaranteed=est.guaranteed,
        scheme=est.scheme,
        theta=est.theta,
        gamma=est.gamma,
        family_size=family_size,
        fixed_rollouts=fixed_rollouts,
        thresholds={"delta1": cell.rule.config.delta1, "delta2": cell.rule.config.delta2, "tau": cell.rule.config.tau},
        base_seed=cell.base_seed,
        outcomes="".join("1" if r.safe else "0" for r in results),
        failures=failures or [],
    )


def unknown_mixture(
    cells: list[Cell], metrics: list[AvoidCell], gamma: float, settings: AvoidSettings
) -> MixtureEstimate:
    """η̂1 of the unknown conditions as one uniform mixture: of their cells (Hoeffding interval, fixed n), or the
    mixture cell's own estimate (its rollouts drew their variant) with each variant's share of its fixed sample."""
    mixture = settings.unknown[0]
    if isinstance(mixture, Mixture):
        (cell,), est, variants = cells, cells[0].estimate, mixture.variants
        first = cell.results[: settings.fixed_rollouts()]
        drawn = [mixture.variant(cell.base_seed + i) for i in range(len(first))]
        shares = {
            item.name: {"runs": drawn.count(v), "safe": sum(r.safe for r, d in zip(first, drawn) if d == v)}
            for v, item in enumerate(variants)
        }
        interval = f"{est.scheme} (one cell, each rollout's variant drawn from its seed)"
        return MixtureEstimate(
            est.value, est.low, est.high, est.theta, est.gamma, est.n, metrics[0].autonomy, interval, shares
        )
    p = pooled([sum(r.safe for r in c.results) for c in cells], [len(c.results) for c in cells], gamma)
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
        observed = float(np.mean([r.safe for r in off.results]))
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


def replay_check(
    cells: dict[tuple[str, str], Cell],
    calib_groups: list[str],
    settings: AvoidSettings,
    traces: Traces,
) -> dict:
    """The replay at the configured thresholds against the warnings-on cells on the same seeds: how well
    the approximation predicts closed loop, run by run."""
    out = replay(traces, [settings.rule], **settings.replay_args())
    check = {}
    for g, name in enumerate(calib_groups):
        replayed = out.safe[0, traces.group == g]
        safe = np.array([r.safe for r in cells[name, Mode.ON].results[: len(replayed)]])
        check[name] = {
            "replayed_eta1": float(replayed.mean()),
            "closed_loop_eta1": float(safe.mean()),
            "agreement": float(np.mean(replayed == safe)),
        }
    return check


def calibration_summary(
    calib: Calibration, uncaught: list[dict], check: dict, fresh: FreshSeedRecord
) -> CalibrationSummary:
    """The chosen thresholds, what Learn-then-Test certified (and in what words), the replay at them, and the
    closed-loop check on fresh seeds (``fresh``)."""
    row = {
        k: (v[calib.chosen].item() if hasattr(v[calib.chosen], "item") else v[calib.chosen])
        for k, v in calib.table.items()
    }
    return CalibrationSummary(
        delta1=calib.delta1,
        delta2=calib.delta2,
        tau=calib.tau,
        feasible=calib.feasible,
        certified=calib.certified,
        guarantee=calib.guarantee,
        autonomy_target=calib.target,
        max_certifiable_target=calib.max_target,
        gamma=calib.gamma,
        missed_limit=calib.missed_limit,
        order=calib.order,
        calibration_runs=calib.calibration_runs,
        learn_runs=calib.learn_runs,
        candidates=len(calib.table["delta1"]),
        replayed={k: v for k, v in row.items() if k not in ("delta1", "delta2", "tau")},
        fresh_seed_check=fresh,
        uncaught_variants=uncaught,
        replay_check=check,
        rule=calib.rule.to_dict(),
        middle_guaranteed=calib.rule.tier.middle_guaranteed,
        refused={f"{d1:g}/{d2:g}": why for (d1, d2), why in calib.refused.items()},
    )
