"""The acquire stage's schema and plan: the stage's config (`AcquireStage`, its `AcquireSection`), where a round
drives (`Where`) and what every round shares (`Rounds`). The stage functions are
`uqdrive.pipeline.acquire_stage`'s."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from uqdrive.resolvers import condition_label, world_location
from uqdrive.safety.plan import SafetyStage
from uqdrive.safety.runner import CellRunner
from uqdrive.schema import Count, NonNegative, OpenUnit, Seed, Str, Unit, invalid, schema
from uqdrive.sim.condition import NO_WEATHER
from uqdrive.sim.config import WorldAxis
from uqdrive.stage import compose_cell
from uqdrive.uq import Estimate


@schema
class Where:
    """A condition as a safety cell names it: location (a scenario, or a Gymnasium world or one of its
    ``acquire.world_axis`` locations), weather (``env`` in a Gymnasium world) and sensor noise σ."""

    location: Str
    weather: Str
    noise: NonNegative

    @property
    def label(self) -> str:
        return condition_label(self.location, self.weather, self.noise)


@schema
class AcquireSection:
    """conf/acquire.yaml's `acquire`."""

    rounds: Seed  # DAgger rounds; 0: the behaviour-cloned controller alone
    episodes: Count  # rollouts per acquisition condition and round
    beta: Unit  # round 1's chance per step that the expert drives instead of the learner
    beta_decay: Unit  # β of round k: beta · beta_decay^(k−1)
    base_seed: Seed  # acquisition rollouts: seeds base_seed + replicate·1,000,000 + i, apart from the sweep's
    check_seed: Seed  # rounds > 0: every round's check rollouts (round 0's too), apart from the sweep's seeds
    check_theta: OpenUnit | None  # rounds > 0: the check cells' θ, smaller than the sweep's for more paired runs
    target: Unit  # a swept condition is flagged when the upper end of η1's interval is below it
    margin: OpenUnit  # the training condition is non-inferior when its paired loss is bounded below this
    cells_dir: Str  # the previous offline-safety sweep's cells (metrics/safety/<method>-seed<r>-<condition>.json)
    training: Where  # the condition the training data was collected at: acquired at and checked every round
    checks: tuple[Where, ...]  # further check cells, never acquired at (e.g. an untouched location)
    world_axis: WorldAxis | None  # a Gymnasium world's swept condition, to place its flagged cells (gym_world.axis)
    expert_logs: Str  # the expert's check rollouts, by condition
    out_dir: Str
    out: Str


@schema(root=True)
class AcquireStage(SafetyStage):
    """`stages/acquire.py`: the safety cell's controller, world and estimator (conf/safety.yaml) and the rounds."""

    acquire: AcquireSection

    def __post_init__(self) -> None:
        super().__post_init__()
        for key, where in (
            ("acquire.training", self.acquire.training),
            *((f"acquire.checks[{i}]", w) for i, w in enumerate(self.acquire.checks)),
        ):
            placed(self, where, key)


@dataclasses.dataclass
class Rounds:
    """What every round of one stage run shares."""

    cfg: DictConfig
    stage: AcquireStage
    rollout_overrides: list[str]
    train_overrides: list[str]
    conditions: list[Where]
    checks: list[Where]
    runner: CellRunner
    key: str
    expert: dict[str, Estimate] = dataclasses.field(default_factory=dict)

    def folder(self, k: int) -> Path:
        return Path(self.stage.acquire.out_dir) / f"round{k}"

    def safety_config(self, where: Where, model: Path, **more: Any) -> DictConfig:
        cell = {**placed(self.stage, where), "safety.model_path": str(model), **more}
        return compose_cell("safety", self.rollout_overrides, cell)


def placed(stage: AcquireStage, where: Where, key: str = "acquire") -> dict[str, Any]:
    """The overrides of conf/safety.yaml that put its cell at ``where``."""
    world = stage.gym_world
    if world is None:
        if where.weather == NO_WEATHER:
            raise invalid(f"{key}.weather", where.weather, "must name a weather (conf/weather/) in the pybullet world")
        return {"scenario": where.location, "weather": where.weather, "noise": where.noise}
    if where.weather != NO_WEATHER:
        raise invalid(f"{key}.weather", where.weather, f"must be {NO_WEATHER!r}: {world.env_id} has its own")
    axis = stage.acquire.world_axis
    if where.location == world.name:
        return {"noise": where.noise}
    for label, value in axis.values.items() if axis else ():
        if world_location(world.name, label) == where.location:
            return {f"++gym_world.{axis.key}": value, "gym_world.name": where.location, "noise": where.noise}
    raise invalid(f"{key}.location", where.location, f"must be {world.name!r} or a location of acquire.world_axis")
