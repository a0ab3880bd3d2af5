"""The `avoid` stage: real-time collision avoidance with the three-tier warning system (the paper's
section "Real-time Collision Avoidance"), for one controller of the `avoid` experiment.

On the obstacle road, one cell per condition × warnings mode, every cell on the same seeds:
conditions `known` (the training weather) and each unknown variant on its own (other weathers,
sensor noise, another obstacle car: a fixed number of runs each, so every variant has its own
interval and the unknown mixture is their mean); modes `off` and `on` (the configured
thresholds). Thresholds are then calibrated on the warnings-off rollouts (the most unknown-condition
safety whose known-condition autonomy bound meets the target) and checked in closed loop
(`calibrated`) on fresh seeds. A cell whose rollout log holds its identity is reused, not rerun.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from omegaconf import DictConfig

from uqdrive.pipeline.avoid_cells import Cell, traces_of
from uqdrive.pipeline.avoid_config import AvoidSettings, Condition, build_settings
from uqdrive.pipeline.avoid_outputs import write_outputs
from uqdrive.pipeline.records import FRESH, WARNINGS_OFF
from uqdrive.safety.calibration import calibrate
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.runner import CellRunner, estimate_key
from uqdrive.safety.warnings import WarningConfig, classify


def unchanged_by(warning: WarningConfig, off: Cell) -> dict[int, RolloutResult]:
    """Warnings-off rollouts in which ``warning`` never fires: with warnings on, the same seed gives the
    same frames, draws and measures, no action ever changes a command, so the rollout is identical."""
    return {
        i: r
        for i, r in enumerate(off.results)
        if not (classify(r.eta2, r.mutual_information, warning.delta1, warning.delta2, warning.tau) >= 0).any()
    }


def run_cell(
    runner: CellRunner,
    cfg: DictConfig,
    settings: AvoidSettings,
    condition: Condition,
    mode: str,
    warning: WarningConfig,
    off: Cell | None = None,
) -> Cell:
    """η̂1 of one cell; the rollouts its log already holds (same identity) are replayed, not rerun, so a finished
    cell costs nothing on a rerun and an interrupted one resumes. The modes off and fresh_off drive without
    warnings (``warning``'s are only counted); fresh_off and calibrated drive the validation seeds. ``off``: the
    warnings-off cell on the same seeds, whose rollouts no warning would change are reused exactly (with fixed
    draws only: sequential draws differ between a controller that acts on warnings and one that does not)."""
    base_seed = settings.validation_seed if mode in FRESH else settings.estimator.base_seed
    estimator = dataclasses.replace(settings.estimator, base_seed=base_seed)
    job = settings.job(condition, None if mode in WARNINGS_OFF else warning, base_seed)
    name = f"{settings.name}-{condition.name}-{mode}"
    run = runner.estimate(
        f"avoid {name}",
        job,
        estimator,
        estimate_key(job, estimator, __name__),
        Path(cfg.avoid.rollout_log) / f"{name}.jsonl",
        reuse=unchanged_by(warning, off) if off is not None and settings.spec.draws.scheme == "fixed" else None,
        floor=settings.min_rollouts,
    )
    return Cell(name, condition.name, mode, warning, run.outcome, run.results, run.seconds, run.reused, base_seed)


def run_avoid(cfg: DictConfig) -> dict:
    """All cells of one method, the calibration and its closed-loop check; writes metrics, data, figures, runs."""
    settings = build_settings(cfg)
    geometries = settings.geometries()
    start = time.perf_counter()
    cells: dict[tuple[str, str], Cell] = {}
    with CellRunner.of(settings.executor, settings.progress) as runner:
        for condition in settings.conditions:
            off = cells[condition.name, "off"] = run_cell(runner, cfg, settings, condition, "off", settings.warning)
            cells[condition.name, "on"] = run_cell(runner, cfg, settings, condition, "on", settings.warning, off)
        c, names = settings.calibration, [k.name for k in settings.conditions]
        traces = traces_of([cells[name, "off"] for name in names], geometries, settings.fixed_rollouts())
        calib = calibrate(
            traces,
            names,
            settings.warning,
            list(c.deltas),
            list(c.taus),
            c.autonomy_target,
            c.gamma,
            missed_limit=c.missed_limit,
            calibration_fraction=c.calibration_fraction,
            order=c.order,
            **settings.replay_args(),
        )
        calibrated = settings.warning.with_thresholds(calib.delta1, calib.delta2, calib.tau)
        for condition in settings.conditions:
            fresh = cells[condition.name, "fresh_off"] = run_cell(
                runner, cfg, settings, condition, "fresh_off", calibrated
            )
            cells[condition.name, "calibrated"] = run_cell(
                runner, cfg, settings, condition, "calibrated", calibrated, fresh
            )
    return write_outputs(cfg, settings, cells, calib, traces, geometries, time.perf_counter() - start)
