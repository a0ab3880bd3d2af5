from pathlib import Path

import pytest
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from uqdrive.schema import ConfigError
from uqdrive.sim import AutopilotConfig, CameraConfig, DrivingEnv, ScenarioConfig, VehicleConfig, WeatherConfig
from uqdrive.sim.condition import Condition

CONF = Path(__file__).resolve().parents[1] / "conf"


@pytest.mark.parametrize(
    "group,name",
    [("scenario", n) for n in ("straight", "obstacle", "roundabout", "roundabout_large", "roundabout_town")]
    + [("weather", n) for n in ("clear_noon", "afternoon", "rain", "fog")],
)
def test_group_files_list_only_changes_and_compose_onto_the_schema_defaults(group, name):
    cls = ScenarioConfig if group == "scenario" else WeatherConfig
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose(overrides=[f"+{group}={name}"])
    obj = cls.from_config(cfg[group])
    assert obj.name == name
    assert set(cfg[group]) == set(obj.to_dict()), "every field is in the composed config: CLI overrides work"
    assert obj == cls.from_yaml(CONF / group / f"{name}.yaml")  # without Hydra (bench, frames tools): the same
    own = OmegaConf.load(CONF / group / f"{name}.yaml")
    defaults = cls().to_dict()
    same = [k for k, v in own.items() if k not in ("defaults", "name") and obj.to_dict()[k] == defaults[k]]
    assert not same, f"{name}.yaml repeats the schema's defaults for {same}"


def test_a_field_no_yaml_lists_is_overridden_on_the_command_line():
    with initialize_config_dir(config_dir=str(CONF), version_base=None):
        cfg = compose(overrides=["+scenario=roundabout", "scenario.ring_radius=20", "+weather=rain"])
    assert ScenarioConfig.from_config(cfg.scenario).ring_radius == 20.0


@pytest.mark.parametrize(
    "cls,key,value,message",
    [
        (
            ScenarioConfig,
            "kind",
            "loop",
            "scenario.kind='loop': input should be 'straight', 'obstacle' or 'roundabout'",
        ),
        (ScenarioConfig, "lane_width", -3.5, "scenario.lane_width=-3.5: input should be greater than 0"),
        (ScenarioConfig, "num_lanes", 1.5, "scenario.num_lanes=1.5: input should be a valid integer"),
        (ScenarioConfig, "num_lanes", True, "scenario.num_lanes=True: input should be a valid integer"),
        (ScenarioConfig, "obstacle_color", [1.2, 0, 0], "scenario.obstacle_color[0]=1.2: input should be less than"),
        (ScenarioConfig, "crown_colors", [], "scenario.crown_colors=[]: tuple should have at least 1 item"),
        (ScenarioConfig, "lane_widht", 3.0, "scenario.lane_widht: unknown key; did you mean 'lane_width'?"),
        (WeatherConfig, "fog_density", -0.1, "weather.fog_density=-0.1: input should be greater than or equal to 0"),
        (WeatherConfig, "shadow", "yes", "weather.shadow='yes': input should be a valid boolean"),
        (WeatherConfig, "ambient", "0.5", "weather.ambient='0.5': input should be a valid number"),
        (WeatherConfig, "blur", float("inf"), "weather.blur=inf: input should be a finite number"),
        (CameraConfig, "width", 0, "camera.width=0: input should be greater than or equal to 8"),
        (VehicleConfig, "max_steer_deg", 95, "vehicle.max_steer_deg=95: input should be less than 90"),
        (AutopilotConfig, "perturb_prob", 1.5, "autopilot.perturb_prob=1.5: input should be less than or equal to 1"),
    ],
)
def test_a_bad_value_is_one_line_naming_the_key_the_value_and_what_is_allowed(cls, key, value, message):
    with pytest.raises(ConfigError) as err:
        cls.from_config({key: value})
    assert str(err.value).startswith(message) and "\n" not in str(err.value)


def test_a_dictconfig_is_accepted_and_lists_become_tuples():
    cfg = ScenarioConfig.from_config(OmegaConf.create({"kind": "obstacle", "obstacle_size": [4.0, 1.7, 1.4]}))
    assert cfg.obstacle_size == (4.0, 1.7, 1.4)
    assert cfg == ScenarioConfig(kind="obstacle", obstacle_size=(4.0, 1.7, 1.4))


def test_inconsistent_geometry_is_rejected():
    with pytest.raises(ConfigError, match=r"^scenario.num_lanes=1 must be >= 2 for kind 'obstacle'"):
        ScenarioConfig.from_config(kind="obstacle", num_lanes=1)
    with pytest.raises(ConfigError, match=r"^vehicle.wheelbase=5.0 must be < vehicle.length"):
        VehicleConfig.from_config(wheelbase=5.0)
    with pytest.raises(ValueError, match="scenario.route_fillet=30"):
        with DrivingEnv() as env:
            env.reset(0, Condition(ScenarioConfig(kind="roundabout", route_fillet=30.0), None), render=False)


def test_negative_noise_is_rejected():
    with DrivingEnv() as env, pytest.raises(ConfigError, match=r"^noise=-0.1: input should be greater than or equal"):
        env.reset(0, Condition(ScenarioConfig(), None, -0.1))


def test_every_scenario_kind_has_a_layout_builder():
    from uqdrive.sim.config import SCENARIO_KINDS
    from uqdrive.sim.layouts import LAYOUTS

    assert set(LAYOUTS) == set(SCENARIO_KINDS)


@pytest.mark.parametrize(
    ("stage", "overrides", "size"),
    [
        ("avoid", [], (96, 72)),  # conf/experiment/avoid.yaml's render size (docs/render_size.md)
        ("safety", [], (64, 48)),  # the offline experiment's
        ("safety", ["experiment=avoid"], (96, 72)),
        ("avoid", ["render=160x120"], (160, 120)),  # another conf/render/ size
        ("avoid", ["camera.width=80", "camera.height=60"], (80, 60)),  # the camera's own keys still win
        ("collect", [], (64, 48)),  # no experiment: the network's own size
        ("collect", ["+experiment=avoid"], (96, 72)),  # collected for an experiment: its size
        ("collect", ["+experiment=offline"], (64, 48)),
    ],
)
def test_the_camera_renders_at_the_experiments_size(stage_config, stage, overrides, size):
    cfg = stage_config(stage, *overrides)
    assert (cfg.camera.width, cfg.camera.height) == size


def test_every_experiment_is_trained_on_frames_collected_at_its_render_size(stage_config):
    """params.yaml's scenarios name the experiment each is collected for (collect@<scenario> composes it): every
    scenario of every pipeline experiment is collected at that experiment's render size."""
    params = yaml.safe_load((CONF.parent / "params.yaml").read_text())
    camera = {}
    for experiment in params["experiments"]:
        cfg = stage_config("avoid", f"experiment={experiment}")
        camera[experiment] = (cfg.camera.width, cfg.camera.height)
        for scenario in cfg.experiment.scenarios:
            collected = stage_config("collect", f"scenario={scenario}", f"+experiment={params['scenarios'][scenario]}")
            assert (collected.camera.width, collected.camera.height) == camera[experiment], (experiment, scenario)
    assert camera == {"avoid": (96, 72), "offline": (64, 48)}
