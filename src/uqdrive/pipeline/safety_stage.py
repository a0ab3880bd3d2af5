"""The `safety` stage: η1 of one offline controller in one sweep cell (method × replicate × location × weather ×
noise), each cell as the single-cell command composes it, the whole sweep in one process. The location may be a
Gymnasium world (``gym_world=highway_roundabout``: no weather of ours; its sweep varies one of the env's own
conditions, ``sweep.world_axis``, each value a location of its own).

Every cell drives the same rollout seeds (base_seed + i), so methods and conditions are compared
on paired runs: the same start jitter, rain streaks and sensor noise.

Every input is checked (method, model file, estimator, speed, world, executor) before the
first rollout. A cell whose result file already holds its config hash is not run again.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Iterator, Sequence
from contextlib import nullcontext
from functools import partial
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import mlflow
from omegaconf import DictConfig

from uqdrive.figures import save_figure
from uqdrive.files import write_csv
from uqdrive.records import as_dict, read_record, write_record
from uqdrive.replay.video import worst_clips
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.safety.drive import Driver, resolve_driver
from uqdrive.safety.executors import RolloutJob, job_world
from uqdrive.safety.failures import job_failures
from uqdrive.safety.figure import safety_hexbin, visits_colour_bar
from uqdrive.safety.plan import (
    CellPlan,
    SafetyRun,
    SafetySection,
    SafetyStage,
    SafetySweepStage,
    SweepCells,
)
from uqdrive.safety.positions import CellPositions, job_positions, write_positions
from uqdrive.safety.rollout_metrics import summarise
from uqdrive.safety.runner import CellRun, CellRunner, estimate_key
from uqdrive.schema import validate
from uqdrive.stage import cell_overrides, run_cells
from uqdrive.tracking import log_artifact_as, numeric_metrics, stage_parent_run, stage_run
from uqdrive.uq import Estimate


def cell_driver(stage: SafetyStage) -> Driver:
    """What drives the cell (`resolve_driver`): the trained model, loaded as its method's with the experiment's
    classes (a missing or mismatched file is one line naming the key and the stage that trains it), or a user's
    policy (``safety.policy``), its own method, named by its file."""
    s = stage.safety
    return resolve_driver("safety", s, stage, s.samples, stage.condition().native)


def check_model(stage: SafetyStage) -> str:
    """The cell's method, its driver resolved (`cell_driver`): every cell of a sweep is checked before any runs."""
    return cell_driver(stage).method


def plan_cell(cfg: DictConfig) -> CellPlan:
    """Validate the cell's config and resolve what drives it once, before any rollout: a bad config value is one line
    naming the key, the value and what is allowed; a missing or mismatched model file names the stage to run; a
    user's policy is run on the cell's first frame (its file's bytes or its class's source in the cell's key)."""
    stage = validate(SafetyStage, cfg)
    s = stage.safety
    drive = cell_driver(stage)
    where = stage.condition()
    world = job_world(where, stage.camera, stage.vehicle, stage.control_hz, s.horizon_s, s.half_width)
    job = RolloutJob(drive.spec, where, stage.estimator.base_seed, **world)
    drive.probe(job)
    return CellPlan(stage, drive.method, job, estimate_key(job, stage.estimator, __name__))


def reusable_result(path: str | Path, key: str) -> SafetyCell | None:
    """The finished cell at ``path`` if it was computed for the cell with key ``key`` (by this code: a file of
    another format is not reused)."""
    try:
        cell = read_record(SafetyCell, path, "safety")
    except (FileNotFoundError, ValueError):
        return None
    return cell if cell.config_hash == key else None


def safety_cell(plan: CellPlan, run: CellRun[Estimate], overrides: Sequence[str] = ()) -> SafetyCell:
    """The cell's record: η̂1 with its interval and guarantee, how its runs failed (a record per failing run, worst
    margin first), each run's verdict in order, and the ``overrides`` that compose it (`uqdrive replay`)."""
    estimate, results, stage, where = run.outcome, run.results, plan.stage, plan.job.where
    return SafetyCell(
        method=plan.method,
        replicate=stage.seed,
        experiment=stage.experiment.name,
        location=where.location,
        weather=where.weather_name,
        noise=where.noise,
        estimate=dataclasses.replace(estimate, condition=""),
        base_seed=stage.estimator.base_seed,
        family_size=stage.safety.family_size,
        fixed_rollouts=stage.estimator.fixed_rollouts(),
        rollouts=estimate.n,
        steps=int(sum(r.steps for r in results)),
        seconds=run.seconds,
        **summarise(results),
        outcomes="".join("1" if r.verdict.safe else "0" for r in results),  # by rollout index: paired across cells
        config_hash=plan.key,
        unread=run.unread,
        margins=[None if math.isnan(r.verdict.margin) else round(r.verdict.margin, 6) for r in results],
        failures=job_failures(plan.job, results),
        overrides=list(overrides),
    )


def cell_figure(plan: CellPlan, positions: CellPositions, estimate: Estimate) -> plt.Figure:
    where = plan.job.where
    title = (
        f"{plan.method} · {where.location} · {where.weather_name} · noise {where.noise:g}: "
        f"η̂1 = {estimate.value:.2f} [{estimate.low:.2f}, {estimate.high:.2f}]"
    )
    fig, ax = plt.subplots(figsize=(5.6, 5))
    p = positions
    hexagons = safety_hexbin(ax, p.x, p.y, p.route, p.edges, tuple(p.extent), title, p.road)
    ax.legend(loc="lower left", fontsize=7)
    visits_colour_bar(fig, [hexagons] if hexagons is not None else [], [ax])
    return fig


def run_safety(cfg: DictConfig, runner: CellRunner | None = None, overrides: Sequence[str] = ()) -> SafetyRun:
    """Estimate η1 for one cell: plan, drive (the rollouts its log holds are replayed), compute, plot, write, log.
    A cell whose result file holds its key is only logged again. ``runner``: shared by many cells
    (`run_safety_sweep`), else the cell's own; ``overrides``: the Hydra overrides that composed ``cfg``, kept in
    the record so that `uqdrive replay` can compose the cell again."""
    plan = plan_cell(cfg)
    section = plan.stage.safety
    previous = reusable_result(section.out, plan.key)
    if previous is not None:
        seconds = draw_clips(plan, previous, only_missing=True)
        log_cell(cfg, plan.stage, previous, _cell_files(section, previous), reused=True, clip_seconds=seconds)
        return SafetyRun(previous, reused=True)
    with nullcontext(runner) if runner else CellRunner.of(plan.stage.executor, plan.stage.progress) as cells:
        run = cells.estimate(f"safety {section.cell}", plan.job, plan.stage.estimator, plan.key, section.rollout_log)
    positions = job_positions(plan.job, run.results, run.outcome.value)
    cell = safety_cell(plan, run, overrides)
    figure = save_figure(cell_figure(plan, positions, run.outcome), Path(section.plots_dir) / f"{section.cell}.png")
    table = write_csv(Path(section.plots_dir) / f"{section.cell}.csv", [r.summary() for r in run.results])
    write_positions(section.positions, positions)
    write_record(
        section.out, cell
    )  # before logging: a tracking failure never loses the cell; its presence marks it done
    seconds = draw_clips(plan, cell, only_missing=False)
    log_cell(cfg, plan.stage, cell, [figure, table, *_clips_of(section, cell)], run.reused, seconds)
    return SafetyRun(cell, run.reused)


def draw_clips(plan: CellPlan, cell: SafetyCell, only_missing: bool) -> float:
    """Re-drives the cell's worst `safety.clips` failures as clips (a reused cell only those it has no clip of yet,
    so a larger `safety.clips` draws the new ones); returns the seconds it took, logged with the cell so that the
    clips' share of a run is measured, not estimated."""
    section, started = plan.stage.safety, time.perf_counter()
    failures = cell.failures[: section.clips]
    if only_missing:
        failures = [f for f in failures if not _clip_path(section, cell, f.seed).exists()]
    worst_clips(plan.job, failures, _clip_title(cell), section.clips_dir, cell.name, len(failures))
    return time.perf_counter() - started


def sweep_cells(stage: SafetySweepStage) -> list[dict[str, Any]]:
    """The sweep's cells as overrides (`SweepCells`)."""
    return stage.choose(SweepCells(stage.sweep))


def run_safety_sweep(cfg: DictConfig, overrides: Sequence[str]) -> Iterator[tuple[DictConfig, SafetyRun]]:
    """Every cell of ``cfg.sweep`` (`sweep_cells`) in this process, on one cell runner (one pool of workers with the
    process backend); yields each cell's config and result as it finishes (`uqdrive.stage.run_cells`)."""
    stage = validate(SafetySweepStage, cfg)
    cells = sweep_cells(stage)
    if stage.safety.family_wise:  # every cell at γ/m: the whole sweep within ±θ at once with probability ≥ 1 − γ
        cells = [{**cell, "safety.family_size": len(cells)} for cell in cells]
    runner = CellRunner.of(stage.executor, stage.progress)
    parent = partial(stage_parent_run, stage.paths.root, "safety", cfg, overrides, name=f"sweep of {len(cells)} cells")
    each = iter([cell_overrides(overrides, cell) for cell in cells])  # `run_cells` runs the cells in this order

    def run(config: DictConfig, shared: CellRunner) -> SafetyRun:
        return run_safety(config, shared, next(each))

    # every cell's model first: a missing one stops the sweep before any cell runs
    yield from run_cells("safety", overrides, cells, SafetyStage, run, runner, stage.progress, parent, check_model)


def describe(name: str, run: SafetyRun) -> str:
    """The line a stage prints for a finished cell."""
    e = run.cell.estimate
    return (
        f"safety {name}: eta1 = {e.value:.3f} in [{e.low:.3f}, {e.high:.3f}] "
        f"from {e.n} rollouts ({e.scheme}, theta={e.theta:g}, gamma={e.gamma:g})"
        f"{' (reused: config unchanged)' if run.reused else ''}"
    )


CELL_PARAMS = (
    "method",
    "replicate",
    "experiment",
    "location",
    "weather",
    "noise",
    "theta",
    "gamma",
    "scheme",
    "n",
    "base_seed",
    "family_size",
)


CELL_ARTEFACTS = {".png": "paths.png", ".csv": "rollouts.csv"}  # one name in every cell's run (Compare lines them up)


def _cell_files(section: SafetySection, cell: SafetyCell) -> list[Path]:
    """The files a finished cell left: its figure, table and clips."""
    plots = Path(section.plots_dir)
    return [p for p in (plots / f"{section.cell}{suffix}" for suffix in CELL_ARTEFACTS) if p.exists()] + _clips_of(
        section, cell
    )


def _clip_path(section: SafetySection, cell: SafetyCell, seed: int) -> Path:
    return Path(section.clips_dir) / f"{cell.name}-seed{seed}.mp4"


def _clips_of(section: SafetySection, cell: SafetyCell) -> list[Path]:
    """The clips on disk of the cell's worst `safety.clips` failures."""
    worst = (_clip_path(section, cell, f.seed) for f in cell.failures[: section.clips])
    return [p for p in worst if p.exists()]


def _clip_title(cell: SafetyCell) -> str:
    return f"{cell.method} seed{cell.replicate} {cell.location} {cell.weather} noise {cell.noise:g}"


def log_cell(
    cfg: DictConfig, stage: SafetyStage, cell: SafetyCell, artifacts: list[Path], reused: bool, clip_seconds: float
) -> None:
    """One MLflow run per cell, a reused one too (tagged ``reused``), so a sweep's runs list every cell."""
    metrics = numeric_metrics({k: v for k, v in as_dict(cell).items() if k not in CELL_PARAMS})
    metrics["clip_seconds"] = clip_seconds
    name = f"{cell.weather} σ{cell.noise:g} {cell.location} · {cell.method} seed{cell.replicate}"  # siblings differ
    tags = {"reused": str(reused).lower(), "config_hash": cell.config_hash, "cell": stage.safety.cell}
    with stage_run(stage.paths.root, "safety", cfg, run_name=name, tags=tags):
        # the rest: the cell's config (`stage_run`)
        mlflow.log_params({"n": cell.estimate.n, "cell_gamma": cell.estimate.gamma})
        mlflow.log_metrics(metrics)
        for path in artifacts:
            if path.suffix in CELL_ARTEFACTS:
                log_artifact_as(path, CELL_ARTEFACTS[path.suffix])
            else:  # a failure's clip, by its cell and seed
                mlflow.log_artifact(str(path), artifact_path="failures")
