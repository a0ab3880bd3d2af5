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
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
from omegaconf import DictConfig
from tqdm import tqdm

from uqdrive.models.posterior import posterior_from_config
from uqdrive.pipeline.avoid_cells import Cell, traces_of
from uqdrive.pipeline.avoid_config import AvoidStage, CalibrationSettings
from uqdrive.pipeline.avoid_outputs import write_outputs
from uqdrive.pipeline.safety import code_digest
from uqdrive.safety.calibration import calibrate, min_known_runs
from uqdrive.safety.cells import EstimatorSettings, cell_hash, cell_posterior, estimate_safety, file_digest
from uqdrive.safety.executors import (
    Executor,
    PolicySpec,
    ProcessPool,
    RolloutJob,
    executor_options,
    make_executor,
)
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.rollout_log import RolloutLog
from uqdrive.safety.safe_sets import obstacle_pass_progress
from uqdrive.safety.warnings import WarningConfig, classify
from uqdrive.schema import ConfigError, validate
from uqdrive.sim import CameraConfig, ScenarioConfig, ScenarioGeometry, VehicleConfig, WeatherConfig, build_geometry

KNOWN = "known"
MODES = ("off", "on", "calibrated")


@dataclasses.dataclass(frozen=True)
class Condition:
    """Where a cell drives: the world (e.g. another obstacle car), the weather, the sensor noise."""

    name: str
    scenario: ScenarioConfig
    weather: WeatherConfig
    noise: float = 0.0


@dataclasses.dataclass(frozen=True)
class AvoidSettings:
    """Everything a stage run needs, validated; ``spec`` is the warnings-off policy."""

    method: str
    spec: PolicySpec
    model_sha256: str
    warning: WarningConfig
    estimator: EstimatorSettings
    validation_seed: int
    known: Condition
    unknown: tuple[Condition, ...]
    calibration: CalibrationSettings
    camera: CameraConfig
    vehicle: VehicleConfig
    control_hz: float
    horizon_s: float

    @property
    def conditions(self) -> tuple[Condition, ...]:
        return (self.known, *self.unknown)

    def job(self, condition: Condition, warning: WarningConfig | None, base_seed: int) -> RolloutJob:
        """The rollouts of one cell: ``warning`` None drives without the warning system."""
        return RolloutJob(
            policy=dataclasses.replace(self.spec, warnings=warning),
            scenario=condition.scenario,
            weather=condition.weather,
            noise=condition.noise,
            base_seed=base_seed,
            camera=self.camera,
            vehicle=self.vehicle,
            control_hz=self.control_hz,
            horizon_s=self.horizon_s,
        )

    def geometries(self) -> dict[str, ScenarioGeometry]:
        """Road geometry per condition name, for distances along the road."""
        return {c.name: build_geometry(c.scenario) for c in self.conditions}


def _unknown_conditions(stage: AvoidStage) -> tuple[Condition, ...]:
    """The unknown conditions, each a world: the known scenario with the condition's changes, a loaded weather."""
    weathers = {stage.weather.name: stage.weather, **stage.weathers}
    return tuple(
        Condition(
            item.name,
            ScenarioConfig.from_config({**stage.scenario.to_dict(), **item.scenario}),
            weathers[item.weather or stage.weather.name],
            item.noise,
        )
        for item in stage.avoid.unknown
    )


def check_horizon(
    horizon: float, warning: WarningConfig, speed: float, scenario: ScenarioConfig, vehicle: VehicleConfig
) -> float:
    """The horizon must let a run that warnings slow down (but do not stop) pass the obstacle: a timeout
    before it would be a non-answer, neither safe nor a collision."""
    slowest = (
        min(a.speed for a in warning.actions if not a.handover) if any(not a.handover for a in warning.actions) else 1.0
    )
    if slowest <= 0:
        raise ConfigError(
            "warning.actions: a slow-down to speed 0 without a hand-over never passes the obstacle; "
            "give it a speed > 0 or handover: true"
        )
    distance = obstacle_pass_progress(build_geometry(scenario), vehicle.length) - scenario.start_distance
    needed = distance / (slowest * speed) + 1.0  # + 1 s for the start jitter and speed changes
    if horizon < needed:
        raise ConfigError(
            f"avoid.horizon_s={horizon:g} is too short: a run slowed to {slowest * speed:g} m/s needs "
            f"{needed:.1f} s to pass the obstacle ({distance:.0f} m); set at least {np.ceil(needed):g}"
        )
    return horizon


def build_settings(cfg: DictConfig) -> AvoidSettings:
    """Validate the stage's config and the model file; raises before any rollout, naming key and value."""
    stage = validate(AvoidStage, cfg)
    avoid, warning, estimator = stage.avoid, stage.warning, stage.avoid.estimator
    method = posterior_from_config(stage.model).method
    horizon = check_horizon(avoid.horizon_s, warning, avoid.speed, stage.scenario, stage.vehicle)
    calibration = avoid.calibration
    needed = min_known_runs(calibration.autonomy_target, calibration.gamma)
    if estimator.scheme != "sequential" and estimator.planned_rollouts() < needed:
        raise ConfigError(
            f"avoid.calibration.autonomy_target={calibration.autonomy_target:g} cannot be shown with "
            f"{estimator.planned_rollouts()} known-condition runs (it needs {needed}); lower it or "
            "tighten avoid.theta"
        )
    bins = stage.experiment.bins
    model_path = Path(avoid.model_path)
    cell_posterior("avoid.model_path", model_path, method, bins)
    spec = PolicySpec("bnn", avoid.speed, str(model_path), method, bins, warning.samples, avoid.eps)
    return AvoidSettings(
        method,
        spec,
        file_digest(model_path),
        warning,
        estimator,
        avoid.validation_seed,
        Condition(KNOWN, stage.scenario, stage.weather, avoid.known_noise),
        _unknown_conditions(stage),
        calibration,
        stage.camera,
        stage.vehicle,
        float(stage.control_hz),
        horizon,
    )


class ReusingExecutor:
    """Takes finished rollouts from ``known`` (by index) and runs only the others on ``inner``, in order."""

    def __init__(self, inner: Executor, known: dict[int, RolloutResult]):
        self.inner, self.known = inner, known

    def run(self, indices: Sequence[int]) -> Iterator[RolloutResult]:
        fresh = self.inner.run([i for i in indices if i not in self.known])
        for i in indices:
            yield self.known[i] if i in self.known else next(fresh)

    def close(self) -> None:
        self.inner.close()


def unchanged_by(warning: WarningConfig, off: Cell) -> dict[int, RolloutResult]:
    """Warnings-off rollouts in which ``warning`` never fires: with warnings on, the same seed gives the
    same frames, draws and measures, no action ever changes a command, so the rollout is identical."""
    return {
        i: r
        for i, r in enumerate(off.results)
        if not (classify(r.eta2, r.mutual_information, warning.delta1, warning.delta2, warning.tau) >= 0).any()
    }


def run_cell(
    cfg: DictConfig,
    settings: AvoidSettings,
    condition: Condition,
    mode: str,
    warning: WarningConfig,
    pool: ProcessPool | None,
    off: Cell | None = None,
) -> Cell:
    """η̂1 of one cell; the rollouts its log already holds (same identity) are reused, not rerun, so a finished
    cell costs nothing on a rerun and an interrupted one resumes. ``mode`` off drives without warnings (its
    warnings are only counted). ``pool``: the stage's worker processes (process backend). ``off``: the
    warnings-off cell on the same seeds, whose rollouts no warning would change are reused exactly."""
    base_seed = settings.validation_seed if mode == "calibrated" else settings.estimator.base_seed
    estimator = dataclasses.replace(settings.estimator, base_seed=base_seed)
    job = settings.job(condition, None if mode == "off" else warning, base_seed)
    name = f"{settings.method}-{condition.name}-{mode}"
    identity = {
        "model_sha256": settings.model_sha256,
        "code": code_digest(),
        "estimator": estimator.__dict__,
        "job": {**job.__dict__, "policy": {k: v for k, v in job.policy.__dict__.items() if k != "model_path"}},
    }
    log = RolloutLog(Path(cfg.avoid.rollout_log) / f"{name}.jsonl", cell_hash(identity), base_seed)
    executor: Executor = make_executor(
        cfg.executor.name,
        job,
        cfg.executor.workers,
        pool,
        **executor_options(cfg.executor),
    )
    if off is not None:
        executor = ReusingExecutor(executor, unchanged_by(warning, off))
    ran: list[RolloutResult] = []
    bar = tqdm(
        total=estimator.planned_rollouts(), desc=f"avoid {name}", unit="rollout", disable=not cfg.progress, leave=False
    )

    def progress(fresh: Iterator[RolloutResult]) -> Iterator[RolloutResult]:
        for result in fresh:  # one bar over the cell, however many looks a sequential scheme takes
            bar.update()
            ran.append(result)
            yield result

    start = time.perf_counter()
    try:
        estimate, results = estimate_safety(executor, estimator, progress, log)
    finally:
        bar.close()
        executor.close()
    return Cell(name, condition.name, mode, warning, estimate, results, time.perf_counter() - start, reused=not ran)


def run_avoid(cfg: DictConfig) -> dict:
    """All cells of one method, the calibration and its closed-loop check; writes metrics, data, figures, runs."""
    settings = build_settings(cfg)
    geometries = settings.geometries()
    start = time.perf_counter()
    cells: dict[tuple[str, str], Cell] = {}
    pool = ProcessPool(cfg.executor.workers) if cfg.executor.name == "process" else None
    try:
        for condition in settings.conditions:
            off = cells[condition.name, "off"] = run_cell(cfg, settings, condition, "off", settings.warning, pool)
            cells[condition.name, "on"] = run_cell(cfg, settings, condition, "on", settings.warning, pool, off)
        c, names = settings.calibration, [k.name for k in settings.conditions]
        traces = traces_of([cells[name, "off"] for name in names], geometries)
        calib = calibrate(
            traces,
            names,
            settings.warning,
            list(c.deltas),
            list(c.taus),
            c.autonomy_target,
            c.gamma,
            **replay_args(settings),
        )
        calibrated = settings.warning.with_thresholds(calib.delta1, calib.delta2, calib.tau)
        for condition in settings.conditions:
            cells[condition.name, "calibrated"] = run_cell(cfg, settings, condition, "calibrated", calibrated, pool)
    finally:
        if pool is not None:
            pool.close()
    return write_outputs(
        cfg, settings, cells, calib, traces, replay_args(settings), geometries, time.perf_counter() - start
    )


def replay_args(settings: AvoidSettings) -> dict:
    return {
        "control_hz": settings.control_hz,
        "cruise": settings.spec.speed,
        "start_speed": min(settings.known.scenario.start_speed, settings.vehicle.max_speed),
        "max_accel": settings.vehicle.max_accel,
        "max_brake": settings.vehicle.max_brake,
        "margin_m": settings.calibration.margin_m,
    }
