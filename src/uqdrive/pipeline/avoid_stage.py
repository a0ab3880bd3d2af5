"""The `avoid` stage: real-time collision avoidance with the three-tier warning system (the paper's section
"Real-time Collision Avoidance"), for one controller of the `avoid` experiment (or of a Gymnasium world's:
conf/gym_avoid.yaml), or a user's policy that gives draws (``avoid.policy``).

On the obstacle road (or in the Gymnasium world), one cell per condition × warnings mode, every cell on the same
seeds: the known condition (the training weather; the world as collected) and the unknown ones (a cell per variant,
or one mixture cell), warnings off and on (the configured thresholds). Thresholds are then calibrated on the
warnings-off rollouts and checked in closed loop on fresh seeds (off again and calibrated). A cell whose rollout log
holds its identity is replayed, not rerun. The drive computes all of it once (`uqdrive.avoid.cells.AvoidRun`); the
answers, figures, files and MLflow runs read that.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import matplotlib.pyplot as plt
import mlflow
import numpy as np
from omegaconf import DictConfig

from uqdrive.avoid.answers import avoid_result
from uqdrive.avoid.calibration import Calibration, calibrate, fresh_seed_check, replay_check
from uqdrive.avoid.cells import (
    AvoidRun,
    Cell,
    cell_arrays,
    handed_over,
    panel,
    rollout_rows,
    signal_rows,
    traces_of,
)
from uqdrive.avoid.course import distances
from uqdrive.avoid.figure import (
    avoid_signals_figure,
    avoid_tradeoff_figure,
    avoid_trajectories,
    avoid_trajectories_figure,
)
from uqdrive.avoid.outputs import write_cell_data, write_tradeoff
from uqdrive.avoid.plan import AvoidSettings, build_settings
from uqdrive.avoid.results import AvoidResult, Mode
from uqdrive.figures import save_figure
from uqdrive.files import write_csv
from uqdrive.policy.warnings import WarningConfig, WarningRule
from uqdrive.records import as_dict, write_record
from uqdrive.replay.video import worst_clips
from uqdrive.safety.failures import job_failures
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.runner import CellRunner, estimate_key
from uqdrive.sim import ScenarioGeometry
from uqdrive.sim.condition import Condition, Mixture
from uqdrive.tracking import log_artifact_as, numeric_metrics, stage_run


def unchanged_by(rule: WarningRule, off: Cell) -> dict[int, RolloutResult]:
    """Warnings-off rollouts in which ``rule`` never fires on the recorded draws: with warnings on, the same seed
    gives the same frames and the same draws (each frame's streams are its own), no action ever changes a command,
    so the outcome and path are identical (the per-frame η2 and MI traces are the off run's, read to the cap)."""
    return {i: r for i, r in enumerate(off.results) if not (rule.levels(r.eta2_counts, r.mi_stages) >= 0).any()}


def run_cell(
    runner: CellRunner,
    settings: AvoidSettings,
    where: Condition | Mixture,
    mode: Mode,
    rule: WarningRule,
    off: Cell | None = None,
    floor: int = 0,
) -> Cell:
    """η̂1 of one cell; the rollouts its log already holds (same identity) are replayed, not rerun, so a finished
    cell costs nothing on a rerun and an interrupted one resumes. Warnings-off modes drive without warnings, on
    the same draws (``rule``'s are only counted); fresh modes drive the validation seeds. ``off``: the warnings-off
    cell on the same seeds, whose rollouts the rule never changes are reused. ``floor``: runs the cell makes at
    least, beside the stage's own floor (the fresh-seed check's)."""
    base_seed = settings.validation_seed if mode.fresh else settings.estimator.base_seed
    estimator = dataclasses.replace(settings.estimator, base_seed=base_seed)
    job = settings.job(where, None if mode.warnings_off else rule, base_seed)
    name = f"{settings.name}-{where.name}-{mode}"
    run = runner.estimate(
        f"avoid {name}",
        job,
        estimator,
        estimate_key(job, estimator, __name__),
        Path(settings.stage.avoid.rollout_log) / f"{name}.jsonl",
        reuse=unchanged_by(rule, off) if off is not None else None,
        floor=max(settings.min_rollouts, floor),
    )
    failures = job_failures(settings.job(where, None, base_seed), run.results)
    return Cell(name, where.name, mode, rule, run.outcome, run.results, run.seconds, run.reused, base_seed, failures)


def calibration_of(
    settings: AvoidSettings,
    cells: dict[tuple[str, Mode], Cell],
    names: list[str],
    geometries: dict[str, ScenarioGeometry | None],
) -> tuple[Calibration, dict[str, dict[str, float]]]:
    """Learn-then-Test over the warnings-off cells' fixed sample of runs, and the replay at the configured
    thresholds (replayed with the candidates) against the warnings-on cells on the same seeds."""
    c = settings.calibration
    traces = traces_of([cells[name, Mode.OFF] for name in names], geometries, settings.fixed_rollouts())
    calib = calibrate(
        traces,
        names,
        settings.rule,
        list(c.deltas),
        list(c.taus),
        c.autonomy_target,
        c.gamma,
        missed_limit=c.missed_limit,
        calibration_fraction=c.calibration_fraction,
        order=c.order,
        **settings.replay_args(),
    )
    closed_loop = [[r.verdict.safe for r in cells[name, Mode.ON].results] for name in names]
    return calib, replay_check(calib, traces.group, names, closed_loop)


def drive(settings: AvoidSettings) -> AvoidRun:
    """Every cell: warnings off and on on the stage's seeds, the calibration, then, with the calibrated thresholds,
    off and calibrated on the fresh seeds, and the fresh-seed check of the deployed rule."""
    start, cells = time.perf_counter(), {}
    names, geometries = [c.name for c in settings.conditions], settings.geometries()
    with CellRunner.of(settings.executor, settings.progress) as runner:
        for where in settings.conditions:
            off = cells[where.name, Mode.OFF] = run_cell(runner, settings, where, Mode.OFF, settings.rule)
            cells[where.name, Mode.ON] = run_cell(runner, settings, where, Mode.ON, settings.rule, off)
        calib, check = calibration_of(settings, cells, names, geometries)
        calibrated = calib.rule  # the rule certified is the rule deployed
        for where in settings.conditions:  # the known condition's fresh runs: as many as the fresh-seed check needs
            floor = settings.calibration.fresh_runs() if where is settings.known else 0
            fresh = cells[where.name, Mode.FRESH_OFF] = run_cell(
                runner, settings, where, Mode.FRESH_OFF, calibrated, floor=floor
            )
            cells[where.name, Mode.CALIBRATED] = run_cell(
                runner, settings, where, Mode.CALIBRATED, calibrated, fresh, floor
            )
    sizing = settings.calibration
    handed = handed_over(cells[names[0], Mode.CALIBRATED])[: sizing.fresh_runs()]
    fresh_check = fresh_seed_check(handed, sizing.fresh_check.target, sizing.fresh_level())
    return AvoidRun(settings, names, geometries, cells, calib, check, fresh_check, time.perf_counter() - start)


def plot(run: AvoidRun) -> dict[str, plt.Figure]:
    """Per cell its paths coloured by mutual information; the grid of them; η2 and MI approaching the obstacle
    (warnings off); the calibration's trade-off front."""
    settings, cells, calib, geometries, names = run.settings, run.cells, run.calibration, run.geometries, run.names
    figures = {}
    for (condition, mode), cell in cells.items():
        fig, ax = plt.subplots(figsize=(8, 2.6))
        p = panel(cell, geometries[condition])
        title = f"{settings.name} · {condition}, warnings {mode}: {p['title']}"
        fig.colorbar(avoid_trajectories(ax, p, title), ax=ax, label="mutual information (nats)", extend="max")
        figures[f"cells/{cell.name}"] = fig
    panels = {(c, m): panel(cells[c, m], geometries[c]) for c in names for m in Mode}
    title = f"{settings.name}: paths coloured by mutual information"
    figures["trajectories"] = avoid_trajectories_figure(panels, names, [str(m) for m in Mode], title)
    signals = {
        c: [
            (distances(r, geometries[c]), r.eta2, r.mutual_information, r.termination)
            for r in cells[c, Mode.OFF].results
        ]
        for c in names
    }
    known = geometries[names[0]]
    approaching = "the obstacle" if known.fixed_hazard else "the run's end"
    title = f"{settings.name}, warnings off: uncertainty approaching {approaching}"
    figures["warnings"] = avoid_signals_figure(signals, settings.rule.config, calib.rule.config, title, known.label)
    title = f"{settings.name}: unknown-condition safety against known autonomy (replayed)"
    target = calib.certificate.autonomy_target
    figures["tradeoff"] = avoid_tradeoff_figure(
        calib.table, calib.chosen, configured_index(calib.table, settings.rule.config), target, title
    )
    return figures


def configured_index(t: dict[str, np.ndarray], w: WarningConfig) -> int | None:
    """Row of the configured thresholds ``w`` among the candidates of table ``t`` (None if off the grids)."""
    hit = np.flatnonzero(
        np.isclose(t["delta1"], w.delta1) & np.isclose(t["delta2"], w.delta2) & np.isclose(t["tau"], w.tau)
    )
    return int(hit[0]) if hit.size else None


def write_files(run: AvoidRun, figures: dict[str, plt.Figure]) -> dict:
    """Per-cell tables and traces, the signals and trade-off plot data, the figures; returns the paths by name."""
    avoid = run.settings.stage.avoid
    data_dir, plots_dir = Path(avoid.data_dir), Path(avoid.plots_dir)
    paths = {name: save_figure(fig, plots_dir / f"{name}.png") for name, fig in figures.items()}
    for (condition, _), cell in run.cells.items():
        paths[f"cells/{cell.name}.csv"] = write_csv(plots_dir / "cells" / f"{cell.name}.csv", rollout_rows(cell))
        write_cell_data(data_dir / "traces" / f"{cell.name}.npz", cell_arrays(cell, run.geometries[condition]))
    paths["tradeoff.csv"] = write_tradeoff(plots_dir / "tradeoff.csv", run.calibration.table)
    off = [run.cells[c, Mode.OFF] for c in run.names]
    paths["signals.csv"] = write_csv(plots_dir / "signals.csv", signal_rows(off, run.geometries))
    return paths


def log(cfg: DictConfig, run: AvoidRun, result: AvoidResult, paths: dict, clip_seconds: float) -> None:
    """An MLflow run per cell (condition and warnings first, its thresholds and n; tagged ``reused`` when nothing
    was simulated) and one for the calibration with the stage's figures and plot data and the seconds its clips
    took."""
    settings, root = run.settings, run.settings.stage.paths.root
    for (condition, mode), cell in run.cells.items():
        params = {
            "condition": condition,
            "warnings": str(mode),
            "delta1": cell.rule.config.delta1,
            "delta2": cell.rule.config.delta2,
            "tau": cell.rule.config.tau,
            "samples_per_frame": cell.rule.cap,
            "tier_error": cell.rule.tier.error,
            "middle_guaranteed": cell.rule.tier.middle_guaranteed,
            "n": cell.estimate.n,
        }
        name = f"{condition} {mode} · {settings.method} seed{settings.seed}"  # what tells sibling runs apart first
        tags = {"reused": str(cell.reused).lower(), "cell": cell.name}
        with stage_run(root, "avoid", cfg, run_name=name, tags=tags):
            mlflow.log_params(params)
            mlflow.log_metrics(numeric_metrics(as_dict(result.cell(condition, mode))))
            log_artifact_as(paths[f"cells/{cell.name}"], "paths.png")
            log_artifact_as(paths[f"cells/{cell.name}.csv"], "rollouts.csv")
            for clip in paths.get(f"clips/{cell.name}", []):  # a failure's clip, by its cell and seed
                mlflow.log_artifact(str(clip), artifact_path="failures")
    k, fresh = result.calibration.certificate, result.calibration.fresh_seed_check.check
    with stage_run(root, "avoid", cfg, run_name=f"calibration · {settings.method} seed{settings.seed}"):
        mlflow.log_params(
            {
                "calibrated_delta1": k.delta1,
                "calibrated_delta2": k.delta2,
                "calibrated_tau": k.tau,
                "autonomy_target": k.autonomy_target,
                "calibration_certified": k.certified,
                "fresh_seed_p_value": fresh.p_value,
                "fresh_seed_target_met": fresh.target_met,
            }
        )
        mlflow.log_metrics({f"replayed_{key}": float(v) for key, v in k.replayed.items()})
        mlflow.log_metrics({f"unknown_{mode}_eta1": m.eta1 for mode, m in result.unknown.items()})
        mlflow.log_metric("clip_seconds", clip_seconds)
        for key in ("trajectories", "warnings", "tradeoff", "tradeoff.csv", "signals.csv"):
            mlflow.log_artifact(str(paths[key]))


def run_avoid(cfg: DictConfig) -> AvoidResult:
    """All cells of one method, the calibration and its closed-loop check: drive, compute, plot, write, log."""
    run = drive(build_settings(cfg))
    result = avoid_result(run)
    paths = write_files(run, plot(run))
    write_record(run.settings.stage.avoid.out, result)
    started = time.perf_counter()
    paths |= write_clips(run, result)
    log(cfg, run, result, paths, clip_seconds=time.perf_counter() - started)
    return result


def write_clips(run: AvoidRun, result: AvoidResult) -> dict[str, list[Path]]:
    """Each cell's worst `avoid.clips` failures re-driven (with the cell's warnings) as clips: the MP4s by cell."""
    settings = run.settings
    where, folder = {c.name: c for c in settings.conditions}, Path(settings.stage.avoid.data_dir) / "clips"
    clips = {}
    for (condition, mode), cell in run.cells.items():
        job = settings.job(where[condition], None if mode.warnings_off else cell.rule, cell.base_seed)
        failures = result.cell(condition, mode).failures
        title = f"{settings.method} seed{settings.seed} {condition} warnings {mode}"
        drawn = worst_clips(job, failures, title, folder, cell.name, settings.stage.avoid.clips)
        clips[f"clips/{cell.name}"] = [clip.mp4 for clip in drawn]
    return clips
