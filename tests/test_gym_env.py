"""uqdrive's world as a Gymnasium env (`uqdrive.sim.gym_env`): the env checker, vector envs, seeding, config errors."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from uqdrive.network_input import preprocess_frame
from uqdrive.schema import ConfigError
from uqdrive.sim import DrivingEnv, ScenarioConfig
from uqdrive.sim.condition import Condition
from uqdrive.sim.config import WeatherConfig, find_conf
from uqdrive.sim.gym_env import ENV_IDS


@pytest.mark.parametrize("env_id", sorted(ENV_IDS.values()))
def test_every_registered_env_passes_the_gymnasium_checker_without_a_warning(env_id: str) -> None:
    env = gymnasium.make(env_id, weather="rain", noise=0.05, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the checker's findings are warnings: each one fails the test
        check_env(env.unwrapped)
    assert env.unwrapped.render().shape == (48, 64, 3)
    env.close()


def test_a_vector_env_of_four_starts_as_four_single_envs_with_the_same_seeds() -> None:
    seeds = [10, 11, 12, 13]
    make = [lambda: gymnasium.make("uqdrive/Roundabout-v0", noise=0.05)] * 4
    vector = gymnasium.vector.SyncVectorEnv(make)
    observations, infos = vector.reset(seed=seeds)
    stepped, *_ = vector.step(np.full((4, 1), 0.1, np.float32))
    vector.close()
    assert observations.shape == (4, 48, 64) and observations.dtype == np.uint8
    for i, seed in enumerate(seeds):
        with gymnasium.make("uqdrive/Roundabout-v0", noise=0.05) as single:
            obs, info = single.reset(seed=seed)
            after, *_ = single.step(np.array([0.1], np.float32))
        assert np.array_equal(obs, observations[i]) and np.array_equal(after, stepped[i])
        assert info["x"] == infos["x"][i] and info["seed"] == seed
    assert len({o.tobytes() for o in observations}) == 4  # the seeds' worlds differ (start jitter, noise)


def test_reset_seed_is_the_rollout_seed_of_driving_env_and_unseeded_resets_follow_np_random() -> None:
    env = gymnasium.make("uqdrive/Roundabout-v0", weather="rain", noise=0.05)
    obs, info = env.reset(seed=7)
    with DrivingEnv() as driving:
        weather = WeatherConfig.from_yaml(find_conf() / "weather" / "rain.yaml")
        roundabout = ScenarioConfig.from_yaml(find_conf() / "scenario" / "roundabout.yaml")
        frame = driving.reset(7, Condition(roundabout, weather, 0.05))
    assert np.array_equal(obs, preprocess_frame(frame))  # gymnasium's seed 7 is the pipeline's rollout seed 7
    first, second = env.reset()[1]["seed"], env.reset()[1]["seed"]
    env.reset(seed=7)
    assert (env.reset()[1]["seed"], env.reset()[1]["seed"]) == (first, second) != (7, 7)
    env.close()


def test_speed_as_a_second_action_component() -> None:
    with gymnasium.make("uqdrive/Straight-v0", speed_action=True) as env:
        assert env.action_space.shape == (2,) and env.action_space.high[1] == 20.0
        env.reset(seed=0)
        for _ in range(15):
            *_, info = env.step(np.array([0.0, 0.0], np.float32))
    assert info["speed"] < 3.0  # braking from 8 m/s at up to 6 m/s² for 1 s


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"weather": "snow"}, "weather='snow': no conf/weather/snow.yaml; choose one of ['afternoon', 'clear_noon'"),
        ({"noise": -0.1}, "noise=-0.1"),
        ({"scenario": "straight"}, "scenario='straight' is a straight scenario, not a roundabout one"),
        ({"scenario": {"kind": "roundabout", "ring_radius": -1.0}}, "scenario.ring_radius=-1.0"),
        ({"cruise_speed": 0.0}, "cruise_speed=0.0: must be > 0"),
    ],
)
def test_bad_kwargs_fail_with_one_line_naming_the_key(kwargs: dict, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        gymnasium.make("uqdrive/Roundabout-v0", **kwargs)
    assert message in str(err.value) and "\n" not in str(err.value)
