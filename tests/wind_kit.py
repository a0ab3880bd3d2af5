"""A second Gymnasium world beside HighwayEnv's, as a user would add one: a tiny env (a car on a straight lane pushed
left by a wind whose strength is the env's own ``wind`` kwarg) and its hooks with an expert (steer back to the
centre). Its conf is tests/worlds/gym_world/wind_lane.yaml (with its own condition axis: the wind) and its experiment
tests/worlds/experiment/wind_lane.yaml; tests/test_second_world.py collects, trains and sweeps it."""

from __future__ import annotations

import gymnasium
import numpy as np
from gymnasium import spaces

from uqdrive.sim.gym_hooks import WorldHooks


class WindLane(gymnasium.Env):
    """The car moves 0.4 m a step; the wind pushes it ``wind`` m left a step, its steering up to 0.3 m back."""

    observation_space = spaces.Box(0, 255, (48, 64, 3), np.uint8)  # a bright column where the car is
    action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, wind: float = 0.1):
        self.wind = float(wind)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.x, self.y, self.v = 0.0, float(self.np_random.uniform(-0.3, 0.3)), 6.0
        return self._obs(), {}

    def step(self, action):
        self.x += 0.4
        self.y += 0.3 * float(action[0]) + self.wind + float(self.np_random.normal(0.0, 0.02))
        return self._obs(), 0.0, False, False, {}

    def _obs(self):
        image = np.full((48, 64, 3), 40, np.uint8)
        column = int(np.clip(32 - 10 * self.y, 0, 63))  # y is to the left: left of the picture's centre
        image[:, max(column - 2, 0) : column + 3] = 220
        return image


class WindHooks(WorldHooks):
    """What uqdrive reads of the wind lane: its frame, the car's state (off the road past ``half_width``), the
    action, and the expert that labels collected frames."""

    OPTIONS = {"half_width": 1.0}

    def frame(self, obs):
        return obs[..., 0]

    def state(self, info):
        car = self.env.unwrapped
        return dict(x=car.x, y=car.y, yaw=0.0, speed=car.v, collision=False, lateral_deviation=car.y,
                    off_road=abs(car.y) > self.options["half_width"])  # fmt: skip

    def action(self, steer, speed):
        return np.array([steer], np.float32)

    def expert(self):
        return float(np.clip(-self.env.unwrapped.y - self.env.unwrapped.wind / 0.3, -1.0, 1.0)), 6.0


gymnasium.register("wind_kit/WindLane-v0", entry_point="wind_kit:WindLane")
