"""The condition space of an operating envelope: two or three continuous axes, each a config key with a range.

An axis is ``noise`` (the sensor noise σ), ``weather.blend`` (the fraction t of the way between two weathers,
`uqdrive.sim.config.blend_weather`), or a number of the location or the weather (``scenario.ring_radius``,
``weather.fog_density``); in a Gymnasium world, ``noise`` or a number of the world's own config
(``gym_world.<dotted key>``, e.g. ``gym_world.env_kwargs.config.observation.scaling``, the zoom of HighwayEnv's
view). Search and certification work in the unit cube [0, 1]^d; `ConditionSpace` maps a point of it to the world a
rollout drives in, checked by the same schemas as any cell's world.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence

import numpy as np
from pydantic import Field

from uqdrive.schema import ConfigError, Float, Str, invalid, schema
from uqdrive.sim.condition import Condition
from uqdrive.sim.config import GymWorldConfig, ScenarioConfig, WeatherConfig, blend_weather, check_noise
from uqdrive.sim.location import ByWorld, nothing

NOISE = "noise"
BLEND = "weather.blend"
GYM = "gym_world."  # the prefix of an axis over a number of a Gymnasium world's config
_SECTIONS = {"scenario": ScenarioConfig, "weather": WeatherConfig}
CHECK_POINTS = 5  # per axis: the lattice of conditions checked before any rollout (both ends included)


def _number_fields(cls: type) -> dict[str, bool]:
    """Fields of a world schema that an axis may vary, plain numbers (not switches, names or tuples): name → is it
    a whole number (e.g. weather.rain_streaks, whose values are rounded)."""
    defaults = cls()
    values = {f.name: getattr(defaults, f.name) for f in dataclasses.fields(cls)}
    return {k: type(v) is int for k, v in values.items() if type(v) in (int, float)}


_NUMBERS = {f"{s}.{name}": whole for s, cls in _SECTIONS.items() for name, whole in _number_fields(cls).items()}
AXIS_KEYS = (NOISE, BLEND, *_NUMBERS)


@schema(frozen=True)
class AxisSettings:
    """One axis: a config key and the range [low, high] its values are drawn from."""

    key: Str
    range: tuple[Float, Float]

    def __post_init__(self) -> None:
        if self.key not in AXIS_KEYS and not self.key.startswith(GYM):
            raise invalid(
                "key",
                self.key,
                "must be noise, weather.blend, a number of scenario or weather (e.g. scenario.ring_radius) or of "
                "a gym_world (gym_world.<key>)",
            )
        if not self.range[0] < self.range[1]:
            raise invalid("range", list(self.range), "must be [low, high] with low < high")
        if self.key == BLEND and not 0 <= self.range[0] < self.range[1] <= 1:
            raise invalid("range", list(self.range), "must lie in [0, 1] for weather.blend (t)")


@schema(frozen=True)
class BlendSettings:
    """The two weathers a ``weather.blend`` axis goes between (names of the stage's loaded weathers)."""

    start: Str = Field("clear_noon", alias="from")
    to: Str = "rain"


@dataclasses.dataclass(frozen=True)
class Axis:
    """An axis's key and range; ``integer``: the key holds a whole number, so its values are rounded."""

    key: str
    low: float
    high: float
    integer: bool = False

    @classmethod
    def of(cls, settings: AxisSettings, base: Condition | None = None) -> Axis:
        """The axis of ``settings`` over the ``base`` world (a Gymnasium world's number: whole if it is there)."""
        integer = _NUMBERS.get(settings.key, False)
        if base is not None and settings.key.startswith(GYM):
            integer = type(gym_number(base, settings.key)) is int
        return cls(settings.key, settings.range[0], settings.range[1], integer)

    def value(self, unit: float) -> float | int:
        v = self.low + unit * (self.high - self.low)
        return round(v) if self.integer else float(v)


def gym_number(base: Condition, key: str) -> float | int:
    """The number an axis ``gym_world.env_kwargs.<…>`` varies, as ``base``'s Gymnasium world sets it; one line
    where the world is ours, or the key is not a number the world sets (`GymWorldConfig.condition_slot`)."""

    def ours(scenario: ScenarioConfig) -> float | int:
        raise ConfigError(f"envelope.axes: {key} varies a gym_world; name one (conf/gym_world/) or drop the axis")

    def number(world: GymWorldConfig) -> float | int:
        return world.condition_value(key.removeprefix(GYM), f"envelope.axes: {key}")

    value = base.choose(ByWorld(road=ours, gym=number))
    if type(value) not in (int, float):
        raise ConfigError(f"envelope.axes: {key}={value!r} is not a number")
    return value


@dataclasses.dataclass(frozen=True)
class ConditionSpace:
    """Axes over a base world (the stage's scenario, weather and noise); ``blend``: the weathers a
    ``weather.blend`` axis goes between. Picklable: rollout workers map their conditions themselves."""

    axes: tuple[Axis, ...]
    base: Condition
    blend: tuple[WeatherConfig, WeatherConfig] | None = None

    def __post_init__(self) -> None:
        keys = [a.key for a in self.axes]
        if len(set(keys)) != len(keys):
            raise ConfigError(f"envelope.axes: each key at most once, got {keys}")
        for key in keys:
            if key.startswith(GYM):
                gym_number(self.base, key)
        ours = [k for k in keys if k != NOISE and not k.startswith(GYM)]

        def refuse_ours(world: GymWorldConfig) -> None:
            raise ConfigError(
                f"envelope.axes: {ours[0]} is uqdrive's world; {world.env_id} is the world: "
                "vary noise or a number of gym_world (gym_world.<key>)"
            )

        if ours:
            self.base.choose(ByWorld(road=nothing, gym=refuse_ours))
        if (BLEND in keys) != (self.blend is not None):
            raise ValueError("a weather.blend axis needs the two weathers it blends, and only it")

    @property
    def dim(self) -> int:
        return len(self.axes)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(a.key for a in self.axes)

    def values(self, unit: Sequence[float]) -> dict[str, float | int]:
        """The axes' values at a point of the unit cube."""
        if len(unit) != self.dim:
            raise ValueError(f"a condition has {self.dim} coordinates, got {len(unit)}")
        return {a.key: a.value(float(u)) for a, u in zip(self.axes, unit)}

    def condition(self, unit: Sequence[float]) -> Condition:
        """The condition at a point of the unit cube, each part checked by its schema (`ConfigError` if invalid)."""
        values = self.values(unit)
        noise = check_noise(values[NOISE]) if NOISE in values else self.base.noise

        def in_world(world: GymWorldConfig) -> Condition:
            changes = {k.removeprefix(GYM): v for k, v in values.items() if k.startswith(GYM)}
            return Condition(world.changed(changes, world.name, "envelope.axes"), None, noise)

        return self.base.choose(ByWorld(road=lambda scenario: self._on_road(scenario, values, noise), gym=in_world))

    def _on_road(self, scenario: ScenarioConfig, values: dict[str, float | int], noise: float) -> Condition:
        """The condition at these axis values on our road: the base's scenario and weather with their changes."""
        weather = self.base.weather
        if self.blend is not None:
            weather = blend_weather(*self.blend, float(values[BLEND]))
        changes: dict[str, dict[str, float | int]] = {"scenario": {}, "weather": {}}
        for key, value in values.items():
            section, _, name = key.partition(".")
            if section in changes and key != BLEND:
                changes[section][name] = value
        if changes["scenario"]:
            scenario = ScenarioConfig.from_config({**scenario.to_dict(), **changes["scenario"]})
        if changes["weather"]:
            weather = WeatherConfig.from_config({**weather.to_dict(), **changes["weather"]})
        return Condition(scenario, weather, noise)

    def check(self) -> None:
        """Build the world at every point of a lattice over the box (ends included), so a range that leaves the
        schemas' bounds fails before any rollout, with one line naming the axes and the values."""
        ticks = np.linspace(0.0, 1.0, CHECK_POINTS)
        for unit in itertools.product(ticks, repeat=self.dim):
            try:
                self.condition(unit)
            except (ConfigError, ValueError) as err:
                where = ", ".join(f"{k}={v:g}" for k, v in self.values(unit).items())
                raise ConfigError(f"envelope.axes: the condition {where} is not a valid world: {err}") from None
