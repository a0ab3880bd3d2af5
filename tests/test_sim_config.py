from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from uqdrive.sim import AutopilotConfig, CameraConfig, DrivingEnv, ScenarioConfig, VehicleConfig, WeatherConfig

CONF = Path(__file__).resolve().parents[1] / "conf"


@pytest.mark.parametrize(
    "group,name",
    [("scenario", n) for n in ("straight", "obstacle", "roundabout")]
    + [("weather", n) for n in ("clear_noon", "afternoon", "rain", "fog")],
)
def test_yaml_groups_compose_through_hydra_and_validate(group, name):
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose(overrides=[f"+{group}={name}"])
    cls = ScenarioConfig if group == "scenario" else WeatherConfig
    obj = cls.from_config(cfg[group])
    assert obj.name == name
    assert set(cfg[group]) == set(obj.to_dict()), "yaml lists every field so CLI overrides work"


@pytest.mark.parametrize(
    "cls,key,value,fragment",
    [
        (ScenarioConfig, "kind", "loop", "scenario.kind='loop' is not one of ['straight', 'obstacle', 'roundabout']"),
        (ScenarioConfig, "lane_width", -3.5, "scenario.lane_width=-3.5 must be > 0"),
        (ScenarioConfig, "num_lanes", 1.5, "scenario.num_lanes=1.5"),
        (ScenarioConfig, "obstacle_color", [1.2, 0, 0], "scenario.obstacle_color=[1.2, 0, 0]"),
        (WeatherConfig, "fog_density", -0.1, "weather.fog_density=-0.1 must be >= 0"),
        (WeatherConfig, "shadow", "yes", "weather.shadow='yes'"),
        (CameraConfig, "width", 0, "camera.width=0"),
        (VehicleConfig, "max_steer_deg", 95, "vehicle.max_steer_deg=95 must be < 90"),
        (AutopilotConfig, "perturb_prob", 1.5, "autopilot.perturb_prob=1.5 must be <= 1"),
    ],
)
def test_bad_values_name_key_and_value(cls, key, value, fragment):
    with pytest.raises(ValueError) as err:
        cls.from_config({key: value})
    assert fragment in str(err.value)


def test_unknown_keys_fail_and_dictconfig_is_accepted():
    with pytest.raises(ValueError, match="unknown key.*lane_widht"):
        ScenarioConfig.from_config({"lane_widht": 3.0})
    cfg = ScenarioConfig.from_config(OmegaConf.create({"kind": "obstacle", "obstacle_size": [4.0, 1.7, 1.4]}))
    assert cfg.obstacle_size == (4.0, 1.7, 1.4)
    assert cfg == ScenarioConfig(kind="obstacle", obstacle_size=(4.0, 1.7, 1.4))


def test_inconsistent_geometry_is_rejected():
    with pytest.raises(ValueError, match="scenario.num_lanes=1 must be >= 2"):
        ScenarioConfig(kind="obstacle", num_lanes=1)
    with pytest.raises(ValueError, match="scenario.route_fillet=30"):
        with DrivingEnv() as env:
            env.reset(0, ScenarioConfig(kind="roundabout", route_fillet=30.0), render=False)


def test_negative_noise_is_rejected():
    with DrivingEnv() as env, pytest.raises(ValueError, match=r"noise=-0.1 must be >= 0"):
        env.reset(0, ScenarioConfig(), noise=-0.1)


def test_every_scenario_kind_has_a_layout_builder():
    from uqdrive.sim.config import SCENARIO_KINDS
    from uqdrive.sim.layouts import LAYOUTS

    assert set(LAYOUTS) == set(SCENARIO_KINDS)
