"""The envelope's condition space: weather blends, axes, and the world at a condition, checked by the schemas."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from uqdrive.envelope.space import Axis, AxisSettings, BlendSettings, ConditionSpace
from uqdrive.schema import ConfigError, validate
from uqdrive.sim.condition import Condition
from uqdrive.sim.config import ScenarioConfig, WeatherConfig, blend_weather

CONF = Path(__file__).resolve().parents[1] / "conf"


def weather(name: str) -> WeatherConfig:
    return WeatherConfig.from_yaml(CONF / "weather" / f"{name}.yaml")


def numbers(w: WeatherConfig) -> dict:
    return {k: v for k, v in dataclasses.asdict(w).items() if k != "name"}


def test_a_blend_is_each_weather_exactly_at_its_ends_and_the_mean_halfway():
    clear, rain = weather("clear_noon"), weather("rain")
    assert numbers(blend_weather(clear, rain, 0.0)) == numbers(clear)
    assert numbers(blend_weather(clear, rain, 1.0)) == numbers(rain)
    half = blend_weather(clear, rain, 0.5)
    assert half.fog_density == pytest.approx((clear.fog_density + rain.fog_density) / 2)
    assert half.sky_top == pytest.approx(tuple((a + b) / 2 for a, b in zip(clear.sky_top, rain.sky_top)))
    assert half.rain_streaks == 35 and isinstance(half.rain_streaks, int)  # 70 streaks at t = 1, whole streaks
    assert blend_weather(clear, rain, 0.3).rain_streaks == 21


def test_a_switch_cannot_be_blended_and_a_blend_is_checked_by_the_weather_schema():
    clear = weather("clear_noon")
    with pytest.raises(ConfigError, match="differ in shadow"):
        blend_weather(clear, dataclasses.replace(clear, shadow=True), 0.5)
    opposite = dataclasses.replace(clear, light_direction=tuple(-x for x in clear.light_direction))
    with pytest.raises(ConfigError, match="light_direction.*zero vector"):
        blend_weather(clear, opposite, 0.5)
    with pytest.raises(ConfigError, match="weather.blend.t=1.5"):
        blend_weather(clear, clear, 1.5)


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ({"key": "weather.shadow", "range": [0.0, 1.0]}, "axes[0].key='weather.shadow' must be noise, weather.blend"),
        ({"key": "noise", "range": [0.2, 0.0]}, "axes[0].range=[0.2, 0.0] must be [low, high] with low < high"),
        ({"key": "weather.blend", "range": [0.0, 2.0]}, "axes[0].range=[0.0, 2.0] must lie in [0, 1]"),
        ({"key": "noise", "range": [0.0, 1.0], "rnage": [0, 1]}, "axes[0].rnage: unknown key"),
    ],
)
def test_a_bad_axis_is_one_line_naming_its_key(item, message):
    with pytest.raises(ConfigError) as err:
        validate(tuple[AxisSettings, ...], [item], "axes")
    assert str(err.value).startswith(message), str(err.value)


def test_blend_settings_read_from_and_to():
    blend = validate(BlendSettings, {"from": "fog", "to": "rain"})
    assert (blend.start, blend.to) == ("fog", "rain")


def axis(key: str, low: float, high: float) -> Axis:
    return Axis.of(validate(AxisSettings, {"key": key, "range": [low, high]}))


def space(*axes: Axis, blend: bool = False) -> ConditionSpace:
    base = Condition(ScenarioConfig.from_yaml(CONF / "scenario" / "roundabout.yaml"), weather("clear_noon"), 0.0)
    return ConditionSpace(axes, base, (weather("clear_noon"), weather("rain")) if blend else None)


def test_a_condition_sets_each_axis_key_of_the_world():
    s = space(
        axis("noise", 0.0, 0.2),
        axis("weather.blend", 0.0, 1.0),
        axis("scenario.ring_radius", 10.0, 24.0),
        blend=True,
    )
    world = s.condition(np.array([0.25, 1.0, 0.5]))
    assert world.noise == pytest.approx(0.05)
    assert numbers(world.weather) == numbers(weather("rain"))
    assert world.scenario.ring_radius == pytest.approx(17.0) and world.scenario.kind == "roundabout"
    streaks = space(axis("weather.rain_streaks", 0.0, 10.0)).condition([0.33])
    assert streaks.weather.rain_streaks == 3  # a whole-number key: rounded


def test_a_range_outside_a_schema_fails_before_any_rollout_with_one_line():
    s = space(axis("noise", 0.0, 0.2), axis("scenario.ring_radius", 2.0, 24.0))  # ring_width 6 needs a radius > 3
    with pytest.raises(ConfigError) as err:
        s.check()
    assert str(err.value).startswith(
        "envelope.axes: the condition noise=0, scenario.ring_radius=2 is not a valid world"
    )
    assert "\n" not in str(err.value)
    space(axis("noise", 0.0, 0.2), axis("scenario.ring_radius", 10.0, 24.0)).check()
