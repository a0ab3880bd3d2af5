import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from uqdrive.sim import Autopilot, AutopilotConfig, DrivingEnv, ScenarioConfig, WeatherConfig
from uqdrive.sim.condition import Condition

CONF = Path(__file__).resolve().parents[1] / "conf"


def drive(env, scenario, seed, config=None):
    env.reset(seed, Condition(scenario, WeatherConfig()), render=False)
    pilot = Autopilot(env.route, env.vehicle_config, config, control_hz=env.control_hz, seed=seed)
    info, infos, actions = env.last_info, [], []
    while not info["done"]:
        action = pilot.act(info)
        _, info = env.step(action.steer, action.speed)
        infos.append(info)
        actions.append(action)
    return infos, actions


@pytest.fixture(scope="module")
def env():
    with DrivingEnv() as e:
        yield e


@pytest.mark.parametrize("kind", ["straight", "obstacle", "roundabout"])
def test_autopilot_is_safe_and_completes_the_route(env, kind):
    scenario = ScenarioConfig.from_yaml(CONF / "scenario" / f"{kind}.yaml")
    for seed in range(20):
        infos, _ = drive(env, scenario, seed)
        last = infos[-1]
        assert last["termination"] == "route_complete", (seed, last)
        assert not any(i["collision"] or i["off_road"] for i in infos)
        assert max(abs(i["lateral_deviation"]) for i in infos) < 0.8
        lane_y = -scenario.lane_width / 2
        if kind == "obstacle":  # passed the stationary car and is back in the right lane
            obstacle = env.geometry.obstacles[0]
            assert last["x"] > obstacle.x + obstacle.size[0]
            assert abs(last["y"] - lane_y) < 0.3 and abs(last["yaw"]) < 0.05
            assert min(i["y"] for i in infos if abs(i["x"] - obstacle.x) < 3) > lane_y + 0.8 * scenario.lane_width
        if kind == "roundabout":  # first exit: on the east arm, heading east
            assert last["x"] > scenario.ring_radius + scenario.ring_width / 2
            assert abs(last["y"] - lane_y) < 0.3 and abs(last["yaw"]) < 0.1


def test_obstacle_clearance(env):
    scenario = ScenarioConfig(kind="obstacle")
    env.reset(0, Condition(scenario, WeatherConfig()), render=False)
    pilot = Autopilot(env.route, env.vehicle_config, seed=0)
    info, clearance = env.last_info, []
    while not info["done"]:
        action = pilot.act(info)
        _, info = env.step(action.steer, action.speed)
        clearance.append(env.scene.clearance())
    assert min(clearance) > 1.2


def test_perturbations_are_seeded_and_labels_stay_unperturbed(env):
    scenario = ScenarioConfig(kind="straight")
    config = AutopilotConfig(perturb_prob=0.05, perturb_magnitude=0.15, perturb_duration_s=0.4)
    infos, actions = drive(env, scenario, 3, config)
    again, actions_again = drive(env, scenario, 3, config)
    assert actions == actions_again and infos == again
    perturbed = [a for a in actions if a.perturbed]
    assert perturbed and all(a.steer != a.label for a in perturbed)
    assert all(-1 <= a.steer <= 1 for a in actions)
    clean = [a for a in actions if not a.perturbed]
    assert all(a.steer == a.label for a in clean)
    assert infos[-1]["termination"] == "route_complete"


def test_pure_pursuit_steers_back_towards_the_route(env):
    scenario = dataclasses.replace(ScenarioConfig(kind="straight"), start_jitter_lateral=0.0, start_jitter_yaw_deg=0.0)
    env.reset(0, Condition(scenario, WeatherConfig()), render=False)
    pilot = Autopilot(env.route, env.vehicle_config)
    left_of_route = dict(env.last_info, y=env.last_info["y"] + 1.0)
    right_of_route = dict(env.last_info, y=env.last_info["y"] - 1.0)
    assert pilot.act(left_of_route).label < 0 < pilot.act(right_of_route).label
    assert math.isclose(pilot.act(env.last_info).label, 0.0, abs_tol=1e-9)
    assert np.isclose(env.last_info["lateral_deviation"], 0.0)
