"""The `collect` stage: expert episodes in one scenario (`uqdrive.sim.episodes`: the autopilot, or a Gymnasium world's
own expert with ``gym_world=<conf/gym_world/ file>``) → one parquet row per camera frame, a mosaic of frames, the
collection's metrics."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated

import mlflow
import numpy as np
from omegaconf import DictConfig
from pydantic import Field
from tqdm import tqdm

from uqdrive.data.frames import encode_png
from uqdrive.data.tables import RAW_SCHEMA, write_table_batches
from uqdrive.figures import mosaic
from uqdrive.files import atomic_path
from uqdrive.network_input import INPUT_HEIGHT, INPUT_WIDTH
from uqdrive.parallel import ProcessPool
from uqdrive.records import as_dict, record, write_record
from uqdrive.schema import Count, Seed, Str, schema, validate
from uqdrive.sim.condition import WorldChoice
from uqdrive.sim.config import SimConfig
from uqdrive.sim.episodes import EpisodeJob
from uqdrive.sim.gym_hooks import require_expert
from uqdrive.sim.location import ByWorld, nothing
from uqdrive.stage_schemas import Stage
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
class CollectStage(WorldChoice, SimConfig, Stage):
    """`stages/collect.py` (and each condition of `stages/heldout.py`), in a pybullet location or a Gymnasium world
    (`WorldChoice`; there the world's own control rate and horizon, and frames at the network's size)."""

    collect: CollectSection

    def __post_init__(self) -> None:
        super().__post_init__()
        self.choose(ByWorld(road=nothing, gym=lambda world: require_expert(world.hooks, world.env_id)))


@record
class Collection:
    """metrics/collect/<scenario>.json: episodes and frames recorded, how the episodes ended (a Gymnasium world has no
    route: an episode it did not end early ends by timeout), the render size (every frame is delivered at the
    network's 64x48)."""

    episodes: int
    frames: int
    route_complete_fraction: float
    episodes_collision: int
    episodes_off_road: int
    episodes_timeout: int
    render_width: int
    render_height: int


def episode_job(stage: CollectStage) -> EpisodeJob:
    sim = SimConfig(stage.control_hz, stage.horizon_s, stage.camera, stage.vehicle, stage.autopilot)
    return EpisodeJob(sim, stage.condition(), stage.collect.base_seed, stage.collect.mosaic_columns, encode_png)


def iter_episodes(
    stage: CollectStage, outcomes: Counter, mosaic_frames: list[np.ndarray], pool: ProcessPool | None = None
) -> Iterator[dict[str, list]]:
    """Yield one column batch per episode, in episode order whatever the worker count. ``pool``: worker
    processes shared with other collections (the `heldout` stage's conditions), else the stage's own."""
    collect, job = stage.collect, episode_job(stage)
    executor = (pool or ProcessPool(collect.workers)).executor(job, owns_pool=pool is None)
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
                "scenario": [job.where.location] * n,
                "weather": [job.where.weather_name] * n,
                "noise": [stage.noise] * n,
                "episode": [episode] * n,
                "seed": [seed] * n,
                **rows,
            }
    finally:
        executor.close()


def run_collect(cfg: DictConfig, pool: ProcessPool | None = None) -> Collection:
    """Record collect.episodes autopilot episodes; ``pool``: worker processes shared by many collections."""
    stage = validate(CollectStage, cfg)
    collect = stage.collect
    outcomes: Counter = Counter()
    mosaic_frames: list[np.ndarray] = []
    frames = write_table_batches(collect.out, RAW_SCHEMA, iter_episodes(stage, outcomes, mosaic_frames, pool))
    collection = Collection(
        episodes=collect.episodes,
        frames=frames,
        route_complete_fraction=outcomes["route_complete"] / collect.episodes,
        episodes_collision=outcomes["collision"],
        episodes_off_road=outcomes["off_road"],
        episodes_timeout=outcomes["timeout"],
        render_width=INPUT_WIDTH if stage.gym_world else stage.camera.width,
        render_height=INPUT_HEIGHT if stage.gym_world else stage.camera.height,
    )
    image = encode_png(mosaic(mosaic_frames, collect.mosaic_columns))
    write_record(collect.metrics, collection)
    mosaic_path = Path(collect.mosaic)
    with atomic_path(mosaic_path) as tmp:
        tmp.write_bytes(image)
    with stage_run(stage.paths.root, "collect", cfg, run_name=collect.name):
        mlflow.log_metrics(as_dict(collection))
        mlflow.log_artifact(str(mosaic_path))
    return collection


def describe(collection: Collection, path: str) -> str:
    """The line a stage prints for a finished collection."""
    c = collection
    return (
        f"collect: {c.frames} frames from {c.episodes} episodes (route completed in {c.route_complete_fraction:.0%}, "
        f"{c.episodes_timeout} to the horizon, rendered at {c.render_width}x{c.render_height}) -> {path}"
    )
