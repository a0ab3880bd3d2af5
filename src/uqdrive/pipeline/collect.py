"""The `collect` stage: autopilot episodes in one scenario → one parquet row per camera frame."""

from __future__ import annotations

import dataclasses
import re
from collections import Counter
from collections.abc import Iterator, Sequence
from pathlib import Path

import mlflow
import numpy as np
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from uqdrive.checks import ConfigError
from uqdrive.data.frames import encode_png
from uqdrive.data.tables import RAW_SCHEMA, write_table_batches
from uqdrive.files import atomic_path, write_json
from uqdrive.parallel import ProcessPool
from uqdrive.pipeline.sweeps import grid, run_cells
from uqdrive.plots import mosaic
from uqdrive.sim import (
    Autopilot,
    AutopilotConfig,
    CameraConfig,
    DrivingEnv,
    ScenarioConfig,
    VehicleConfig,
    WeatherConfig,
    check_noise,
)
from uqdrive.tracking import stage_run


def make_env(cfg: DictConfig) -> DrivingEnv:
    return DrivingEnv(
        camera=CameraConfig.from_config(cfg.camera),
        vehicle=VehicleConfig.from_config(cfg.vehicle),
        control_hz=cfg.control_hz,
        horizon_s=cfg.horizon_s,
    )


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
    """Autopilot episodes of one collect config (a plain, picklable copy), for `uqdrive.parallel.ProcessPool`."""

    cfg: dict

    def worker(self) -> EpisodeWorker:
        return EpisodeWorker(DictConfig(self.cfg))


class EpisodeWorker:
    """One env (its own pybullet client) reused for every episode this process records."""

    def __init__(self, cfg: DictConfig):
        self.cfg = cfg
        self.env = make_env(cfg)
        self.autopilot = AutopilotConfig.from_config(cfg.autopilot)
        self.scenario = ScenarioConfig.from_config(cfg.scenario)
        self.weather = WeatherConfig.from_config(cfg.weather)

    def run(self, episode: int) -> tuple[int, dict[str, list], str, list[np.ndarray]]:
        """Episode ``episode`` (seed collect.base_seed + episode): its seed, rows, termination and mosaic frames."""
        cfg = self.cfg
        seed = cfg.collect.base_seed + episode
        rows, termination, frames = record_episode(
            self.env, self.autopilot, seed, self.scenario, self.weather, cfg.noise
        )
        picks = np.linspace(0, len(frames) - 1, cfg.collect.mosaic_columns + 2)[1:-1].astype(int)
        return seed, rows, termination, [frames[i] for i in picks]

    def close(self) -> None:
        self.env.close()


def iter_episodes(
    cfg: DictConfig, outcomes: Counter, mosaic_frames: list[np.ndarray], pool: ProcessPool | None = None
) -> Iterator[dict[str, list]]:
    """Yield one column batch per episode, in episode order whatever the worker count. ``pool``: worker
    processes shared with other collections (the `heldout` stage's conditions), else the stage's own."""
    job = EpisodeJob(OmegaConf.to_container(cfg, resolve=True))
    executor = (pool or ProcessPool(cfg.collect.workers, "collect.workers")).executor(job, owns_pool=pool is None)
    progress = tqdm(
        executor.run(range(cfg.collect.episodes)),
        total=cfg.collect.episodes,
        desc=f"collect {cfg.collect.name}",
        unit="episode",
        disable=not cfg.progress,
    )
    try:
        for episode, (seed, rows, termination, picks) in enumerate(progress):
            outcomes[termination] += 1
            if episode < cfg.collect.mosaic_rows:
                mosaic_frames.extend(picks)
            n = len(rows["step"])
            yield {
                "scenario": [cfg.scenario.name] * n,
                "weather": [cfg.weather.name] * n,
                "noise": [cfg.noise] * n,
                "episode": [episode] * n,
                "seed": [seed] * n,
                **rows,
            }
    finally:
        executor.close()


def check_name(name: object) -> str:
    """`collect.name` becomes file names, so it must be a plain one: no folders, nothing a shell would mangle."""
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9_.-]+", name) or name.startswith("."):
        raise ConfigError(
            f"collect.name={name!r} must be a plain file name: letters, digits, '_', '-', '.' (not starting with '.')"
        )
    return name


def run_collect(cfg: DictConfig, pool: ProcessPool | None = None) -> dict:
    """Record cfg.collect.episodes autopilot episodes; ``pool``: worker processes shared by many collections."""
    ScenarioConfig.from_config(cfg.scenario)
    name = check_name(cfg.collect.name)
    WeatherConfig.from_config(cfg.weather)
    check_noise(cfg.noise)
    if cfg.collect.episodes < 1:
        raise ConfigError(f"collect.episodes={cfg.collect.episodes} must be >= 1")
    out = Path(cfg.collect.out)
    outcomes: Counter = Counter()
    mosaic_frames: list[np.ndarray] = []
    frames = write_table_batches(out, RAW_SCHEMA, iter_episodes(cfg, outcomes, mosaic_frames, pool))
    metrics = {
        "episodes": cfg.collect.episodes,
        "frames": frames,
        "route_complete_fraction": outcomes["route_complete"] / cfg.collect.episodes,
        **{f"episodes_{reason}": outcomes[reason] for reason in ("collision", "off_road", "timeout")},
    }
    write_json(cfg.collect.metrics, metrics)
    mosaic_path = Path(cfg.collect.mosaic)
    with atomic_path(mosaic_path) as tmp:
        tmp.write_bytes(encode_png(mosaic(mosaic_frames, cfg.collect.mosaic_columns)))
    with stage_run(cfg.paths.root, "collect", cfg, run_name=name):
        mlflow.log_metrics(metrics)
        mlflow.log_artifact(str(mosaic_path))
    return {**metrics, "path": str(out)}


def run_heldout(cfg: DictConfig, overrides: Sequence[str]) -> Iterator[tuple[DictConfig, dict]]:
    """Held-out frames in every condition of ``cfg.sweep`` (weathers × noises) in this process, on one pool of
    workers; yields each condition's config and result as it finishes (`uqdrive.pipeline.sweeps`)."""
    cells = grid(weather=cfg.sweep.weathers, noise=cfg.sweep.noises)
    pool = ProcessPool(cfg.collect.workers, "collect.workers")
    yield from run_cells("heldout", overrides, cells, run_collect, pool, cfg.progress)


def describe(result: dict) -> str:
    """The line a stage prints for a finished collection."""
    return (
        f"collect: {result['frames']} frames from {result['episodes']} episodes "
        f"(route completed in {result['route_complete_fraction']:.0%}) -> {result['path']}"
    )
