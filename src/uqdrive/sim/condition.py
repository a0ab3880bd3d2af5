"""Where a rollout drives: a `Condition` (location, weather, sensor noise, under a name), or a `Mixture` of them
whose rollout draws its variant from its seed; and `WorldChoice`, what a stage's config says about it.

Every closed-loop stage speaks of conditions: a cell of the offline-safety sweep, an avoid cell ("known", "fog",
"white_van"), a point of an envelope's condition space, a held-out evaluation's weather × noise. A rollout job
asks its source for rollout i's condition (`condition(index, seed)`); a `Condition` is its own source.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol

import numpy as np
from pydantic import model_validator

from uqdrive.resolvers import condition_label
from uqdrive.schema import NonNegative, invalid, schema
from uqdrive.sim.config import (
    CameraConfig,
    GymWorldConfig,
    ScenarioConfig,
    VehicleConfig,
    WeatherConfig,
    refuse_conditions,
)
from uqdrive.sim.location import NO_WEATHER, Location, LocationVisitor, location_of

__all__ = [
    "NO_WEATHER",
    "Condition",
    "ConditionSource",
    "Mixture",
    "WorldChoice",
    "source_conditions",
    "source_identity",
    "variant_of",
]
from uqdrive.sim.world import R, World, WorldVisitor

VARIANT_STREAM = 0xA401D  # a mixture's variant draw: its own random stream of a rollout seed, apart from the episode's


@dataclasses.dataclass(frozen=True)
class Condition:
    """A location (``scenario``: a pybullet scenario, or a Gymnasium world, whose env is the whole world and has no
    ``weather`` of ours: None), a ``weather`` (a blend of two is one weather) and sensor ``noise`` σ; ``name``: what
    a stage calls it (an avoid variant's name), else `label`."""

    scenario: ScenarioConfig | GymWorldConfig
    weather: WeatherConfig | None
    noise: float = 0.0
    name: str = ""

    @property
    def place(self) -> Location:
        """The location, as its world's type (`uqdrive.sim.location`): every answer that differs by world."""
        return location_of(self.scenario)

    @property
    def gym_world(self) -> GymWorldConfig | None:
        """The Gymnasium world this condition drives in (None: the pybullet world); inside `uqdrive.sim` only."""
        return self.scenario if isinstance(self.scenario, GymWorldConfig) else None

    @property
    def native(self) -> bool:
        """Whether rollouts here drive an env as it is: the agent sees its observation and acts in its action space."""
        return self.place.native

    @property
    def location(self) -> str:
        return self.scenario.name

    @property
    def weather_name(self) -> str:
        return self.place.weather_name(self.weather)

    @property
    def label(self) -> str:
        """location-weather-noise<σ>: the condition in cell names and paths."""
        return condition_label(self.location, self.weather_name, self.noise)

    @property
    def title(self) -> str:
        return self.name or self.label

    def condition(self, index: int, seed: int) -> Condition:
        """Every rollout drives here."""
        return self

    @property
    def single(self) -> Condition | None:
        """The one condition every rollout drives in: this one."""
        return self

    def visit(self, visitor: WorldVisitor[R]) -> R:
        """``visitor``'s answer where this condition drives: on its scenario's road (built here), or in its
        Gymnasium world."""
        return self.place.visit(visitor)

    def choose(self, visitor: LocationVisitor[R]) -> R:
        """``visitor``'s answer for this condition's location config (`Location.choose`)."""
        return self.place.choose(visitor)

    @property
    def external(self) -> bool:
        """Whether rollouts here run code and config beyond uqdrive's and this condition's fields (a Gymnasium
        world's env and hooks), which a cell's identity then records (`external_identity`, `loaded_modules`)."""
        return self.place.external

    def external_identity(self) -> dict[str, Any] | None:
        """The world's identity beyond uqdrive's code (`uqdrive.sim.gym_world.world_identity`); None: nothing."""
        return self.place.external_identity()

    def loaded_modules(self) -> list[str]:
        """The modules rollouts here load by name, which no static import reaches (`world_modules`)."""
        return self.place.loaded_modules()

    def make_world(self, camera: CameraConfig, vehicle: VehicleConfig, control_hz: float, horizon_s: float) -> World:
        """A new world to drive this condition in (`Location.make_world`)."""
        return self.place.make_world(camera, vehicle, control_hz, horizon_s)

    def world_key(self, camera: CameraConfig, vehicle: VehicleConfig, control_hz: float, horizon_s: float) -> str:
        """The worlds `make_world` makes with one key interchange (`Location.world_key`)."""
        return self.place.world_key(camera, vehicle, control_hz, horizon_s)


class ConditionSource(Protocol):
    """Where each rollout of a job drives: rollout ``index`` (seed ``seed``) at ``condition(index, seed)``."""

    @property
    def title(self) -> str: ...

    def condition(self, index: int, seed: int) -> Condition: ...


def variant_of(seed: int, count: int) -> int:
    """The variant (0 … count − 1) rollout seed ``seed`` drives in a mixture: uniform, independent across seeds."""
    return int(np.random.default_rng([VARIANT_STREAM, seed]).integers(count))


@dataclasses.dataclass(frozen=True)
class Mixture:
    """Conditions as one: rollout i drives the variant its seed draws, uniformly. Its outcomes are then independent
    Bernoulli draws of the variants' mean rate, so any estimator gives the mixture's η1 with its own guarantee in one
    sample; the draw uses rollout i's seed alone, so rollout i of a mixture is rollout i of its variant's own cell."""

    name: str
    variants: tuple[Condition, ...]

    def __post_init__(self) -> None:
        if not self.variants:
            raise ValueError(f"mixture {self.name!r} needs at least one variant")

    @property
    def title(self) -> str:
        return self.name

    def variant(self, seed: int) -> int:
        return variant_of(seed, len(self.variants))

    def condition(self, index: int, seed: int) -> Condition:
        return self.variants[self.variant(seed)]

    @property
    def single(self) -> Condition | None:
        """None: its rollouts drive in several conditions."""
        return None


def source_conditions(where: Any) -> tuple[Condition, ...]:
    """The conditions a rollout source's identity rests on: a condition itself, a mixture's variants, an envelope
    source's base world (its ``base``: the axes' values are the source's own fields); none for anything else."""
    if isinstance(where, Mixture):
        return where.variants
    found = where if isinstance(where, Condition) else getattr(where, "base", None)
    return (found,) if isinstance(found, Condition) else ()


def source_identity(where: Any) -> Any:
    """A rollout source as a cell's identity sees it: an external world by its identity (`Condition.external_identity`),
    a mixture by its variants', an envelope's source over an external world with that world's; anything else as
    itself."""
    if isinstance(where, Mixture):
        return {"mixture": where.name, "variants": [source_identity(v) for v in where.variants]}
    if isinstance(where, Condition) and where.external:
        return {"gym_world": where.external_identity(), "noise": where.noise, "name": where.name}
    if any(c.external for c in source_conditions(where)):  # an envelope's source over an external world
        return {"source": where, "gym_world": where.base.external_identity()}
    return where


@schema(root=True)
class WorldChoice:
    """A stage that drives a world (conf/<stage>.yaml): a pybullet location (``scenario``) in a ``weather``, or a
    Gymnasium world (``gym_world=<conf/gym_world/ file>``, which unsets the scenario and weather: its env is the
    whole world), seen with sensor ``noise`` σ. A scenario or weather beside a gym_world is refused, naming it."""

    scenario: ScenarioConfig | None = None
    weather: WeatherConfig | None = None
    gym_world: GymWorldConfig | None = None
    noise: NonNegative

    @model_validator(mode="before")
    @classmethod
    def _unnamed_scenario_fields(cls, data: Any) -> Any:
        """Scenario fields without a scenario named (a profile's tweaks for the kinds that read them, e.g. tiny's
        obstacle road) are no scenario: beside a gym_world they are dropped; a named scenario is refused."""
        if isinstance(data, dict) and data.get("gym_world") is not None:
            scenario = data.get("scenario")
            if isinstance(scenario, dict) and "name" not in scenario:
                return {k: v for k, v in data.items() if k != "scenario"}
        return data

    def __post_init__(self) -> None:
        if self.gym_world is not None:
            refuse_conditions(self.gym_world, self.scenario, self.weather)
        elif self.scenario is None or self.weather is None:
            key = "scenario" if self.scenario is None else "weather"
            raise invalid(key, None, "is required: a scenario and a weather (conf/), or a gym_world (conf/gym_world/)")
        after = getattr(super(), "__post_init__", None)  # the stage's other bases' checks
        if after is not None:
            after()

    def condition(self, name: str = "") -> Condition:
        """Where the stage drives."""
        return Condition(self.gym_world or self.scenario, self.weather, self.noise, name)

    def choose(self, visitor: LocationVisitor[R]) -> R:
        """``visitor``'s answer for the stage's location (`Location.choose`): a stage's check or choice that differs
        by world."""
        return self.condition().choose(visitor)
