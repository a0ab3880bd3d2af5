"""The `safety` stage: η1 of one offline controller in one sweep cell (method × replicate × location × weather ×
noise), each cell as the single-cell command composes it, the whole sweep in one process.

Every cell drives the same rollout seeds (base_seed + i), so methods and conditions are compared
on paired runs: the same start jitter, rain streaks and sensor noise.

Every input is checked (method, model file, estimator, speed, world, executor) before the
first rollout. A cell whose result file already holds its config hash is not run again.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Sequence
from contextlib import nullcontext
from pathlib import Path

import matplotlib.pyplot as plt
import mlflow
import numpy as np
from omegaconf import DictConfig

from uqdrive.files import atomic_path, write_csv
from uqdrive.models.posterior import posterior_from_config
from uqdrive.pipeline.configs import Executor, ModelStage, Sweep, train_stage
from uqdrive.pipeline.records import SafetyCell, as_dict, read_record, write_record
from uqdrive.pipeline.sweeps import grid, run_cells
from uqdrive.plots import safety_hexbin, save_figure
from uqdrive.safety.cells import EstimatorSettings, cell_posterior, rates
from uqdrive.safety.draws import DrawSettings
from uqdrive.safety.executors import PolicySpec, RolloutJob
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.runner import CellRunner, estimate_key
from uqdrive.safety.safe_sets import SafeSet, safe_set_for
from uqdrive.schema import Bool, Count, NonNegative, Positive, Str, invalid, schema, validate
from uqdrive.sim import ScenarioGeometry, build_geometry
from uqdrive.sim.config import ScenarioConfig, SimConfig, WeatherConfig
from uqdrive.tracking import numeric_metrics, stage_run

EXTENT_MARGIN = 12.0  # metres around the reference route shown in the figures


@schema(frozen=True, kw_only=True)
class SafetySection(EstimatorSettings):
    """conf/safety.yaml's `safety`: one cell's estimator (scheme, theta, gamma, look_size, base_seed), controller
    and outputs."""

    model_path: Str
    horizon_s: Positive  # T
    speed: Positive  # m/s, at most vehicle.max_speed
    samples: Count  # posterior draws per frame (the cap, with sequential draws)
    draws: DrawSettings  # fixed (the paper's) or sequential draws per frame
    eps: Positive  # η2's ball, steering units
    family_wise: Bool  # the sweep spends γ over its cells: every cell within ±θ at once with probability ≥ 1 − γ
    family_size: Count  # cells γ is spread over (the sweep sets it to its cell count); 1 unless family_wise
    half_width: Positive | None  # corridor half-width (m); None = the lane
    cell: Str
    out: Str
    positions: Str
    rollout_log: Str
    plots_dir: Str


@schema(root=True)
class SafetyStage(SimConfig, ModelStage):
    """`stages/safety.py`: one cell of the offline-safety sweep."""

    scenario: ScenarioConfig
    weather: WeatherConfig
    noise: NonNegative
    executor: Executor
    safety: SafetySection

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.safety.speed > self.vehicle.max_speed:
            raise invalid("safety.speed", self.safety.speed, f"must be <= vehicle.max_speed={self.vehicle.max_speed}")
        if self.safety.family_size != 1 and not self.safety.family_wise:
            raise invalid("safety.family_size", self.safety.family_size, "must be 1 unless safety.family_wise")

    @property
    def estimator(self) -> EstimatorSettings:
        """The cell's estimator: γ spread over the family's cells (Bonferroni) when family-wise."""
        s = self.safety
        return dataclasses.replace(s.estimator, gamma=s.gamma / s.family_size)


@schema(root=True)
class SafetySweepStage(SafetyStage):
    """`stages/safety_sweep.py`: every cell of `sweep` (each cell is also checked as a `SafetyStage`)."""

    sweep: Sweep


def build_job(cfg: DictConfig) -> tuple[SafetyStage, RolloutJob, str]:
    """Validate the cell's config and load its model once; returns the stage config, the job and the cell's key.

    Raises before any rollout on a bad config value (one line naming the key, the value and what is
    allowed), a missing or mismatched model file.
    """
    stage = validate(SafetyStage, cfg)
    safety = stage.safety
    method = posterior_from_config(stage.model).method
    bins = stage.experiment.bins
    model_path = Path(safety.model_path)
    trained_by = train_stage(stage.experiment.name, method)
    cell_posterior("safety.model_path", model_path, method, bins, trained_by)
    spec = PolicySpec(
        "bnn", safety.speed, str(model_path), method, bins, safety.samples, safety.eps, draws=safety.draws
    )
    job = RolloutJob(
        policy=spec,
        scenario=stage.scenario,
        weather=stage.weather,
        noise=stage.noise,
        base_seed=safety.base_seed,
        camera=stage.camera,
        vehicle=stage.vehicle,
        control_hz=stage.control_hz,
        horizon_s=safety.horizon_s,
        half_width=safety.half_width,
    )
    return stage, job, estimate_key(job, stage.estimator, __name__)


def reusable_result(path: str | Path, key: str) -> SafetyCell | None:
    """The finished cell at ``path`` if it was computed for the cell with key ``key`` (by this code: a file of
    another format is not reused)."""
    try:
        cell = read_record(SafetyCell, path, "safety")
    except (FileNotFoundError, ValueError):
        return None
    return cell if cell.config_hash == key else None


def _positions(results: list[RolloutResult]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rollout = np.concatenate([np.full(len(r.x), i) for i, r in enumerate(results)]) if results else np.zeros(0, int)
    x = np.concatenate([r.x for r in results]) if results else np.zeros(0)
    y = np.concatenate([r.y for r in results]) if results else np.zeros(0)
    return rollout, x, y


def _extent(route: np.ndarray) -> np.ndarray:
    lo, hi = route.min(0) - EXTENT_MARGIN, route.max(0) + EXTENT_MARGIN
    return np.array([lo[0], hi[0], lo[1], hi[1]])


def road_raster(geometry: ScenarioGeometry, extent: np.ndarray, cell: float = 0.25) -> np.ndarray:
    """Paved area inside ``extent`` (xmin, xmax, ymin, ymax) as a bool image [rows = y ascending, cols = x]:
    the map the figures draw the paths on."""
    xs = np.arange(extent[0], extent[1], cell) + cell / 2
    ys = np.arange(extent[2], extent[3], cell) + cell / 2
    gx, gy = np.meshgrid(xs, ys)
    return geometry.is_paved(np.stack([gx.ravel(), gy.ravel()], axis=1)).reshape(gx.shape)


def write_outputs(
    cfg: DictConfig,
    results: list[RolloutResult],
    geometry: ScenarioGeometry,
    safe_set: SafeSet,
    eta1: float,
    title: str,
) -> tuple[Path, Path, Path]:
    """Per-rollout table (CSV), visited positions with the road, route and safe-set edges (npz, for the
    summary figures) and the cell's hexbin figure."""
    plots = Path(cfg.safety.plots_dir)
    table = write_csv(plots / f"{cfg.safety.cell}.csv", [r.summary() for r in results])
    route = np.stack([safe_set.route_x, safe_set.route_y], axis=1)
    edges = safe_set.boundaries()
    left, right = edges if edges is not None else (np.zeros((0, 2)), np.zeros((0, 2)))
    rollout, x, y = _positions(results)
    extent = _extent(route)
    road = road_raster(geometry, extent)
    positions = Path(cfg.safety.positions)
    with atomic_path(positions) as tmp:
        with tmp.open("wb") as f:
            np.savez_compressed(
                f, rollout=rollout, x=x, y=y, route=route, left=left, right=right, extent=extent, road=road, eta1=eta1
            )
    fig, ax = plt.subplots(figsize=(5, 5))
    safety_hexbin(ax, x, y, route, edges, tuple(extent), title, road)
    ax.legend(loc="lower left", fontsize=7)
    figure = save_figure(fig, plots / f"{cfg.safety.cell}.png")
    return table, positions, figure


def run_safety(cfg: DictConfig, runner: CellRunner | None = None) -> dict:
    """Estimate η1 for one cell; reuses the cell's result file when its key matches, and the rollouts its log
    holds. ``runner``: shared by many cells (`run_safety_sweep`), else the cell's own. ``reused`` in the result:
    nothing was simulated."""
    stage, job, key = build_job(cfg)
    out = Path(cfg.safety.out)
    previous = reusable_result(out, key)
    if previous is not None:
        log_cell(cfg, previous, [p for p in _cell_files(cfg) if p.exists()], reused=True)
        return {**as_dict(previous), "reused": True}
    with nullcontext(runner) if runner else CellRunner.of(stage.executor, stage.progress) as cells:
        run = cells.estimate(f"safety {cfg.safety.cell}", job, stage.estimator, key, cfg.safety.rollout_log)
    estimate, results = run.outcome, run.results
    geometry = build_geometry(job.scenario)
    safe_set = safe_set_for(geometry, job.vehicle.width, job.vehicle.length, job.half_width)
    title = (
        f"{cfg.model.name} · {job.scenario.name} · {job.weather.name} · noise {job.noise:g}: "
        f"η̂1 = {estimate.value:.2f} [{estimate.low:.2f}, {estimate.high:.2f}]"
    )
    table, positions, figure = write_outputs(cfg, results, geometry, safe_set, estimate.value, title)
    cell = SafetyCell(
        method=cfg.model.name,
        replicate=stage.seed,
        experiment=cfg.experiment.name,
        location=job.scenario.name,
        weather=job.weather.name,
        noise=job.noise,
        theta=estimate.theta,
        gamma=estimate.gamma,
        scheme=estimate.scheme,
        n=estimate.n,
        base_seed=stage.safety.base_seed,
        family_size=stage.safety.family_size,
        fixed_rollouts=stage.estimator.fixed_rollouts(),
        eta1=estimate.value,
        eta1_low=estimate.low,
        eta1_high=estimate.high,
        rollouts=estimate.n,
        steps=int(sum(r.steps for r in results)),
        seconds=run.seconds,
        **rates(results),
        guaranteed=estimate.guaranteed,
        outcomes="".join("1" if r.safe else "0" for r in results),  # by rollout index: paired across cells
        config_hash=key,
        unread=run.unread,
    )
    write_record(out, cell)  # before logging: a tracking failure never loses the cell; its presence marks it done
    log_cell(cfg, cell, [figure, table], reused=run.reused)
    return {**as_dict(cell), "reused": run.reused}


def run_safety_sweep(cfg: DictConfig, overrides: Sequence[str]) -> Iterator[tuple[DictConfig, dict]]:
    """Every cell of ``cfg.sweep`` (methods × replicates × locations × weathers × noises) in this process, on one
    cell runner (one pool of workers with the process backend); yields each cell's config and result as it
    finishes (`uqdrive.pipeline.sweeps`)."""
    stage = validate(SafetySweepStage, cfg)
    s = cfg.sweep  # the values as written: a cell's override is what the single-cell command would be given
    cells = grid(model=s.methods, seed=s.replicates, scenario=s.locations, weather=s.weathers, noise=s.noises)
    if stage.safety.family_wise:  # every cell at γ/m: the whole sweep within ±θ at once with probability ≥ 1 − γ
        cells = [{**cell, "safety.family_size": len(cells)} for cell in cells]
    runner = CellRunner.of(stage.executor, stage.progress)
    yield from run_cells("safety", overrides, cells, SafetyStage, run_safety, runner, stage.progress)


def describe(cell: str, result: dict) -> str:
    """The line a stage prints for a finished cell."""
    r = result
    return (
        f"safety {cell}: eta1 = {r['eta1']:.3f} in [{r['eta1_low']:.3f}, {r['eta1_high']:.3f}] "
        f"from {r['n']} rollouts ({r['scheme']}, theta={r['theta']:g}, gamma={r['gamma']:g})"
        f"{' (reused: config unchanged)' if r['reused'] else ''}"
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


def _cell_files(cfg: DictConfig) -> list[Path]:
    plots = Path(cfg.safety.plots_dir)
    return [plots / f"{cfg.safety.cell}.png", plots / f"{cfg.safety.cell}.csv"]


def log_cell(cfg: DictConfig, cell: SafetyCell, artifacts: list[Path], reused: bool = False) -> None:
    """One MLflow run per cell, a reused one too (tagged ``reused``), so a sweep's runs list every cell."""
    metrics = numeric_metrics({k: v for k, v in as_dict(cell).items() if k not in CELL_PARAMS})
    with stage_run(
        cfg.paths.root,
        "safety",
        cfg,
        run_name=cfg.safety.cell,
        tags={"reused": str(reused).lower(), "config_hash": cell.config_hash},
    ):
        mlflow.log_params({"n": cell.n, "cell_gamma": cell.gamma})  # the rest: the cell's config (`stage_run`)
        mlflow.log_metrics(metrics)
        for path in artifacts:
            mlflow.log_artifact(str(path))
