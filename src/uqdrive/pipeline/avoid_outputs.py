"""What the `avoid` stage writes once its cells are done: per-cell tables, traces, figures and MLflow
runs; the unknown conditions' mixture; the calibration with its front and the variants no threshold
catches; metrics/avoid/<method>.json.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import mlflow
import numpy as np
from omegaconf import DictConfig

from uqdrive.pipeline.avoid_cells import (
    Cell,
    cell_metrics,
    distances,
    panel,
    write_cell_data,
    write_cell_table,
    write_signals,
    write_tradeoff,
)
from uqdrive.pipeline.avoid_config import AvoidSettings
from uqdrive.pipeline.avoid_mixture import variant_of
from uqdrive.pipeline.records import (
    MODES,
    AvoidCell,
    AvoidResult,
    CalibrationSummary,
    Mixture,
    as_dict,
    write_record,
)
from uqdrive.plots import (
    avoid_signals_figure,
    avoid_tradeoff_figure,
    avoid_trajectories,
    avoid_trajectories_figure,
    save_figure,
)
from uqdrive.safety.calibration import Calibration, Traces, replay
from uqdrive.sim import ScenarioGeometry
from uqdrive.tracking import numeric_metrics, stage_run
from uqdrive.uq.pooled import pooled


def unknown_mixture(cells: list[Cell], metrics: list[AvoidCell], gamma: float, settings: AvoidSettings) -> Mixture:
    """η̂1 of the unknown conditions as one uniform mixture: of their cells (Hoeffding interval, fixed n), or the
    mixture cell's own estimate (its rollouts drew their variant) with each variant's share of its fixed sample."""
    variants = settings.unknown[0].variants
    if variants:
        (cell,), est = cells, cells[0].estimate
        first = cell.results[: settings.fixed_rollouts()]
        drawn = [variant_of(cell.base_seed + i, len(variants)) for i in range(len(first))]
        shares = {
            item.name: {"runs": drawn.count(v), "safe": sum(r.safe for r, d in zip(first, drawn) if d == v)}
            for v, item in enumerate(variants)
        }
        interval = f"{est.scheme} (one cell, each rollout's variant drawn from its seed)"
        return Mixture(est.value, est.low, est.high, est.theta, est.gamma, est.n, metrics[0].autonomy, interval, shares)
    p = pooled([sum(r.safe for r in c.results) for c in cells], [len(c.results) for c in cells], gamma)
    autonomy = float(np.mean([m.autonomy for m in metrics]))
    return Mixture(p.value, p.low, p.high, p.theta, gamma, p.n, autonomy, "hoeffding (uniform mixture of the cells)")


def uncaught_variants(calib: Calibration, cells: dict[tuple[str, str], Cell], names: list[str]) -> list[dict]:
    """Unknown conditions with unsafe warnings-off runs that no candidate's replay saves at all: a confident
    controller that does not see the danger. Named in the report as a finding."""
    out = []
    for name in names:
        off = cells[name, "off"]
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
    w = settings.warning
    out = replay(traces, np.array([w.delta1]), np.array([w.delta2]), np.array([w.tau]), w, **settings.replay_args())
    check = {}
    for g, name in enumerate(calib_groups):
        replayed = out.safe[0, traces.group == g]
        safe = np.array([r.safe for r in cells[name, "on"].results[: len(replayed)]])
        check[name] = {
            "replayed_eta1": float(replayed.mean()),
            "closed_loop_eta1": float(safe.mean()),
            "agreement": float(np.mean(replayed == safe)),
        }
    return check


def calibration_summary(calib: Calibration, uncaught: list[dict], check: dict, fresh: dict) -> CalibrationSummary:
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
    )


def _log_run(cfg: DictConfig, settings: AvoidSettings, cell: Cell, metrics: AvoidCell, artifacts: list[Path]) -> str:
    """The cell's run: the stage's config (`stage_run`) plus what is the cell's own (condition, warnings mode, the
    thresholds it drove with, n); tagged ``reused`` when nothing was simulated."""
    params = {
        "condition": cell.condition,
        "warnings": cell.mode,
        "delta1": cell.warning.delta1,
        "delta2": cell.warning.delta2,
        "tau": cell.warning.tau,
        "samples_per_frame": cell.warning.samples,
        "n": cell.estimate.n,
    }
    with stage_run(cfg.paths.root, "avoid", cfg, run_name=cell.name, tags={"reused": str(cell.reused).lower()}) as run:
        mlflow.log_params(params)
        mlflow.log_metrics(numeric_metrics(as_dict(metrics)))
        for path in artifacts:
            mlflow.log_artifact(str(path))
        return run.info.run_id


def write_outputs(
    cfg: DictConfig,
    settings: AvoidSettings,
    cells: dict[tuple[str, str], Cell],
    calib: Calibration,
    traces: Traces,
    geometries: dict[str, ScenarioGeometry],
    seconds: float,
) -> AvoidResult:
    """Everything the stage writes, from its finished cells and calibration; returns what metrics/avoid/<name>.json
    holds."""
    data_dir, plots_dir = Path(cfg.avoid.data_dir), Path(cfg.avoid.plots_dir)
    names = [c.name for c in settings.conditions]
    unknown = names[1:]
    table: dict[str, dict[str, AvoidCell]] = {name: {} for name in names}
    run_ids: dict[str, str | None] = {}
    fixed, family = settings.fixed_rollouts(), settings.family_size
    for (condition, mode), cell in cells.items():
        geometry = geometries[condition]
        metrics = cell_metrics(cell, settings.spec.speed, geometry, fixed, family)
        csv_path = write_cell_table(plots_dir / "cells" / f"{cell.name}.csv", cell)
        write_cell_data(data_dir / "traces" / f"{cell.name}.npz", cell, geometry)
        fig, ax = plt.subplots(figsize=(8, 2.6))
        p = panel(cell, geometry)
        fig.colorbar(
            avoid_trajectories(ax, p, f"{settings.name} · {condition}, warnings {mode}: {p['title']}"),
            ax=ax,
            label="mutual information (nats)",
            extend="max",
        )
        png = save_figure(fig, plots_dir / "cells" / f"{cell.name}.png")
        run_ids[cell.name] = _log_run(cfg, settings, cell, metrics, [csv_path, png])
        table[condition][mode] = metrics
    mixture = {
        mode: unknown_mixture(
            [cells[name, mode] for name in unknown],
            [table[name][mode] for name in unknown],
            settings.estimator.gamma,
            settings,
        )
        for mode in MODES
    }
    known = table[names[0]]["calibrated"]
    check = replay_check(cells, names, settings, traces)
    fresh = {
        "known_autonomy": known.autonomy,
        "known_eta1": known.eta1,
        "unknown_eta1": mixture["calibrated"].eta1,
        "base_seed": settings.validation_seed,
        "target_met": known.autonomy >= calib.target,
    }
    calibration = calibration_summary(calib, uncaught_variants(calib, cells, unknown), check, fresh)
    calibrated = settings.warning.with_thresholds(calib.delta1, calib.delta2, calib.tau)
    configured = _configured_index(calib, settings)
    figures = [
        save_figure(
            avoid_trajectories_figure(
                {(c, m): panel(cells[c, m], geometries[c]) for c in names for m in MODES},
                names,
                list(MODES),
                f"{settings.name}: paths coloured by mutual information",
            ),
            plots_dir / "trajectories.png",
        ),
        save_figure(
            avoid_signals_figure(
                {
                    c: [
                        (distances(r, geometries[c]), r.eta2, r.mutual_information, r.termination)
                        for r in cells[c, "off"].results
                    ]
                    for c in names
                },
                settings.warning,
                calibrated,
                f"{settings.name}, warnings off: uncertainty approaching the obstacle",
            ),
            plots_dir / "warnings.png",
        ),
        save_figure(
            avoid_tradeoff_figure(
                calib.table,
                calib.chosen,
                configured,
                calib.target,
                f"{settings.name}: unknown-condition safety against known autonomy (replayed)",
            ),
            plots_dir / "tradeoff.png",
        ),
    ]
    data_files = [
        write_tradeoff(plots_dir / "tradeoff.csv", calib),
        write_signals(plots_dir / "signals.csv", [cells[c, "off"] for c in names], geometries),
    ]
    with stage_run(cfg.paths.root, "avoid", cfg, run_name=f"{settings.name}-calibration") as run:
        mlflow.log_params(
            {
                "calibrated_delta1": calib.delta1,
                "calibrated_delta2": calib.delta2,
                "calibrated_tau": calib.tau,
                "autonomy_target": calib.target,
                "calibration_certified": calib.certified,
            }
        )
        mlflow.log_metrics({f"replayed_{k}": float(v) for k, v in calibration.replayed.items()})
        mlflow.log_metrics({f"unknown_{mode}_eta1": m.eta1 for mode, m in mixture.items()})
        for path in [*figures, *data_files]:
            mlflow.log_artifact(str(path))
        run_ids["calibration"] = run.info.run_id
    result = AvoidResult(
        method=settings.method,
        replicate=settings.seed,
        experiment=cfg.experiment.name,
        cells=table,
        unknown=mixture,
        calibration=calibration,
        warning=settings.warning.to_dict(),
        samples_per_frame=settings.warning.samples,
        conditions=names,
        horizon_s=settings.horizon_s,
        speed=settings.spec.speed,
        seconds=seconds,
        mlflow_run_ids=run_ids,
    )
    write_record(cfg.avoid.out, result)
    return result


def _configured_index(calib: Calibration, settings: AvoidSettings) -> int | None:
    """Row of the configured thresholds among the candidates (None if they are off the grids)."""
    t, w = calib.table, settings.warning
    hit = np.flatnonzero(
        np.isclose(t["delta1"], w.delta1) & np.isclose(t["delta2"], w.delta2) & np.isclose(t["tau"], w.tau)
    )
    return int(hit[0]) if hit.size else None
