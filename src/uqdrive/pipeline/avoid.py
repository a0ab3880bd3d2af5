"""The `avoid` stage: real-time collision avoidance with the three-tier warning system (the paper's
section "Real-time Collision Avoidance"), and `avoid_summary`, the table over all methods.

For one method, on the obstacle road, cells condition × warnings: `known` (the training
weather) and `unknown` (each rollout draws a variant: other weathers, sensor noise, another
obstacle car), each with warnings `off` and `on` (the configured thresholds) on the same seeds.
Then thresholds are calibrated by replaying the warnings-off rollouts and checked in closed loop
(`calibrated`) on fresh seeds. Every input is checked before the first rollout.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path

import matplotlib.pyplot as plt
import mlflow
import numpy as np
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from uqdrive import checks
from uqdrive.data.binning import SteeringBins
from uqdrive.files import atomic_path, write_csv, write_json
from uqdrive.models.posterior import posterior_from_config
from uqdrive.plots import (avoid_signals_figure, avoid_trajectories, avoid_trajectories_figure, avoid_tradeoff_figure,
                           save_figure)
from uqdrive.safety.cells import EstimatorSettings, cell_posterior, estimate_safety
from uqdrive.safety.executors import (BACKENDS, Executor, PolicySpec, ProcessPool, RolloutJob, Variant, executor_options,
                                      make_executor)
from uqdrive.safety.rollout import HANDOVER, RolloutResult
from uqdrive.safety.warnings import LEVELS, Calibration, Traces, WarningConfig, calibrate, classify, replay
from uqdrive.sim import (CameraConfig, ScenarioConfig, ScenarioGeometry, VehicleConfig, WeatherConfig, build_geometry,
                         check_noise)
from uqdrive.tracking import stage_run
from uqdrive.uq import Estimate

CONDITIONS = ("known", "unknown")
MODES = ("off", "on", "calibrated")
VARIANT_KEYS = ("name", "weather", "noise", "scenario")
PAPER = {  # the paper's VI numbers (θ = 0.05): unknown 0.00 → 0.90 with warnings, known 1.00 with full autonomy
    "method": "vi", "theta": 0.05,
    "unknown": {"off": {"eta1": 0.0}, "on": {"eta1": 0.9}},
    "known": {"on": {"eta1": 1.0, "autonomy": 1.0}},
}


@dataclasses.dataclass(frozen=True)
class CalibrationSettings:
    """Threshold calibration: the replayed η̂1 lower bound must reach ``target`` in every condition."""

    target: float
    gamma: float
    margin_m: float
    deltas: tuple[float, ...]
    taus: tuple[float, ...]

    def __post_init__(self) -> None:
        for name in ("target", "gamma"):
            if not 0 < checks.finite_number(f"avoid.calibration.{name}", getattr(self, name)) < 1:
                raise ValueError(f"avoid.calibration.{name}={getattr(self, name)!r} must be in the open "
                                 "interval (0, 1)")
        if not checks.finite_number("avoid.calibration.margin_m", self.margin_m) >= 0:
            raise ValueError(f"avoid.calibration.margin_m={self.margin_m!r} must be a number of metres >= 0")
        for name, ok, allowed in (("deltas", lambda v: 0 <= v <= 1, "in [0, 1]"), ("taus", lambda v: v >= 0, ">= 0")):
            values = getattr(self, name)
            if isinstance(values, (str, bytes)) or not values or not all(
                    ok(checks.finite_number(f"avoid.calibration.{name}", v)) for v in values):
                raise ValueError(f"avoid.calibration.{name}={values!r} must be a non-empty list of numbers {allowed}")
            object.__setattr__(self, name, tuple(sorted({float(v) for v in values})))


@dataclasses.dataclass(frozen=True)
class AvoidSettings:
    """Everything a stage run needs, validated; ``spec`` is the warnings-off policy."""

    method: str
    spec: PolicySpec
    warning: WarningConfig
    estimator: EstimatorSettings
    validation_seed: int
    scenario: ScenarioConfig
    known: Variant
    unknown: tuple[Variant, ...]
    calibration: CalibrationSettings
    camera: CameraConfig
    vehicle: VehicleConfig
    control_hz: float
    horizon_s: float

    def job(self, condition: str, warning: WarningConfig | None, base_seed: int) -> RolloutJob:
        """The rollouts of one cell: ``warning`` None drives without the warning system."""
        spec = dataclasses.replace(self.spec, warnings=warning)
        known = self.known
        return RolloutJob(policy=spec, scenario=known.scenario, weather=known.weather, noise=known.noise,
                          base_seed=base_seed, camera=self.camera, vehicle=self.vehicle, control_hz=self.control_hz,
                          horizon_s=self.horizon_s, variants=self.unknown if condition == "unknown" else ())

    def geometries(self) -> dict[str, ScenarioGeometry]:
        """Road geometry per variant name ("" = the known condition), for distances along the road."""
        geometry = build_geometry(self.scenario)
        out = {"": geometry}
        for v in self.unknown:
            out[v.name] = geometry if v.scenario == self.scenario else build_geometry(v.scenario)
        return out


def _variants(cfg: DictConfig, scenario: ScenarioConfig) -> tuple[Variant, ...]:
    items = OmegaConf.to_container(cfg.avoid.unknown, resolve=True)
    if not isinstance(items, list) or not items:
        raise ValueError(f"avoid.unknown={items!r} must be a non-empty list of variants "
                         f"(each with keys {list(VARIANT_KEYS)})")
    weathers = {cfg.weather.name: cfg.weather, **dict(cfg.get("weathers") or {})}
    out = []
    for i, item in enumerate(items):
        key = f"avoid.unknown[{i}]"
        if not isinstance(item, dict) or set(item) - set(VARIANT_KEYS) or not item.get("name"):
            raise ValueError(f"{key}={item!r} must be a mapping with a name and keys among {list(VARIANT_KEYS)}")
        name = item.get("weather", cfg.weather.name)
        if name not in weathers:
            raise ValueError(f"{key}.weather={name!r} is not loaded; choose one of {sorted(weathers)} or add "
                             f"+weather@weathers.{name}={name}")
        overrides = item.get("scenario") or {}
        if not isinstance(overrides, dict):
            raise ValueError(f"{key}.scenario={overrides!r} must be a mapping of scenario fields")
        try:
            variant_scenario = ScenarioConfig.from_config({**scenario.to_dict(), **overrides})
            noise = check_noise(item.get("noise", 0.0))
        except ValueError as err:
            raise ValueError(f"{key}: {err}") from err
        out.append(Variant(str(item["name"]), variant_scenario, WeatherConfig.from_config(weathers[name]), noise))
    names = [v.name for v in out]
    if len(set(names)) != len(names):
        raise ValueError(f"avoid.unknown names {names} must be unique")
    return tuple(out)


def build_settings(cfg: DictConfig) -> AvoidSettings:
    """Validate the stage's config and the model file; raises before any rollout, naming key and value."""
    method = posterior_from_config(cfg.model).method
    if cfg.executor.name not in BACKENDS:
        raise ValueError(f"executor.name={cfg.executor.name!r} is not a known backend; choose one of {list(BACKENDS)}")
    checks.integer("executor.workers", cfg.executor.workers, 1)
    warning = WarningConfig.from_config(OmegaConf.to_container(cfg.warning, resolve=True))
    estimator = EstimatorSettings(scheme=cfg.avoid.scheme, theta=cfg.avoid.theta, gamma=cfg.avoid.gamma,
                                  base_seed=cfg.avoid.base_seed, section="avoid")
    validation_seed = checks.integer("avoid.validation_seed", cfg.avoid.validation_seed, 0)
    vehicle = VehicleConfig.from_config(cfg.vehicle)
    speed = checks.speed("avoid.speed", cfg.avoid.speed, vehicle.max_speed)
    horizon = checks.seconds("avoid.horizon_s", cfg.avoid.horizon_s)
    scenario = ScenarioConfig.from_config(cfg.scenario)
    if scenario.kind != "obstacle":
        raise ValueError(f"scenario.kind={scenario.kind!r}: the avoid stage needs an 'obstacle' scenario")
    known = Variant("", scenario, WeatherConfig.from_config(cfg.weather), check_noise(cfg.avoid.known_noise))
    unknown = _variants(cfg, scenario)
    calibration = CalibrationSettings(**OmegaConf.to_container(cfg.avoid.calibration, resolve=True))
    bins = SteeringBins(**cfg.bins)
    model_path = Path(cfg.avoid.model_path)
    cell_posterior("avoid.model_path", model_path, method, bins)
    if not checks.finite_number("avoid.eps", cfg.avoid.eps) > 0:
        raise ValueError(f"avoid.eps={cfg.avoid.eps!r} must be a number > 0 (steering units)")
    spec = PolicySpec("bnn", speed, str(model_path), method, bins, warning.samples, float(cfg.avoid.eps))
    return AvoidSettings(method, spec, warning, estimator, validation_seed, scenario, known, unknown, calibration,
                         CameraConfig.from_config(cfg.camera), vehicle, float(cfg.control_hz), horizon)


# -- one cell ---------------------------------------------------------------------------------------
@dataclasses.dataclass
class Cell:
    """A finished cell: its estimate, rollouts and the thresholds its warnings are counted with."""

    name: str
    condition: str
    mode: str
    warning: WarningConfig
    estimate: Estimate
    results: list[RolloutResult]
    seconds: float


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
    return {i: r for i, r in enumerate(off.results)
            if not (classify(r.eta2, r.mutual_information, warning.delta1, warning.delta2, warning.tau) >= 0).any()}


def run_cell(cfg: DictConfig, settings: AvoidSettings, condition: str, mode: str, warning: WarningConfig,
             pool: ProcessPool | None, off: Cell | None = None) -> Cell:
    """η̂1 of one cell; ``mode`` off drives without warnings (its warnings are only counted). ``pool``: the
    stage's worker processes (process backend). ``off``: the warnings-off cell on the same seeds, whose
    rollouts no warning would change are reused exactly."""
    base_seed = settings.validation_seed if mode == "calibrated" else settings.estimator.base_seed
    estimator = dataclasses.replace(settings.estimator, base_seed=base_seed)
    job = settings.job(condition, None if mode == "off" else warning, base_seed)
    name = f"{settings.method}-{condition}-{mode}"
    executor: Executor = make_executor(cfg.executor.name, job, cfg.executor.workers, pool, **executor_options(OmegaConf.to_container(cfg.executor, resolve=True)))
    if off is not None:
        executor = ReusingExecutor(executor, unchanged_by(warning, off))
    start = time.perf_counter()
    try:
        estimate, results = estimate_safety(executor, estimator, lambda it: tqdm(
            it, total=estimator.planned_rollouts(), desc=f"avoid {name}", unit="rollout", disable=not cfg.progress,
            leave=False))
    finally:
        executor.close()
    return Cell(name, condition, mode, warning, estimate, results, time.perf_counter() - start)


def levels(cell: Cell, result: RolloutResult) -> np.ndarray:
    """Warning level per frame: as raised (warnings on) or as the cell's thresholds would have raised them (off)."""
    if cell.mode != "off":
        return result.warning
    w = cell.warning
    return classify(result.eta2, result.mutual_information, w.delta1, w.delta2, w.tau)


def passed(geometry: ScenarioGeometry, result: RolloutResult, vehicle_length: float) -> bool:
    """Whether the car ended fully past the obstacle (a slowed car may time out before reaching it)."""
    clear = obstacle_progress(geometry) + (geometry.obstacles[0].size[0] + vehicle_length) / 2
    return progress_along(geometry, result)[1] >= clear


def cell_metrics(cell: Cell, cruise: float, geometries: dict[str, ScenarioGeometry], vehicle_length: float) -> dict:
    """η̂1 with its interval, autonomy, time at full speed, warning counts, failures, η̂1 per variant."""
    results, est = cell.results, cell.estimate
    handover_levels = [lv for lv, a in zip(LEVELS, cell.warning.actions) if a.handover]
    per_run = [levels(cell, r) for r in results]
    handed = [cell.mode != "off" and bool(np.isin(lv, handover_levels).any()) for lv in per_run]
    steps = sum(r.steps for r in results)
    full = sum(int(np.sum(r.command_speed >= cruise - 1e-9)) for r in results)
    metrics = {"eta1": est.value, "eta1_low": est.low, "eta1_high": est.high, "n": est.n,
               "handover_rate": float(np.mean(handed)), "autonomy": 1 - float(np.mean(handed)),
               "full_speed_fraction": full / max(steps, 1),
               "collision_rate": float(np.mean([r.collision for r in results])),
               "off_road_rate": float(np.mean([r.off_road for r in results])),
               "passed_rate": float(np.mean([passed(geometries[r.variant], r, vehicle_length) for r in results])),
               "mean_steps": steps / len(results), "seconds": cell.seconds}
    for level in LEVELS:
        metrics[f"warning{level}_frames"] = int(sum(int(np.sum(lv == level)) for lv in per_run))
        metrics[f"warning{level}_runs"] = int(sum(bool(np.any(lv == level)) for lv in per_run))
    variants: dict[str, dict] = {}
    for r in results:
        if r.variant:
            v = variants.setdefault(r.variant, {"n": 0, "safe": 0})
            v["n"] += 1
            v["safe"] += int(r.safe)
    return {**metrics, "terminations": dict(sorted(Counter(r.termination for r in results).items())),
            "variants": {k: {**v, "eta1": v["safe"] / v["n"]} for k, v in sorted(variants.items())},
            "guaranteed": est.guaranteed, "scheme": est.method, "theta": est.theta, "gamma": est.gamma,
            "thresholds": {"delta1": cell.warning.delta1, "delta2": cell.warning.delta2, "tau": cell.warning.tau}}


# -- traces, replay and calibration -----------------------------------------------------------------
def progress_along(geometry: ScenarioGeometry, result: RolloutResult) -> tuple[np.ndarray, float]:
    """Metres along the route at each decision frame, and where the run ended."""
    s, _ = geometry.route.project(np.stack([result.x, result.y], axis=1))
    return s[:-1], float(s[-1])


def obstacle_progress(geometry: ScenarioGeometry) -> float:
    s, _ = geometry.route.project(np.array([[geometry.obstacles[0].x, geometry.obstacles[0].y]]))
    return float(s[0])


def traces_of(cells: list[Cell], geometries: dict[str, ScenarioGeometry]) -> Traces:
    """The warnings-off rollouts of ``cells`` as replay input, grouped by condition (CONDITIONS order)."""
    runs = []
    for cell in cells:
        for r in cell.results:
            s, end = progress_along(geometries[r.variant], r)
            runs.append((r.eta2, r.mutual_information, s, end, r.safe, CONDITIONS.index(cell.condition)))
    return Traces.from_runs(runs)


def replay_args(settings: AvoidSettings) -> dict:
    return {"control_hz": settings.control_hz, "cruise": settings.spec.speed,
            "start_speed": min(settings.scenario.start_speed, settings.vehicle.max_speed),
            "max_accel": settings.vehicle.max_accel, "max_brake": settings.vehicle.max_brake,
            "margin_m": settings.calibration.margin_m}


def replay_check(off: dict[str, Cell], on: dict[str, Cell], traces: Traces, settings: AvoidSettings) -> dict:
    """The replay at the configured thresholds against the warnings-on cells on the same seeds: how well
    the approximation predicts closed loop, run by run."""
    w = settings.warning
    out = replay(traces, np.array([w.delta1]), np.array([w.delta2]), np.array([w.tau]), w, **replay_args(settings))
    check = {}
    for g, condition in enumerate(CONDITIONS):
        members = traces.group == g
        safe = np.array([r.safe for r in on[condition].results])
        handed = np.array([r.termination == HANDOVER for r in on[condition].results])
        replayed, replayed_handover = out.safe[0, members], out.handover[0, members]
        check[condition] = {"replayed_eta1": float(replayed.mean()), "closed_loop_eta1": float(safe.mean()),
                            "replayed_handover_rate": float(replayed_handover.mean()),
                            "agreement": float(np.mean(replayed == safe)) if len(safe) == len(replayed) else math.nan,
                            "closed_loop_handover_terminations": float(handed.mean())}
    return check


def calibration_summary(calib: Calibration) -> dict:
    row = {k: (v[calib.chosen].item() if hasattr(v[calib.chosen], "item") else v[calib.chosen])
           for k, v in calib.table.items()}
    return {"delta1": calib.delta1, "delta2": calib.delta2, "tau": calib.tau, "feasible": calib.feasible,
            "target": calib.target, "gamma": calib.gamma, "candidates": len(calib.table["delta1"]),
            "replayed": {k: v for k, v in row.items() if k not in ("delta1", "delta2", "tau")}}


# -- outputs ----------------------------------------------------------------------------------------
def write_cell_table(path: Path, cell: Cell) -> Path:
    """Per-rollout rows: outcome, variant, steps, time at full speed, min η2, max MI, frames per warning level."""
    rows = []
    for r in cell.results:
        lv = levels(cell, r)
        rows.append({**r.summary(), "min_eta2": float(np.min(r.eta2)) if r.steps else math.nan,
                     "max_mutual_information": float(np.max(r.mutual_information)) if r.steps else math.nan,
                     **{f"warning{level}_frames": int(np.sum(lv == level)) for level in LEVELS}})
    return write_csv(path, rows)


def write_cell_data(path: Path, cell: Cell, geometries: dict[str, ScenarioGeometry]) -> Path:
    """Per-frame traces of a cell (npz) for the summary figure: positions, distance to the obstacle, η2, MI, level."""
    frames: dict[str, list[np.ndarray]] = {k: [] for k in ("rollout", "x", "y", "distance", "eta2", "mi", "level")}
    for i, r in enumerate(cell.results):
        for key, value in (("rollout", np.full(r.steps, i)), ("x", r.x[:-1]), ("y", r.y[:-1]),
                           ("distance", distances(r, geometries)), ("eta2", r.eta2),
                           ("mi", r.mutual_information), ("level", levels(cell, r))):
            frames[key].append(value)
    with atomic_path(path) as tmp, tmp.open("wb") as f:
        np.savez_compressed(f, **{k: np.concatenate(v) if v else np.zeros(0) for k, v in frames.items()},
                            end_x=np.array([r.x[-1] for r in cell.results]),
                            end_y=np.array([r.y[-1] for r in cell.results]),
                            termination=np.array([r.termination for r in cell.results]),
                            safe=np.array([r.safe for r in cell.results]), eta1=cell.estimate.value,
                            obstacle=_obstacle_box(geometries[""]), road=_road_box(geometries[""]))
    return path


def _obstacle_box(geometry: ScenarioGeometry) -> np.ndarray:
    ob = geometry.obstacles[0]
    return np.array([ob.x, ob.y, ob.size[0], ob.size[1]])


def _road_box(geometry: ScenarioGeometry) -> np.ndarray:
    """x range of the road and its lane edges (y), for drawing the straight obstacle road."""
    cfg = geometry.config
    return np.array([0.0, cfg.road_length, -cfg.lane_width, 0.0, cfg.lane_width * (cfg.num_lanes - 1)])


def write_signals(path: Path, cells: list[Cell], geometries: dict[str, ScenarioGeometry]) -> Path:
    """η2 and MI per frame against the distance to the obstacle (a DVC plot)."""
    return write_csv(path, [{"condition": cell.condition, "rollout": i, "distance": f"{d:.3f}", "eta2": f"{e:.4f}",
                             "mutual_information": f"{m:.4f}", "outcome": r.termination}
                            for cell in cells for i, r in enumerate(cell.results)
                            for d, e, m in zip(distances(r, geometries), r.eta2, r.mutual_information)])


def write_tradeoff(path: Path, calib: Calibration) -> Path:
    return write_csv(path, [{k: _fmt(v[i]) for k, v in calib.table.items()} for i in range(len(calib.table["delta1"]))])


def _fmt(value: object) -> str:
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value)).lower()
    return f"{float(value):.6g}"


def _panel(cell: Cell, geometries: dict[str, ScenarioGeometry]) -> dict:
    paths = []
    for r in cell.results:
        paths.append({"x": r.x[:-1], "y": r.y[:-1], "mi": r.mutual_information, "termination": r.termination})
    geometry = geometries[""]
    return {"paths": paths, "obstacle": _obstacle_box(geometry), "road": _road_box(geometry),
            "title": f"η̂1 = {cell.estimate.value:.2f} [{cell.estimate.low:.2f}, {cell.estimate.high:.2f}]"}


def _log_run(cfg: DictConfig, cell: Cell, metrics: dict, settings: AvoidSettings, artifacts: list[Path]) -> str:
    params = {"method": settings.method, "condition": cell.condition, "warnings": cell.mode,
              "delta1": cell.warning.delta1, "delta2": cell.warning.delta2, "tau": cell.warning.tau,
              "samples_per_frame": cell.warning.samples, "scheme": cell.estimate.method,
              "theta": cell.estimate.theta, "gamma": cell.estimate.gamma, "n": cell.estimate.n,
              "variants": ",".join(v.name for v in settings.unknown) if cell.condition == "unknown" else "",
              "base_seed": settings.validation_seed if cell.mode == "calibrated" else settings.estimator.base_seed}
    with stage_run(cfg.paths.root, "avoid", cfg, run_name=cell.name) as run:
        mlflow.log_params(params)
        mlflow.log_metrics({k: float(v) for k, v in metrics.items()
                            if isinstance(v, (int, float)) and not isinstance(v, bool) and not math.isnan(v)})
        mlflow.log_metrics({f"eta1_{k}": v["eta1"] for k, v in metrics["variants"].items()})
        for path in artifacts:
            mlflow.log_artifact(str(path))
        return run.info.run_id


def run_avoid(cfg: DictConfig) -> dict:
    """All cells of one method, the calibration and its closed-loop check; writes metrics, data, figures, runs."""
    settings = build_settings(cfg)
    workers = checks.integer("executor.workers", cfg.executor.workers, 1)
    data_dir, plots_dir = Path(cfg.avoid.data_dir), Path(cfg.avoid.plots_dir)
    geometries = settings.geometries()
    start = time.perf_counter()
    cells: dict[tuple[str, str], Cell] = {}
    pool = ProcessPool(workers) if cfg.executor.name == "process" else None
    try:
        for condition in CONDITIONS:
            off = cells[condition, "off"] = run_cell(cfg, settings, condition, "off", settings.warning, pool)
            cells[condition, "on"] = run_cell(cfg, settings, condition, "on", settings.warning, pool, off)
        traces = traces_of([cells[c, "off"] for c in CONDITIONS], geometries)
        calib = calibrate(traces, list(CONDITIONS), settings.warning, list(settings.calibration.deltas),
                          list(settings.calibration.taus), settings.calibration.target, settings.calibration.gamma,
                          **replay_args(settings))
        calibrated = settings.warning.with_thresholds(calib.delta1, calib.delta2, calib.tau)
        for condition in CONDITIONS:
            cells[condition, "calibrated"] = run_cell(cfg, settings, condition, "calibrated", calibrated, pool)
    finally:
        if pool is not None:
            pool.close()

    table: dict[str, dict] = {c: {} for c in CONDITIONS}
    run_ids = {}
    for (condition, mode), cell in cells.items():
        metrics = cell_metrics(cell, settings.spec.speed, geometries, settings.vehicle.length)
        csv_path = write_cell_table(plots_dir / "cells" / f"{cell.name}.csv", cell)
        write_cell_data(data_dir / f"{cell.name}.npz", cell, geometries)
        fig, ax = plt.subplots(figsize=(8, 2.6))
        panel = _panel(cell, geometries)
        fig.colorbar(avoid_trajectories(ax, panel, f"{settings.method} · {condition}, warnings {mode}: "
                                                   f"{panel['title']}"), ax=ax,
                     label="mutual information (nats)", extend="max")
        png = save_figure(fig, plots_dir / "cells" / f"{cell.name}.png")
        run_ids[cell.name] = _log_run(cfg, cell, metrics, settings, [csv_path, png])
        table[condition][mode] = metrics

    check = replay_check({c: cells[c, "off"] for c in CONDITIONS}, {c: cells[c, "on"] for c in CONDITIONS}, traces,
                         settings)
    calibration = {**calibration_summary(calib), "replay_check": check}
    figures = [
        save_figure(avoid_trajectories_figure(
            {(c, m): _panel(cells[c, m], geometries) for c in CONDITIONS for m in MODES}, list(CONDITIONS),
            list(MODES), f"{settings.method}: paths coloured by mutual information"), plots_dir / "trajectories.png"),
        save_figure(avoid_signals_figure(
            {c: [(distances(r, geometries), r.eta2, r.mutual_information, r.termination)
                 for r in cells[c, "off"].results] for c in CONDITIONS},
            settings.warning, calibrated, f"{settings.method}, warnings off: uncertainty approaching the obstacle"),
            plots_dir / "warnings.png"),
        save_figure(avoid_tradeoff_figure(calib.table, calib.chosen, _default_index(calib, settings.warning),
                                          calib.target, f"{settings.method}: replayed safety–autonomy trade-off"),
                    plots_dir / "tradeoff.png"),
    ]
    data_files = [write_tradeoff(plots_dir / "tradeoff.csv", calib),
                  write_signals(plots_dir / "signals.csv", [cells[c, "off"] for c in CONDITIONS], geometries)]
    with stage_run(cfg.paths.root, "avoid", cfg, run_name=f"{settings.method}-calibration") as run:
        mlflow.log_params({"method": settings.method, "calibrated_delta1": calib.delta1,
                           "calibrated_delta2": calib.delta2, "calibrated_tau": calib.tau,
                           "calibration_target": calib.target, "calibration_feasible": calib.feasible})
        mlflow.log_metrics({f"replayed_{k}": float(v) for k, v in calibration["replayed"].items()})
        for path in [*figures, *data_files]:
            mlflow.log_artifact(str(path))
        run_ids["calibration"] = run.info.run_id
    result = {"method": settings.method, "cells": table, "calibration": calibration,
              "warning": settings.warning.to_dict(), "samples_per_frame": settings.warning.samples,
              "unknown_variants": [v.name for v in settings.unknown], "horizon_s": settings.horizon_s,
              "speed": settings.spec.speed, "seconds": time.perf_counter() - start, "mlflow_run_ids": run_ids}
    write_json(cfg.avoid.out, result)
    return result


def distances(result: RolloutResult, geometries: dict[str, ScenarioGeometry]) -> np.ndarray:
    """Metres to the obstacle along the road at each decision frame."""
    geometry = geometries[result.variant]
    return obstacle_progress(geometry) - progress_along(geometry, result)[0]


def _default_index(calib: Calibration, warning: WarningConfig) -> int | None:
    """Row of the configured thresholds among the candidates (None if they are off the grids)."""
    t = calib.table
    hit = np.flatnonzero(np.isclose(t["delta1"], warning.delta1) & np.isclose(t["delta2"], warning.delta2)
                         & np.isclose(t["tau"], warning.tau))
    return int(hit[0]) if hit.size else None


# -- summary ----------------------------------------------------------------------------------------
SUMMARY_KEYS = ("eta1", "eta1_low", "eta1_high", "n", "handover_rate", "autonomy", "full_speed_fraction",
                "collision_rate", "passed_rate", "warning0_frames", "warning1_frames", "warning2_frames",
                "warning0_runs", "warning1_runs", "warning2_runs", "variants", "thresholds")


def run_avoid_summary(cfg: DictConfig) -> dict:
    """metrics/avoid.json: every method's cells and calibration beside the paper's numbers, and one
    figure of all methods' paths (known with warnings on, unknown off and on)."""
    results_dir, data_dir = Path(cfg.summary.results_dir), Path(cfg.summary.data_dir)
    table: dict = {"paper": PAPER}
    panels = {}
    columns = [("known", "on"), ("unknown", "off"), ("unknown", "on")]
    for method in cfg.methods:
        path = results_dir / f"{method}.json"
        if not path.exists():
            raise FileNotFoundError(f"{path} is missing; run `python stages/avoid.py model={method}` "
                                    "(or dvc repro) first")
        result = json.loads(path.read_text())
        table[method] = {
            **{c: {m: {k: v for k, v in cell.items() if k in SUMMARY_KEYS} for m, cell in modes.items()}
               for c, modes in result["cells"].items()},
            "calibration": {k: v for k, v in result["calibration"].items() if k != "replayed"},
            "samples_per_frame": result["samples_per_frame"]}
        for condition, mode in columns:
            with np.load(data_dir / method / f"{method}-{condition}-{mode}.npz") as data:
                panels[(method, f"{condition}, warnings {mode}")] = _panel_from_data(data)
    fig = avoid_trajectories_figure(panels, list(cfg.methods), [f"{c}, warnings {m}" for c, m in columns],
                                    "Collision avoidance: paths coloured by mutual information")
    figure = save_figure(fig, Path(cfg.summary.figures_dir) / "coll_avoid_main.png")
    write_json(cfg.summary.out, table)
    return {"table": table, "figures": [str(figure)]}


def _panel_from_data(data) -> dict:
    rollout = data["rollout"]
    paths = [{"x": data["x"][rollout == i], "y": data["y"][rollout == i], "mi": data["mi"][rollout == i],
              "termination": str(t)} for i, t in enumerate(data["termination"])]
    return {"paths": paths, "obstacle": data["obstacle"], "road": data["road"],
            "title": f"η̂1 = {float(data['eta1']):.2f}"}
