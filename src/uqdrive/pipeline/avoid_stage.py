"""The `avoid` stage: real-time collision avoidance with the three-tier warning system (the paper's section
"Real-time Collision Avoidance"), for one controller of the `avoid` experiment (or of a Gymnasium world's:
conf/gym_avoid.yaml).

On the obstacle road (or in the Gymnasium world), one cell per condition × warnings mode, every cell on the same
seeds: the known condition (the training weather; the world as collected) and the unknown ones (a cell per variant,
or one mixture cell), warnings off and on (the configured thresholds). Thresholds are then calibrated on the
warnings-off rollouts and checked in closed loop on fresh seeds (off again and calibrated). A cell whose rollout log
holds its identity is replayed, not rerun.
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
from uqdrive.avoid.calibration import Calibration, calibrate
from uqdrive.avoid.cells import Cell, distances, panel, traces_of
from uqdrive.avoid.figure import (
    avoid_signals_figure,
    avoid_tradeoff_figure,
    avoid_trajectories,
    avoid_trajectories_figure,
)
from uqdrive.avoid.outputs import write_cell_data, write_cell_table, write_signals, write_tradeoff
from uqdrive.avoid.plan import AvoidSettings, build_settings
from uqdrive.avoid.results import AvoidResult, Mode
from uqdrive.avoid.trace_replay import Traces
from uqdrive.figures import save_figure
from uqdrive.policy.warnings import WarningRule
from uqdrive.records import as_dict, write_record
from uqdrive.replay.video import worst_clips
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.runner import CellRunner, estimate_key
from uqdrive.sim.condition import Condition, Mixture
from uqdrive.tracking import log_artifact_as, numeric_metrics, stage_run

Cells = dict[tuple[str, Mode], Cell]


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
    return Cell(name, where.name, mode, rule, run.outcome, run.results, run.seconds, run.reused, base_seed)


def calibration_of(settings: AvoidSettings, cells: Cells) -> tuple[Calibration, Traces]:
    """Learn-then-Test over the warnings-off cells' fixed sample of runs: the thresholds and their replay traces."""
    c, names = settings.calibration, [k.name for k in settings.conditions]
    traces = traces_of([cells[name, Mode.OFF] for name in names], settings.geometries(), settings.fixed_rollouts())
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
    return calib, traces


def drive(settings: AvoidSettings) -> tuple[Cells, Calibration, Traces]:
    """Every cell: warnings off and on on the stage's seeds, then, with the calibrated thresholds, off and
    calibrated on the fresh seeds."""
    cells: Cells = {}
    with CellRunner.of(settings.executor, settings.progress) as runner:
        for where in settings.conditions:
            off = cells[where.name, Mode.OFF] = run_cell(runner, settings, where, Mode.OFF, settings.rule)
            cells[where.name, Mode.ON] = run_cell(runner, settings, where, Mode.ON, settings.rule, off)
        calib, traces = calibration_of(settings, cells)
        calibrated = calib.rule  # the rule certified is the rule deployed
        for where in settings.conditions:  # the known condition's fresh runs: as many as the fresh-seed check needs
            floor = settings.calibration.fresh_runs() if where is settings.known else 0
            fresh = cells[where.name, Mode.FRESH_OFF] = run_cell(
                runner, settings, where, Mode.FRESH_OFF, calibrated, floor=floor
            )
            cells[where.name, Mode.CALIBRATED] = run_cell(
                runner, settings, where, Mode.CALIBRATED, calibrated, fresh, floor
            )
    return cells, calib, traces


def plot(settings: AvoidSettings, cells: Cells, calib: Calibration) -> dict[str, plt.Figure]:
    """Per cell its paths coloured by mutual information; the grid of them; η2 and MI approaching the obstacle
    (warnings off); the calibration's trade-off front."""
    geometries, names = settings.geometries(), [c.name for c in settings.conditions]
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
    title = f"{settings.name}, warnings off: uncertainty approaching " + ("the obstacle" if known else "the run's end")
    figures["warnings"] = avoid_signals_figure(signals, settings.rule.config, calib.rule.config, title, known.label)
    title = f"{settings.name}: unknown-condition safety against known autonomy (replayed)"
    figures["tradeoff"] = avoid_tradeoff_figure(
        calib.table, calib.chosen, configured_index(calib, settings), calib.target, title
    )
    return figures


def configured_index(calib: Calibration, settings: AvoidSettings) -> int | None:
    """Row of the configured thresholds among the candidates (None if they are off the grids)."""
    t, w = calib.table, settings.rule.config
    hit = np.flatnonzero(
        np.isclose(t["delta1"], w.delta1) & np.isclose(t["delta2"], w.delta2) & np.isclose(t["tau"], w.tau)
    )
    return int(hit[0]) if hit.size else None


def write_files(settings: AvoidSettings, cells: Cells, calib: Calibration, figures: dict[str, plt.Figure]) -> dict:
    """Per-cell tables and traces, the signals and trade-off plot data, the figures; returns the paths by name."""
    data_dir, plots_dir = Path(settings.stage.avoid.data_dir), Path(settings.stage.avoid.plots_dir)
    geometries, names = settings.geometries(), [c.name for c in settings.conditions]
    paths = {name: save_figure(fig, plots_dir / f"{name}.png") for name, fig in figures.items()}
    for (condition, _), cell in cells.items():
        paths[f"cells/{cell.name}.csv"] = write_cell_table(plots_dir / "cells" / f"{cell.name}.csv", cell)
        write_cell_data(data_dir / "traces" / f"{cell.name}.npz", cell, geometries[condition])
    paths["tradeoff.csv"] = write_tradeoff(plots_dir / "tradeoff.csv", calib)
    paths["signals.csv"] = write_signals(plots_dir / "signals.csv", [cells[c, Mode.OFF] for c in names], geometries)
    return paths


def log(cfg: DictConfig, settings: AvoidSettings, cells: Cells, result: AvoidResult, paths: dict) -> None:
    """An MLflow run per cell (condition and warnings first, its thresholds and n; tagged ``reused`` when nothing
    was simulated) and one for the calibration with the stage's figures and plot data."""
    root = settings.stage.paths.root
    for (condition, mode), cell in cells.items():
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
    k = result.calibration
    with stage_run(root, "avoid", cfg, run_name=f"calibration · {settings.method} seed{settings.seed}"):
        mlflow.log_params(
            {
                "calibrated_delta1": k.delta1,
                "calibrated_delta2": k.delta2,
                "calibrated_tau": k.tau,
                "autonomy_target": k.autonomy_target,
                "calibration_certified": k.certified,
                "fresh_seed_p_value": k.fresh_seed_check.p_value,
                "fresh_seed_target_met": k.fresh_seed_check.target_met,
            }
        )
        mlflow.log_metrics({f"replayed_{key}": float(v) for key, v in k.replayed.items()})
        mlflow.log_metrics({f"unknown_{mode}_eta1": m.eta1 for mode, m in result.unknown.items()})
        for key in ("trajectories", "warnings", "tradeoff", "tradeoff.csv", "signals.csv"):
            mlflow.log_artifact(str(paths[key]))


def run_avoid(cfg: DictConfig) -> AvoidResult:
    """All cells of one method, the calibration and its closed-loop check: drive, compute, plot, write, log."""
    settings = build_settings(cfg)
    start = time.perf_counter()
    cells, calib, traces = drive(settings)
    result = avoid_result(settings, cells, calib, traces, settings.geometries(), time.perf_counter() - start)
    paths = write_files(settings, cells, calib, plot(settings, cells, calib))
    write_record(settings.stage.avoid.out, result)
    paths |= write_clips(settings, cells, result)
    log(cfg, settings, cells, result, paths)
    return result


def write_clips(settings: AvoidSettings, cells: Cells, result: AvoidResult) -> dict[str, list[Path]]:
    """Each cell's worst `avoid.clips` failures re-driven (with the cell's warnings) as clips: the MP4s by cell."""
    where, folder = {c.name: c for c in settings.conditions}, Path(settings.stage.avoid.data_dir) / "clips"
    clips = {}
    for (condition, mode), cell in cells.items():
        job = settings.job(where[condition], None if mode.warnings_off else cell.rule, cell.base_seed)
        failures = result.cell(condition, mode).failures
        title = f"{settings.method} seed{settings.seed} {condition} warnings {mode}"
        drawn = worst_clips(job, failures, title, folder, cell.name, settings.stage.avoid.clips)
        clips[f"clips/{cell.name}"] = [clip.mp4 for clip in drawn]
    return clips
