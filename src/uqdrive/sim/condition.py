"""Where a rollout drives: a `Condition` (location, weather, sensor noise, under a name), or a `Mixture` of them
whose rollout draws its variant from its seed.

Every closed-loop stage speaks of conditions: a cell of the offline-safety sweep, an avoid cell ("known", "fog",
"white_van"), a point of an envelope's condition space, a held-out evaluation's weather × noise. A rollout job
asks its source for rollout i's condition (`condition(index, seed)`); a `Condition` is its own source.
"""

from __future__ import annotations

import dataclasses
from typing import Protocol

import numpy as np

from uqdrive.resolvers import condition_label
from uqdrive.sim.config import ScenarioConfig, WeatherConfig

VARIANT_STREAM = 0xA401D  # a mixture's variant draw: its own random stream of a rollout seed, apart from the episode's


@dataclasses.dataclass(frozen=True)
class Condition:
    """A location (``scenario``), a ``weather`` (a blend of two is one weather) and sensor ``noise`` σ; ``name``: what
    a stage calls it (an avoid variant's name), else `label`."""

    scenario: ScenarioConfig
    weather: WeatherConfig
    noise: float = 0.0
    name: str = ""

    @property
    def label(self) -> str:
        """location-weather-noise<σ>: the condition in cell names and paths."""
        return condition_label(self.scenario.name, self.weather.name, self.noise)

    @property
    def title(self) -> str:
        return self.name or self.label

    def condition(self, index: int, seed: int) -> Condition:
        """Every rollout drives here."""
        return self


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
