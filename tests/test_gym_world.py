"""Any Gymnasium env as a closed-loop world (`uqdrive.sim.gym_world`), driven by `run_rollouts` and judged by
`InfoSafeSet`: a stub env with a known crash rate, uqdrive's own env round trip, HighwayEnv end to end."""

from __future__ import annotations

import copy
import json

import gymnasium
import numpy as np
import pytest
from gymnasium import spaces

from uqdrive.network_input import preprocess_frame
from uqdrive.policy.interface import Command
from uqdrive.policy.references import ConstantPolicy
from uqdrive.safety.info_safe_set import InfoSafeSet
from uqdrive.safety.rollout import run_rollouts
from uqdrive.schema import ConfigError
from uqdrive.sim import DrivingEnv, ScenarioConfig
from uqdrive.sim.condition import Condition
from uqdrive.sim.config import GymWorldConfig, find_conf
from uqdrive.sim.gym_world import GymWorld, world_identity, world_modules
from uqdrive.uq import clopper_pearson_interval

CRASH_RATE = 0.3
COIN_ID = "uqdrive_test/CoinCrash-v0"


class LineEnv(gymnasium.Env):
    """A point driving along x at the commanded speed: the cheapest env with uqdrive's info keys."""

    observation_space = spaces.Box(0, 255, (24, 32), np.uint8)
    action_space = spaces.Box(np.array([-1.0, 0.0], np.float32), np.array([1.0, 20.0], np.float32))

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.speed = float(self.np_random.uniform(0, 1)), 1.0
        return self._obs(), self._info()

    def step(self, action):
        self.speed = float(action[1])
        self.x += self.speed / 15
        return self._obs(), 0.0, False, False, self._info()

    def _obs(self):
        return np.full((24, 32), 100 + int(self.x * 10) % 50, np.uint8)  # mid-grey: the noise is never clipped

    def _info(self):
        return dict(x=self.x, y=0.0, yaw=0.0, speed=self.speed, collision=False, off_road=False, lateral_deviation=0.0)


class CoinCrash(gymnasium.Wrapper):
    """Crashes the episode of seed s at a step drawn from s, with probability ``rate`` (a coin drawn from s)."""

    def __init__(self, env: gymnasium.Env, rate: float):
        super().__init__(env)
        self.rate = rate

    def reset(self, *, seed=None, options=None):
        self.crash_step = coin_crash_step(seed, self.rate)
        self.steps = 0
        return self.env.reset(seed=seed, options=options)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.steps += 1
        if self.steps == self.crash_step:
            info, terminated = {**info, "collision": True}, True
        return obs, reward, terminated, truncated, info


def coin_crash_step(seed: int, rate: float) -> int | None:
    rng = np.random.default_rng([seed, 99])
    crash, step = rng.random() < rate, int(rng.integers(1, 10))
    return step if crash else None


if COIN_ID not in gymnasium.registry:
    gymnasium.register(COIN_ID, entry_point=lambda rate=CRASH_RATE: CoinCrash(LineEnv(), rate))


def conditions(seeds: list[int], noise: float) -> list[Condition]:
    """A Gymnasium world's condition for each rollout: no scenario or weather of ours, only the sensor noise."""
    return [Condition(None, None, noise)] * len(seeds)


def coin_world(**overrides) -> GymWorld:
    return GymWorld(GymWorldConfig.from_config({"env_id": COIN_ID, "horizon_steps": 12, **overrides}))


def test_stub_crash_rate_is_covered_by_the_exact_interval_of_the_rollouts_outcomes() -> None:
    seeds = list(range(100, 400))
    safe_set = InfoSafeSet()
    worlds = [coin_world() for _ in range(3)]
    results = run_rollouts(worlds, ConstantPolicy(0.0, 1.0), seeds, conditions(seeds, 0.0), safe_set=safe_set)
    assert [r.verdict.collision for r in results] == [coin_crash_step(s, CRASH_RATE) is not None for s in seeds]
    assert [r.verdict.safe for r in results] == [not r.verdict.collision for r in results]
    assert all(r.termination in ("collision", "timeout") for r in results)
    crashes = sum(r.verdict.collision for r in results)
    low, high = clopper_pearson_interval(crashes, len(seeds), 0.05)
    assert low <= CRASH_RATE <= high, (crashes, low, high)
    alone = run_rollouts(
        worlds[:1],
        ConstantPolicy(0.0, 1.0),
        seeds[:20],
        conditions(seeds[:20], 0.0),
        safe_set=safe_set,
    )
    assert _same(alone, results[:20])  # a rollout is its seed's, whatever the lockstep width


def test_uqdrive_env_through_the_adapter_drives_the_paths_driving_env_drives() -> None:
    config = GymWorldConfig(env_id="uqdrive/Roundabout-v0", env_kwargs={"speed_action": True})
    policy, seeds = ConstantPolicy(0.0625, 6.0), [3, 4]  # a steer float32 holds exactly: the action space's dtype
    with GymWorld(config) as world:
        through = run_rollouts([world], policy, seeds, conditions(seeds, 0.0), safe_set=InfoSafeSet.of(config))
        first = world.reset(3, Condition(config, None, 0.0))
        with gymnasium.make("uqdrive/Roundabout-v0") as env:
            assert np.array_equal(preprocess_frame(first), env.reset(seed=3)[0])  # the grey frame, exactly
    with DrivingEnv() as env:
        scenario = ScenarioConfig.from_yaml(find_conf() / "scenario" / "roundabout.yaml")
        direct = run_rollouts([env], policy, seeds, [Condition(scenario, None, 0.0)] * len(seeds))
    for a, b in zip(through, direct):
        assert np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y) and a.termination == b.termination
        assert (
            a.verdict.safe == (b.termination == "timeout")
            and a.mean_abs_lateral_deviation == b.mean_abs_lateral_deviation
        )


def test_a_gymnasium_runs_lane_is_the_path_it_drove_with_what_the_env_reported() -> None:
    """`DrivenPath` answers the `Lane` questions at the run's own points: metres driven and the env's lateral
    deviation, on the lane where the env said on the road, the car's heading, a width the env does not give."""
    config = GymWorldConfig(env_id="uqdrive/Roundabout-v0", env_kwargs={"speed_action": True}, horizon_steps=40)
    with GymWorld(config) as world:
        world.reset(3, render=False)
        while not world.done:
            world.step(0.3, 6.0)
        log, lane, infos = world.trajectory, world.lane, world.lane.infos
    points = np.stack([log["x"], log["y"]], axis=1)
    driven, lateral = lane.local_coordinates(points)
    assert driven[0] == 0.0 and np.all(np.diff(driven) >= 0)
    np.testing.assert_array_equal(lateral, [info["lateral_deviation"] for info in infos])
    np.testing.assert_allclose(lane.position(driven, np.zeros_like(driven)), points, atol=1e-9)
    np.testing.assert_allclose(lane.heading_at(driven), np.unwrap(log["yaw"]), atol=1e-9)
    assert np.isnan(lane.width_at(driven)).all()
    assert lane.on_lane(points).tolist() == [not info["off_road"] for info in infos]
    with pytest.raises(ValueError, match="points for an episode of"):
        lane.local_coordinates(points[:-1])


def test_frames_are_the_network_size_in_rgb_and_the_noise_is_the_seeds() -> None:
    with coin_world() as world:
        clean = world.reset(5)
        noisy, again, other = (world.reset(seed, Condition(world.config, None, 0.1)) for seed in (5, 5, 6))
        assert world.reset(5, render=False) is None
    assert clean.shape == (48, 64, 3) and clean.dtype == np.uint8
    assert np.array_equal(clean[..., 0], clean[..., 2]) and np.array_equal(preprocess_frame(clean), clean[..., 1])
    assert np.array_equal(noisy, again) and not np.array_equal(noisy, clean) and not np.array_equal(noisy, other)
    assert abs(float(np.std(noisy.astype(float) - clean.astype(float))) - 25.5) < 3


@pytest.mark.parametrize("key", ["scenario", "weather"])
def test_a_condition_the_env_lacks_is_refused_naming_the_key(key: str) -> None:
    value = ScenarioConfig() if key == "scenario" else "rain"
    with coin_world() as world, pytest.raises(ConfigError) as err:
        world.reset(0, Condition(value, None) if key == "scenario" else Condition(world.config, value))
    assert str(err.value).startswith(f"{key}=") and f"{COIN_ID} has no {key} condition" in str(err.value)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"env_id": "nowhere/Nothing-v0"}, "gym_world.env_id='nowhere/Nothing-v0': "),
        ({"safe_if": {"crashed": False}}, "gym_world.safe_if: 'crashed' is not in the info of"),
        (
            {"hooks_options": {"destination": "nxs"}},
            "gym_world.hooks_options.destination='nxs': not an option of InfoHooks (known: none)",
        ),
        ({"horizon": 3}, "gym_world.horizon: unknown key; did you mean 'horizon_steps'?"),
    ],
)
def test_a_bad_world_config_fails_with_one_line_naming_the_key(overrides: dict, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        coin_world(**overrides).reset(0)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_identity_records_the_config_and_the_package_versions_and_the_modules_to_digest() -> None:
    config = GymWorldConfig(env_id="uqdrive/Roundabout-v0", env_kwargs={"weather": "rain"})
    identity = world_identity(config)
    assert identity["config"]["env_kwargs"] == {"weather": "rain"}
    assert identity["packages"]["gymnasium"] == "1.4.0" and "uqdrive" in identity["packages"]
    assert world_modules(config) == ["uqdrive.sim.gym_world", "uqdrive.sim.gym_hooks", "uqdrive.sim.gym_env"]
    assert "code" not in identity  # its modules are digested with the cell's others (`cell_key`)
    json.dumps(identity)  # hashable as the cell identity hashes its job


@pytest.fixture(scope="module")
def highway_config() -> GymWorldConfig:
    pytest.importorskip("highway_env", reason="highway-env is not installed (pip install 'uqdrive[highway]')")
    config = GymWorldConfig.from_yaml(find_conf() / "gym_world" / "highway_roundabout.yaml")
    return GymWorldConfig.from_config({**config.to_dict(), "horizon_steps": 20})


class ExpertPolicy:
    """Drives with the world's own expert (what a collect stage would record)."""

    needs_camera = True

    def __init__(self):
        self.worlds: dict[int, GymWorld] = {}

    def reset(self, seed, slot=0, world=None):
        self.worlds[slot] = world

    def act_batch(self, slots, frames, infos):
        assert all(frame.shape == (48, 64, 3) for frame in frames)
        return [Command(*self.worlds[slot].expert_command()) for slot in slots]


def test_highway_roundabout_runs_end_to_end_through_run_rollouts(highway_config: GymWorldConfig) -> None:
    seeds, safe_set = [0, 1, 2], InfoSafeSet.of(highway_config)
    worlds = [GymWorld(highway_config) for _ in range(2)]
    results = run_rollouts(worlds, ExpertPolicy(), seeds, conditions(seeds, 0.05), safe_set=safe_set)
    again = run_rollouts(worlds[:1], ExpertPolicy(), seeds, conditions(seeds, 0.05), safe_set=safe_set)
    assert _same(results, again)
    assert [r.termination for r in results] == ["timeout"] * 3 and all(r.verdict.safe for r in results)
    info = worlds[0].last_info
    assert {"crashed", "on_road", "x", "y", "yaw", "speed", "lateral_deviation"} <= set(info)
    assert abs(info["speed"] - 8.0) < 0.5 and info["t"] == pytest.approx(20 / 15)
    for world in worlds:
        world.close()


def test_asking_highways_expert_leaves_the_episode_as_it_was(highway_config: GymWorldConfig) -> None:
    with GymWorld(highway_config) as world:
        paths = []
        for ask in (False, True):
            world.reset(4)
            while not world.done:
                if ask:
                    world.expert_command()
                world.step(0.02, 7.0)
            paths.append(world.trajectory)
    assert all(np.array_equal(paths[0][key], paths[1][key]) for key in paths[0])


def test_highway_refuses_weather_and_a_two_component_action(highway_config: GymWorldConfig) -> None:
    with GymWorld(highway_config) as world, pytest.raises(ConfigError, match=r"^weather='rain': roundabout-v0 has no"):
        world.reset(0, Condition(world.config, "rain"))
    kwargs = {"config": {**highway_config.env_kwargs["config"], "action": {"type": "ContinuousAction"}}}
    bad = GymWorldConfig.from_config({**highway_config.to_dict(), "env_kwargs": kwargs})
    with pytest.raises(ConfigError, match=r"^gym_world.env_kwargs.config.action: must be \{type: ContinuousAction"):
        GymWorld(bad)


def _same(a, b) -> bool:
    """Identical outcomes and paths (NaN fields compare equal)."""
    summaries = json.dumps([r.summary() for r in a], default=str) == json.dumps([r.summary() for r in b], default=str)
    return summaries and all(np.array_equal(x.x, y.x) and np.array_equal(x.y, y.y) for x, y in zip(a, b))


def test_a_highway_car_braking_for_a_hand_over_stops_well_within_the_worlds_horizon() -> None:
    """HighwayEnv's car tracks a speed of 0 asymptotically (8 m/s × (14/15)^step): it must count as stopped at
    the world's stopped_speed long before the configured horizon, or no hand-over there would ever end."""
    pytest.importorskip("highway_env", reason="highway-env is not installed (pip install 'uqdrive[highway]')")
    config = GymWorldConfig.from_yaml(find_conf() / "gym_world" / "highway_roundabout.yaml")
    with GymWorld(config) as world:
        world.reset(0, render=False)
        steps = 0
        while world.last_info["speed"] > config.stopped_speed and not world.done:
            world.step(0.0, 0.0)
            steps += 1
    assert world.last_info["speed"] <= config.stopped_speed and steps <= config.horizon_steps / 2, steps
    assert world.stopped_speed == config.stopped_speed == 0.1


def test_highway_refuses_a_destination_its_road_lacks_and_a_bad_option_value_before_any_run(highway_config) -> None:
    racetrack = GymWorldConfig.from_config({**highway_config.to_dict(), "env_id": "racetrack-v0"})
    with pytest.raises(ConfigError, match=r"^gym_world.hooks_options.destination='nxs': not a node of racetrack-v0's"):
        GymWorld(racetrack)
    with pytest.raises(ConfigError, match=r"^gym_world.hooks_options.expert_speed=-1.0 must be a speed > 0 \(m/s\)$"):
        GymWorldConfig.from_config({**highway_config.to_dict(), "hooks_options": {"expert_speed": -1.0}})


@pytest.mark.parametrize("heading", [0.0, np.pi / 2, 2.0, -2.7])
def test_highways_car_view_turns_the_frame_with_the_ego_so_ahead_is_up(highway_config, heading: float) -> None:
    """A spot drawn on HighwayEnv's screen 10 px ahead of the ego (its heading: y down the screen) lands 10 px above
    the ego's place in the car view, a spot 8 px to its right 8 px right of it: what the view shows turns with the car
    (and a world view shows them where the screen has them)."""
    from uqdrive.sim.gym_highway import CAR_VIEW_EGO_ROW

    world = GymWorld(highway_config)
    world.reset(0, render=False)
    world.hooks.env.vehicle.heading = heading
    side = highway_config.env_kwargs["config"]["observation"]["observation_shape"][0]
    ahead, right = np.array([np.cos(heading), np.sin(heading)]), np.array([-np.sin(heading), np.cos(heading)])
    ego_col, ego_row = 32, int(48 * CAR_VIEW_EGO_ROW)
    for offset, where in ((10 * ahead, (ego_row - 10, ego_col)), (8 * right, (ego_row, ego_col + 8))):
        screen = np.zeros((side, side), np.uint8)
        col, row = np.rint(side / 2 + offset).astype(int)
        screen[row, col] = 255
        view = world.hooks.frame(screen.T[None])  # HighwayEnv's obs: stack x W x H
        assert view.shape == (48, 64) and np.unravel_index(view.argmax(), view.shape) == where
    world.close()


def test_highways_car_view_needs_an_observation_that_holds_the_turned_frame(highway_config) -> None:
    from uqdrive.sim.gym_highway import car_view_side

    config = copy.deepcopy(highway_config.to_dict())
    config["env_kwargs"]["config"]["observation"]["observation_shape"] = [car_view_side() - 1, 120]
    with pytest.raises(ConfigError, match=rf"observation_shape=\[{car_view_side() - 1}, 120\]: the car view needs"):
        GymWorld(GymWorldConfig.from_config(config))
    with pytest.raises(ConfigError, match=r"^gym_world.hooks_options.view='bird' must be one of world, car$"):
        GymWorldConfig.from_config({**highway_config.to_dict(), "hooks_options": {"view": "bird"}})
