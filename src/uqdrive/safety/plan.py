"""The offline-safety stages' schemas and plan: one cell's config (`SafetyStage`, its `SafetySection`), the sweep's
(`SafetySweepStage`, its cells `SweepCells`), a validated cell (`CellPlan`) and what a cell's run returns
(`SafetyRun`). The stage functions are `uqdrive.pipeline.safety_stage`'s."""

from __future__ import annotations

import dataclasses
from typing import Annotated, Any

from pydantic import Field

from uqdrive.models.model_stage import ModelStage
from uqdrive.resolvers import world_location
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.safety.cells import EstimatorSettings
from uqdrive.safety.drive import CorridorDrive
from uqdrive.safety.executors import RolloutJob
from uqdrive.schema import Bool, Count, Str, invalid, schema
from uqdrive.sim.condition import WorldChoice
from uqdrive.sim.config import GymWorldConfig, ScenarioConfig, SimConfig, WorldAxis
from uqdrive.sim.location import ByWorld, nothing
from uqdrive.stage import grid
from uqdrive.stage_schemas import ExecutorSettings, Names, Sweep
from uqdrive.uq.multiplicity import split_gamma


@schema(frozen=True, kw_only=True)
class SafetySection(CorridorDrive, EstimatorSettings):
    """conf/safety.yaml's `safety`: one cell's estimator (scheme, theta, gamma, look_size, base_seed), what drives it
    (`CorridorDrive`: model_path or policy, speed, samples, draws, eps, horizon_s, half_width) and outputs."""

    family_wise: Bool  # the sweep spends γ over its cells: every cell within ±θ at once with probability ≥ 1 − γ
    family_size: Count  # cells γ is spread over (the sweep sets it to its cell count); 1 unless family_wise
    cell: Str
    positions: Str
    clips: Annotated[int, Field(ge=0, strict=True)]  # the worst failures re-driven as clips and logged (0: none)
    clips_dir: Str


@schema(root=True)
class SafetyStage(WorldChoice, SimConfig, ModelStage):
    """`stages/safety.py`: one cell of the offline-safety sweep, in a pybullet location or a Gymnasium world
    (`WorldChoice`); in a Gymnasium world, T and the control rate are the world's (gym_world.horizon_steps,
    gym_world.control_hz), and the car, camera and safety.horizon_s are the pybullet world's, unused."""

    executor: ExecutorSettings
    safety: SafetySection

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.safety.speed > self.vehicle.max_speed:
            raise invalid("safety.speed", self.safety.speed, f"must be <= vehicle.max_speed={self.vehicle.max_speed}")
        if self.safety.family_size != 1 and not self.safety.family_wise:
            raise invalid("safety.family_size", self.safety.family_size, "must be 1 unless safety.family_wise")
        if self.safety.half_width is not None:
            self.choose(ByWorld(road=nothing, gym=self._refuse_corridor))

    def _refuse_corridor(self, world: GymWorldConfig) -> None:
        raise invalid("safety.half_width", self.safety.half_width, "is a lane's: a gym_world is judged by its safe_if")

    @property
    def estimator(self) -> EstimatorSettings:
        """The cell's estimator: γ spread over the family's cells (Bonferroni) when family-wise; the replicate's
        block of rollout seeds."""
        s = self.safety
        return dataclasses.replace(
            s.estimator, gamma=split_gamma(s.gamma, s.family_size), base_seed=self.rollout_seeds(s.base_seed)
        )


@schema(kw_only=True)
class SafetySweep(Sweep):
    """The offline-safety sweep's cells: in the pybullet world, methods × replicates × locations × weathers × noises;
    in a Gymnasium world, methods × replicates × the values of ``world_axis`` (or the one world) × noises."""

    weathers: Names = ()  # conf/weather/: at least one in the pybullet world, none in a Gymnasium world
    world_axis: WorldAxis | None = None  # conf/gym_safety_sweep.yaml: the world's own (gym_world.axis)


@schema(root=True)
class SafetySweepStage(SafetyStage):
    """`stages/safety_sweep.py`: every cell of `sweep` (each cell is also checked as a `SafetyStage`)."""

    sweep: SafetySweep

    def __post_init__(self) -> None:
        super().__post_init__()
        self.choose(SweepCells(self.sweep))  # each world's sweep checked


@dataclasses.dataclass(frozen=True)
class SweepCells:
    """The sweep's cells as overrides, the last axis varying fastest, each world's axes checked: on a road, methods ×
    replicates × locations × weathers × noises; in a Gymnasium world, methods × replicates × the world's variants
    (the values of ``world_axis``, each a location of its own) × noises."""

    sweep: SafetySweep

    def road(self, scenario: ScenarioConfig) -> list[dict[str, Any]]:
        s = self.sweep
        if not s.weathers:
            raise invalid("sweep.weathers", [], "must name at least one weather (conf/weather/)")
        if s.world_axis is not None:
            raise invalid("sweep.world_axis", s.world_axis.key, "varies a gym_world; name one (conf/gym_world/)")
        return grid(model=s.methods, seed=s.replicates, scenario=s.locations, weather=s.weathers, noise=s.noises)

    def gym(self, world: GymWorldConfig) -> list[dict[str, Any]]:
        s = self.sweep
        for key, names in (("locations", s.locations), ("weathers", s.weathers)):
            if names:
                raise invalid(f"sweep.{key}", list(names), f"must be empty: {world.env_id} is the world")
        for label, value in s.world_axis.values.items() if s.world_axis else ():  # a key the world sets
            world.changed({s.world_axis.key: value}, label, "sweep.world_axis")
        cells = grid(model=s.methods, seed=s.replicates, world=self.variants(world), noise=s.noises)
        return [{"model": c["model"], "seed": c["seed"], **c["world"], "noise": c["noise"]} for c in cells]

    def variants(self, world: GymWorldConfig) -> list[dict[str, Any]]:
        """Each location of a Gymnasium sweep as a cell's overrides (one empty set: the named world alone)."""
        axis = self.sweep.world_axis
        if axis is None:
            return [{}]
        return [
            {f"++gym_world.{axis.key}": value, "gym_world.name": world_location(world.name, label)}
            for label, value in axis.values.items()
        ]


@dataclasses.dataclass(frozen=True)
class SafetyRun:
    """A finished cell and whether it was ``reused``: nothing simulated (its result file or every rollout replayed
    from its log)."""

    cell: SafetyCell
    reused: bool


@dataclasses.dataclass(frozen=True)
class CellPlan:
    """A validated cell: its config, method, rollout job and identity."""

    stage: SafetyStage
    method: str
    job: RolloutJob
    key: str
