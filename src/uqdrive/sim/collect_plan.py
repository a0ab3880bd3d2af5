"""The collect stage's schema (`CollectStage`, its `CollectSection`) and what a run returns (`Collection`). The stage
function is `uqdrive.pipeline.collect_stage`'s; the heldout stage builds on the same schema."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from uqdrive.records import record
from uqdrive.schema import Count, Seed, Str, schema
from uqdrive.sim.condition import WorldChoice
from uqdrive.sim.config import SimConfig
from uqdrive.sim.gym_hooks import require_expert
from uqdrive.sim.location import ByWorld, nothing
from uqdrive.stage_schemas import Stage, Sweep


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


@schema(root=True)
class HeldoutStage(CollectStage):
    sweep: Sweep


FileName = Annotated[Str, Field(pattern=r"^[A-Za-z0-9_-][A-Za-z0-9_.-]*$")]  # letters, digits, _ - . (no folders)
