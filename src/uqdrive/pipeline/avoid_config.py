"""The avoid stage's config: its unknown conditions, the threshold calibration, the stage's whole schema."""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import Field

from uqdrive.pipeline.configs import Executor, ModelStage
from uqdrive.safety.cells import EstimatorSettings
from uqdrive.safety.warnings import WarningConfig
from uqdrive.schema import NonNegative, OpenUnit, Positive, Seed, Str, Unit, invalid, schema, validate
from uqdrive.sim.config import ScenarioConfig, SimConfig, WeatherConfig


@schema
class UnknownCondition:
    """One unknown condition of the avoid stage: a weather loaded under `weathers`, sensor noise, scenario changes."""

    name: Str
    weather: Str | None = None  # None: the known weather
    noise: NonNegative = 0.0
    scenario: dict[str, Any] = Field(default_factory=dict)  # fields of the obstacle scenario to change

    def __post_init__(self) -> None:
        if self.name == "known":
            raise invalid("name", self.name, "is the training condition's name; choose another")


@schema(frozen=True)
class CalibrationSettings:
    """Threshold calibration: known-condition autonomy must have an exact lower bound (level 1 − ``gamma``)
    ≥ ``autonomy_target``; among those, the most replayed unknown-condition safety. The candidate grids are
    kept sorted and without repeats."""

    autonomy_target: OpenUnit
    gamma: OpenUnit
    margin_m: NonNegative  # extra stopping distance a saved run must have kept before its collision point
    deltas: Annotated[tuple[Unit, ...], Field(min_length=1)]  # candidates for δ1 and δ2 (δ2 <= δ1)
    taus: Annotated[tuple[NonNegative, ...], Field(min_length=1)]  # candidates for τ

    def __post_init__(self) -> None:
        object.__setattr__(self, "deltas", tuple(sorted(set(self.deltas))))
        object.__setattr__(self, "taus", tuple(sorted(set(self.taus))))


@schema(frozen=True, kw_only=True)
class AvoidSection(EstimatorSettings):
    """conf/avoid.yaml's `avoid`: every cell's estimator (scheme, theta, gamma, look_size, base_seed), the world and
    the calibration."""

    model_path: Str
    horizon_s: Positive  # T; long enough for a run slowed by warnings to pass the obstacle (checked)
    speed: Positive  # cruise speed (m/s), at most vehicle.max_speed
    eps: Positive
    validation_seed: Seed
    known_noise: NonNegative
    unknown: Annotated[tuple[UnknownCondition, ...], Field(min_length=1)]
    calibration: CalibrationSettings
    out: Str
    data_dir: Str
    rollout_log: Str
    plots_dir: Str

    def __post_init__(self) -> None:
        names = [c.name for c in self.unknown]
        if len(set(names)) != len(names):
            raise invalid("unknown", names, "must have unique names")


@schema(root=True)
class AvoidStage(SimConfig, ModelStage):
    """`stages/avoid.py`: collision avoidance with the warning system, one method."""

    scenario: ScenarioConfig
    weather: WeatherConfig  # the known condition
    weathers: dict[str, WeatherConfig]  # those `avoid.unknown` may name
    warning: WarningConfig
    executor: Executor
    avoid: AvoidSection

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.scenario.kind != "obstacle":
            raise invalid("scenario.kind", self.scenario.kind, "must be 'obstacle' for the avoid stage")
        if self.avoid.speed > self.vehicle.max_speed:
            raise invalid("avoid.speed", self.avoid.speed, f"must be <= vehicle.max_speed={self.vehicle.max_speed}")
        loaded = {self.weather.name, *self.weathers}
        for i, condition in enumerate(self.avoid.unknown):
            if condition.weather is not None and condition.weather not in loaded:
                raise invalid(
                    f"avoid.unknown[{i}].weather",
                    condition.weather,
                    f"is not loaded; choose one of {sorted(loaded)} or add +weather@weathers.{condition.weather}="
                    f"{condition.weather}",
                )
            validate(ScenarioConfig, {**self.scenario.to_dict(), **condition.scenario}, f"avoid.unknown[{i}].scenario")
