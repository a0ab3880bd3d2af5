"""The `collect` stage: expert episodes in one scenario (`uqdrive.sim.episodes`: the autopilot, or a Gymnasium world's
own expert with ``gym_world=<conf/gym_world/ file>``) → one parquet row per camera frame, a mosaic of frames, the
collection's metrics."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import mlflow
import numpy as np
from omegaconf import DictConfig
from tqdm import tqdm

from uqdrive.data.frames import encode_png
from uqdrive.data.tables import RAW_SCHEMA, write_table_batches
from uqdrive.figures import mosaic
from uqdrive.files import atomic_path
from uqdrive.network_input import INPUT_HEIGHT, INPUT_WIDTH
from uqdrive.parallel import ProcessPool
from uqdrive.records import as_dict, write_record
from uqdrive.schema import validate
from uqdrive.sim.collect_plan import Collection, CollectStage
from uqdrive.sim.config import SimConfig
from uqdrive.sim.episodes import EpisodeJob
from uqdrive.tracking import stage_run


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
