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
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from uqdrive import checks
from uqdrive.checks import ConfigError
from uqdrive.data.binning import SteeringBins
from uqdrive.models.posterior import posterior_from_config
from uqdrive.pipeline.avoid_cells import Cell, traces_of
from uqdrive.pipeline.avoid_outputs import write_outputs
from uqdrive.pipeline.safety import code_digest
from uqdrive.safety.calibration import calibrate, min_known_runs
from uqdrive.safety.cells import EstimatorSettings, cell_hash, cell_posterior, estimate_safety, file_digest
from uqdrive.safety.executors import (
    BACKENDS,
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
from uqdrive.sim import (
    CameraConfig,
    ScenarioConfig,
    ScenarioGeometry,
    VehicleConfig,
    WeatherConfig,
    build_geometry,
    check_noise,
)

KNOWN = "known"
MODES = ("off", "on", "calibrated")
UNKNOWN_KEYS = ("name", "weather", "noise", "scenario")


@dataclasses.dataclass(frozen=True)
class CalibrationSettings:
    """Threshold calibration: known-condition autonomy must have an exact lower bound (level 1 − ``gamma``)
    ≥ ``autonomy_target``; among those, the most replayed unknown-condition safety."""

    autonomy_target: float
    gamma: float
    margin_m: float
    deltas: tuple[float, ...]
    taus: tuple[float, ...]

    def __post_init__(self) -> None:
        for name in ("autonomy_target", "gamma"):
            if not 0 < checks.finite_number(f"avoid.calibration.{name}", getattr(self, name)) < 1:
                raise ConfigError(
                    f"avoid.calibration.{name}={getattr(self, name)!r} must be in the open interval (0, 1)"
                )
        if not checks.finite_number("avoid.calibration.margin_m", self.margin_m) >= 0:
            raise ConfigError(f"avoid.calibration.margin_m={self.margin_m!r} must be a number of metres >= 0")
        for name, ok, allowed in (("deltas", lambda v: 0 <= v <= 1, "in [0, 1]"), ("taus", lambda v: v >= 0, ">= 0")):
            values = getattr(self, name)
            if (
                isinstance(values, (str, bytes))
                or not values
                or not all(ok(checks.finite_number(f"avoid.calibration.{name}", v)) for v in values)
            ):
                raise ConfigError(f"avoid.calibration.{name}={values!r} must be a non-empty list of numbers {allowed}")
            object.__setattr__(self, name, tuple(sorted({float(v) for v in values})))


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


def _unknown_conditions(cfg: DictConfig, scenario: ScenarioConfig) -> tuple[Condition, ...]:
    items = OmegaConf.to_container(cfg.avoid.unknown, resolve=True)
    if not isinstance(items, list) or not items:
        raise ConfigError(
            f"avoid.unknown={items!r} must be a non-empty list of conditions (each with keys {list(UNKNOWN_KEYS)})"
        )
    weathers = {cfg.weather.name: cfg.weather, **dict(cfg.get("weathers") or {})}
    out = []
    for i, item in enumerate(items):
        key = f"avoid.unknown[{i}]"
        if not isinstance(item, dict) or set(item) - set(UNKNOWN_KEYS) or not item.get("name"):
            raise ConfigError(f"{key}={item!r} must be a mapping with a name and keys among {list(UNKNOWN_KEYS)}")
        if item["name"] == KNOWN:
            raise ConfigError(f"{key}.name={KNOWN!r} is the training condition's name; choose another")
        name = item.get("weather", cfg.weather.name)
        if name not in weathers:
            raise ConfigError(
                f"{key}.weather={name!r} is not loaded; choose one of {sorted(weathers)} or add "
                f"+weather@weathers.{name}={name}"
            )
        overrides = item.get("scenario") or {}
        if not isinstance(overrides, dict):
            raise ConfigError(f"{key}.scenario={overrides!r} must be a mapping of scenario fields")
        try:
            condition_scenario = ScenarioConfig.from_config({**scenario.to_dict(), **overrides})
            noise = check_noise(item.get("noise", 0.0))
        except ValueError as err:
            raise ConfigError(f"{key}: {err}") from err
        out.append(Condition(str(item["name"]), condition_scenario, WeatherConfig.from_config(weathers[name]), noise))
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise ConfigError(f"avoid.unknown names {names} must be unique")
    return tuple(out)


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
    method = posterior_from_config(cfg.model).method
    if cfg.executor.name not in BACKENDS:
        raise ConfigError(f"executor.name={cfg.executor.name!r} is not a known backend; choose one of {list(BACKENDS)}")
    checks.integer("executor.workers", cfg.executor.workers, 1)
    warning = WarningConfig.from_config(OmegaConf.to_container(cfg.warning, resolve=True))
    estimator = EstimatorSettings.from_section(cfg.avoid, "avoid")
    validation_seed = checks.integer("avoid.validation_seed", cfg.avoid.validation_seed, 0)
    vehicle = VehicleConfig.from_config(cfg.vehicle)
    speed = checks.speed("avoid.speed", cfg.avoid.speed, vehicle.max_speed)
    scenario = ScenarioConfig.from_config(cfg.scenario)
    if scenario.kind != "obstacle":
        raise ConfigError(f"scenario.kind={scenario.kind!r}: the avoid stage needs an 'obstacle' scenario")
    horizon = check_horizon(checks.seconds("avoid.horizon_s", cfg.avoid.horizon_s), warning, speed, scenario, vehicle)
    known = Condition(KNOWN, scenario, WeatherConfig.from_config(cfg.weather), check_noise(cfg.avoid.known_noise))
    calibration = CalibrationSettings(**OmegaConf.to_container(cfg.avoid.calibration, resolve=True))
    needed = min_known_runs(calibration.autonomy_target, calibration.gamma)
    if estimator.scheme != "sequential" and estimator.planned_rollouts() < needed:
        raise ConfigError(
            f"avoid.calibration.autonomy_target={calibration.autonomy_target:g} cannot be shown with "
            f"{estimator.planned_rollouts()} known-condition runs (it needs {needed}); lower it or "
            "tighten avoid.theta"
        )
    bins = SteeringBins(**cfg.experiment.bins)
    model_path = Path(cfg.avoid.model_path)
    cell_posterior("avoid.model_path", model_path, method, bins)
    if not checks.finite_number("avoid.eps", cfg.avoid.eps) > 0:
        raise ConfigError(f"avoid.eps={cfg.avoid.eps!r} must be a number > 0 (steering units)")
    spec = PolicySpec("bnn", speed, str(model_path), method, bins, warning.samples, float(cfg.avoid.eps))
    return AvoidSettings(
        method,
        spec,
        file_digest(model_path),
        warning,
        estimator,
        validation_seed,
        known,
        _unknown_conditions(cfg, scenario),
        calibration,
        CameraConfig.from_config(cfg.camera),
        vehicle,
        float(cfg.control_hz),
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
        **executor_options(OmegaConf.to_container(cfg.executor, resolve=True)),
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
