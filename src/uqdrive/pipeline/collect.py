"""The `collect` stage: autopilot episodes in one scenario → one parquet row per camera frame."""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Annotated

import mlflow
import numpy as np
from omegaconf import DictConfig
from pydantic import Field
from tqdm import tqdm

from uqdrive.data.frames import encode_png
from uqdrive.data.tables import RAW_SCHEMA, write_table_batches
from uqdrive.files import atomic_path, write_json
from uqdrive.parallel import ProcessPool
from uqdrive.pipeline.configs import Stage, Sweep
from uqdrive.pipeline.sweeps import grid, run_cells
from uqdrive.plots import mosaic
from uqdrive.schema import Count, NonNegative, Seed, Str, schema, validate
from uqdrive.sim import Autopilot, AutopilotConfig, DrivingEnv, ScenarioConfig, WeatherConfig
from uqdrive.sim.config import SimConfig
from uqdrive.tracking import stage_run

FileName = Annotated[Str, Field(pattern=r"^[A-Za-z0-9_-][A-Za-z0-9_.-]*$")]  # letters, digits, _ - . (no folders)


@schema
class CollectSection:
    out: Str
    name: FileName  # the MLflow run, and file names
    metrics: Str
    mosaic: Str
    episodes: Count
    base_seed: Seed
    workers: Count
    mosaic_rows: Seed
    mosaic_columns: Count


@schema(root=True)
class CollectStage(SimConfig, Stage):
    """`stages/collect.py` (and each condition of `stages/heldout.py`)."""

    scenario: ScenarioConfig
    weather: WeatherConfig
    noise: NonNegative
    collect: CollectSection


@schema(root=True)
class HeldoutStage(CollectStage):
    sweep: Sweep


def record_episode(
    env: DrivingEnv,
    autopilot_cfg: AutopilotConfig,
    seed: int,
    scenario: ScenarioConfig,
    weather: WeatherConfig,
    noise: float,
) -> tuple[dict[str, list], str, list[np.ndarray]]:
    """Drive one episode; each row pairs the frame seen at step k with the autopilot's label for it."""
    rows: dict[str, list] = {
        name: [] for name in RAW_SCHEMA.names if name not in {"scenario", "weather", "noise", "episode", "seed"}
    }
    frames: list[np.ndarray] = []
    obs = env.reset(seed, scenario, weather, noise)
    autopilot = Autopilot(env.route, env.vehicle_config, autopilot_cfg, env.control_hz, seed=seed)
    info = env.last_info
    step = 0
    while not env.done:
        action = autopilot.act(info)
        for key in ("t", "x", "y", "yaw", "speed", "lateral_deviation"):
            rows[key].append(info[key])
        rows["step"].append(step)
        rows["steering"].append(action.label)
        rows["applied_steering"].append(action.steer)
        rows["image"].append(encode_png(obs))
        frames.append(obs)
        obs, info = env.step(action.steer, action.speed)
        step += 1
    return rows, info["termination"], frames


@dataclasses.dataclass(frozen=True)
class EpisodeJob:
    """Autopilot episodes of one collect config, for `uqdrive.parallel.ProcessPool` (only the world's settings:
    a worker imports no more than the simulator)."""

    sim: SimConfig
    scenario: ScenarioConfig
    weather: WeatherConfig
    noise: float
    base_seed: int
    mosaic_columns: int

    @classmethod
    def of(cls, stage: CollectStage) -> EpisodeJob:
        sim = SimConfig(stage.control_hz, stage.horizon_s, stage.camera, stage.vehicle, stage.autopilot)
        collect = stage.collect
        return cls(sim, stage.scenario, stage.weather, stage.noise, collect.base_seed, collect.mosaic_columns)

    def worker(self) -> EpisodeWorker:
        return EpisodeWorker(self)


class EpisodeWorker:
    """One env (its own pybullet client) reused for every episode this process records."""

    def __init__(self, job: EpisodeJob):
        self.job = job
        self.env = DrivingEnv(job.sim.camera, job.sim.vehicle, job.sim.control_hz, job.sim.horizon_s)

    def run(self, episode: int) -> tuple[int, dict[str, list], str, list[np.ndarray]]:
        """Episode ``episode`` (seed collect.base_seed + episode): its seed, rows, termination and mosaic frames."""
        job = self.job
        seed = job.base_seed + episode
        rows, termination, frames = record_episode(
            self.env, job.sim.autopilot, seed, job.scenario, job.weather, job.noise
        )
        picks = np.linspace(0, len(frames) - 1, job.mosaic_columns + 2)[1:-1].astype(int)
        return seed, rows, termination, [frames[i] for i in picks]

    def close(self) -> None:
        self.env.close()


def iter_episodes(
    stage: CollectStage, outcomes: Counter, mosaic_frames: list[np.ndarray], pool: ProcessPool | None = None
) -> Iterator[dict[str, list]]:
    """Yield one column batch per episode, in episode order whatever the worker count. ``pool``: worker
    processes shared with other collections (the `heldout` stage's conditions), else the stage's own."""
    collect = stage.collect
    executor = (pool or ProcessPool(collect.workers)).executor(EpisodeJob.of(stage), owns_pool=pool is None)
    progress = tqdm(
        executor.run(range(collect.episodes)),
        total=collect.episodes,
        desc=f"collect {collect.name}",
        unit="episode",
        disable=not stage.progress,
    )
    try:
        for episode, (seed, rows, termination, picks) in enumerate(progress):
            outcomes[termination] += 1
            if episode < collect.mosaic_rows:
                mosaic_frames.extend(picks)
            n = len(rows["step"])
            yield {
                "scenario": [stage.scenario.name] * n,
                "weather": [stage.weather.name] * n,
                "noise": [stage.noise] * n,
                "episode": [episode] * n,
                "seed": [seed] * n,
                **rows,
            }
    finally:
        executor.close()


def run_collect(cfg: DictConfig, pool: ProcessPool | None = None) -> dict:
    """Record collect.episodes autopilot episodes; ``pool``: worker processes shared by many collections."""
    stage = validate(CollectStage, cfg)
    name, episodes = stage.collect.name, stage.collect.episodes
    out = Path(stage.collect.out)
    outcomes: Counter = Counter()
    mosaic_frames: list[np.ndarray] = []
    frames = write_table_batches(out, RAW_SCHEMA, iter_episodes(stage, outcomes, mosaic_frames, pool))
    metrics = {
        "episodes": episodes,
        "frames": frames,
        "route_complete_fraction": outcomes["route_complete"] / episodes,
        **{f"episodes_{reason}": outcomes[reason] for reason in ("collision", "off_road", "timeout")},
        "render_width": stage.camera.width,  # the camera's render size (every frame is delivered at 64x48)
        "render_height": stage.camera.height,
    }
    write_json(stage.collect.metrics, metrics)
    mosaic_path = Path(stage.collect.mosaic)
    with atomic_path(mosaic_path) as tmp:
        tmp.write_bytes(encode_png(mosaic(mosaic_frames, stage.collect.mosaic_columns)))
    with stage_run(cfg.paths.root, "collect", cfg, run_name=name):
        mlflow.log_metrics(metrics)
        mlflow.log_artifact(str(mosaic_path))
    return {**metrics, "path": str(out)}


def run_heldout(cfg: DictConfig, overrides: Sequence[str]) -> Iterator[tuple[DictConfig, dict]]:
    """Held-out frames in every condition of ``cfg.sweep`` (weathers × noises) in this process, on one pool of
    workers; yields each condition's config and result as it finishes (`uqdrive.pipeline.sweeps`)."""
    stage = validate(HeldoutStage, cfg)
    cells = grid(weather=cfg.sweep.weathers, noise=cfg.sweep.noises)  # as written, as the single-condition command
    pool = ProcessPool(stage.collect.workers)
    yield from run_cells("heldout", overrides, cells, CollectStage, run_collect, pool, stage.progress)


def describe(result: dict) -> str:
    """The line a stage prints for a finished collection."""
    return (
        f"collect: {result['frames']} frames from {result['episodes']} episodes "
        f"(route completed in {result['route_complete_fraction']:.0%}, rendered at "
        f"{result['render_width']}x{result['render_height']}) -> {result['path']}"
    )
