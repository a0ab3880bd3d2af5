"""HighwayEnv (``highway-env``) as a uqdrive world: the hooks `GymWorld` reads its envs through (``hooks: highway``).
The one module of uqdrive that names that package.

- The env must steer only: ``action: {type: ContinuousAction, longitudinal: false, lateral: true}`` (its roundabout's
  reward cannot take a two-component action), and observe ``GrayscaleObservation`` (C x W x H; the last frame,
  transposed, is the grey frame: a top-down view, world-aligned, centred on the ego).
- Speed: ContinuousAction's ``speed_range`` bounds the ego's speed, and a bound the ego is outside pulls it back
  at (bound − v) per second (``Vehicle.clip_actions``); a range of (speed, speed) is thus a first-order speed
  tracker with a 1 s time constant, set every step.
- Frames: HighwayEnv draws with y down the screen, so uqdrive's pose is (x, −y, −heading): what the picture shows
  as a left turn is a left turn (+ steer, counter-clockwise yaw, + lateral deviation), and steer s is
  ContinuousAction's −s (its steering_range, ±45° by default, maps [-1, 1] to the road-wheel angle).
- View (``hooks_options.view``): ``world`` gives HighwayEnv's frame as it draws it (north up); ``car`` turns it
  with the ego, as a camera on the car would see it: the ego points up at `CAR_VIEW_EGO_ROW` of the network's
  64x48 frame, so the frame shows more road ahead than behind. The car view cuts that frame out of a larger
  observation at the same px per m, so ``observation_shape`` must hold the turned frame's corners (side ≥
  `car_view_side`).
- State: ``collision`` is the ego's ``crashed``; ``off_road`` is not ``on_road`` (off its closest lane's width);
  ``lateral_deviation`` is the offset from that lane's centre line. The info also gets ``on_road`` for the safe set.
- Expert: IDM (speed) and MOBIL (lanes) with HighwayEnv's lane-following steering, i.e. the policy of its own
  traffic (``IDMVehicle``), evaluated in the ego's place every step by a shadow vehicle that follows a route to
  ``destination`` (``hooks_options``; the roundabout's ego is routed to its north exit, ``nxs``) at ``expert_speed``.
  The shadow takes the ego's state, stands in for it in the road's vehicle list while it decides (so that it sees
  the traffic, not the ego) and draws nothing from the env's random generator: querying the expert leaves the
  episode as it would be without.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import cv2
import highway_env  # noqa: F401  (registers HighwayEnv's ids)
import numpy as np
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.vehicle.behavior import IDMVehicle

from uqdrive.network_input import INPUT_HEIGHT, INPUT_WIDTH
from uqdrive.schema import ConfigError, invalid

from .config import GymWorldConfig
from .gym_hooks import WorldHooks

SPEED_TIME_CONSTANT_S = 1.0  # of the speed_range tracker: acceleration = (command − v) / this
CAR_VIEW_EGO_ROW = 0.75  # of the car view's height, from the top: 3/4 of the frame lies ahead of the ego
VIEWS = ("world", "car")


def car_view_side() -> int:
    """The least side (px) of a square observation centred on the ego that holds the car view's turned frame."""
    reach = np.hypot(INPUT_WIDTH / 2, INPUT_HEIGHT * CAR_VIEW_EGO_ROW)
    return 2 * int(np.ceil(reach)) + 2  # + a pixel each side for the interpolation


class HighwayHooks(WorldHooks):
    """A HighwayEnv env's ego vehicle behind `GymWorld` (module docstring)."""

    OPTIONS: ClassVar[Mapping[str, Any]] = {"destination": "nxs", "expert_speed": 8.0, "view": "world"}
    packages: ClassVar[tuple[str, ...]] = ("highway-env", "pygame-ce")  # the sim, and what draws its observation

    def __init__(self, env: Any, config: GymWorldConfig):
        super().__init__(env, config)
        self.env = env.unwrapped
        if not isinstance(self.env, AbstractEnv):
            raise ConfigError(f"gym_world.env_id={config.env_id!r} is not a HighwayEnv env (hooks: highway)")
        policy_hz = self.env.config["policy_frequency"]
        if policy_hz != config.control_hz:
            raise ConfigError(
                f"gym_world.control_hz={config.control_hz}: {config.env_id}'s policy_frequency is {policy_hz}"
            )
        nodes = self.env.road.network.graph  # made with the env (its constructor resets it): checked before any run
        if self.options["destination"] not in nodes:
            raise ConfigError(
                f"gym_world.hooks_options.destination={self.options['destination']!r}: not a node of {config.env_id}'s "
                f"road network ({sorted(nodes)})"
            )
        if self.options["view"] == "car":
            shape = self.env.config["observation"].get("observation_shape", (0, 0))
            if min(shape) < car_view_side():
                raise ConfigError(
                    f"gym_world.env_kwargs.config.observation.observation_shape={list(shape)}: the car view needs "
                    f"both sides ≥ {car_view_side()} px (its {INPUT_WIDTH}x{INPUT_HEIGHT} frame, turned)"
                )
        self._shadow: IDMVehicle | None = None
        self._timer0 = 0.0

    @classmethod
    def check_options(cls, options: Mapping[str, Any]) -> None:
        """The keys, and their values' types (a destination's node is checked against the road when the env is made)."""
        super().check_options(options)
        speed, destination = options.get("expert_speed", 8.0), options.get("destination", "nxs")
        if isinstance(speed, bool) or not isinstance(speed, int | float) or speed <= 0:
            raise invalid("hooks_options.expert_speed", speed, "must be a speed > 0 (m/s)")
        if not isinstance(destination, str):
            raise invalid("hooks_options.destination", destination, "must be a node of the road network (a string)")
        view = options.get("view", "world")
        if view not in VIEWS:
            raise invalid("hooks_options.view", view, f"must be one of {', '.join(VIEWS)}")

    @classmethod
    def env_kwargs(cls, kwargs: Mapping[str, Any]) -> dict[str, Any]:
        """The env's ``config`` checked before the env is made (its roundabout fails inside its constructor on a
        two-component action), the observation's shape as the tuple HighwayEnv takes (yaml gives lists)."""
        config = dict(kwargs.get("config", {}))
        action, observation = dict(config.get("action", {})), dict(config.get("observation", {}))
        if (
            action.get("type") != "ContinuousAction"
            or action.get("longitudinal", True)
            or not action.get("lateral", True)
        ):
            raise ConfigError(
                "gym_world.env_kwargs.config.action: must be {type: ContinuousAction, longitudinal: false, "
                f"lateral: true}} (steering only), got {action}"
            )
        if observation.get("type") != "GrayscaleObservation":
            raise ConfigError(
                f"gym_world.env_kwargs.config.observation.type={observation.get('type')!r}: "
                "must be GrayscaleObservation"
            )
        if "observation_shape" in observation:
            observation["observation_shape"] = tuple(observation["observation_shape"])
        return {**kwargs, "config": {**config, "observation": observation}}

    def begin(self) -> None:
        ego, road, destination = self.env.vehicle, self.env.road, self.options["destination"]
        self._shadow = IDMVehicle(
            road, ego.position.copy(), ego.heading, ego.speed, ego.lane_index, float(self.options["expert_speed"])
        )
        self._shadow.plan_route_to(destination)
        self._timer0 = self._shadow.timer

    def frame(self, obs: Any) -> np.ndarray:
        grey = np.ascontiguousarray(np.asarray(obs)[-1].T)  # rows: y down the screen; the ego at the centre
        if self.options["view"] == "world":
            return grey
        heading = self.env.vehicle.heading  # on the screen: the ego points along (cos, sin), its right is (−sin, cos)
        ahead, right = np.array([np.cos(heading), np.sin(heading)]), np.array([-np.sin(heading), np.cos(heading)])
        ego_on_screen = np.array([grey.shape[1], grey.shape[0]]) / 2
        ego_in_view = np.array([INPUT_WIDTH / 2, INPUT_HEIGHT * CAR_VIEW_EGO_ROW])
        to_screen = np.column_stack([right, -ahead])  # the view's (column, row) offset from the ego → the screen's
        offset = ego_on_screen - to_screen @ ego_in_view
        return cv2.warpAffine(
            grey, np.column_stack([to_screen, offset]), (INPUT_WIDTH, INPUT_HEIGHT), flags=cv2.WARP_INVERSE_MAP
        )

    def state(self, info: Mapping[str, Any]) -> dict[str, Any]:
        ego = self.env.vehicle
        on_road = bool(ego.on_road)
        return {
            "x": float(ego.position[0]),
            "y": -float(ego.position[1]),
            "yaw": -float(ego.heading),
            "speed": float(ego.speed),
            "collision": bool(ego.crashed),
            "off_road": not on_road,
            "lateral_deviation": -float(ego.lane.local_coordinates(ego.position)[1]),
            "on_road": on_road,
        }

    def action(self, steer: float, speed: float) -> np.ndarray:
        self.env.action_type.speed_range = (speed, speed)
        return np.array([-steer], dtype=np.float32)

    def expert(self) -> tuple[float, float]:
        """IDM/MOBIL's command for the ego now, as (steer, speed): the steering angle over ContinuousAction's
        range (clipped to [-1, 1]), and the speed whose tracking gives IDM's acceleration this step."""
        if self._shadow is None:
            raise RuntimeError("no episode yet; call reset() first")
        ego, shadow, vehicles = self.env.vehicle, self._shadow, self.env.road.vehicles
        shadow.position, shadow.heading, shadow.speed = ego.position.copy(), ego.heading, ego.speed
        shadow.lane_index, shadow.lane = ego.lane_index, ego.lane
        shadow.timer = self._timer0 + self.env.time  # MOBIL's decision clock, as if the shadow had driven
        slot = vehicles.index(ego)
        vehicles[slot] = shadow
        try:
            shadow.act()
        finally:
            vehicles[slot] = ego
        steer = -shadow.action["steering"] / self.env.action_type.steering_range[1]
        speed = ego.speed + shadow.action["acceleration"] * SPEED_TIME_CONSTANT_S
        return float(np.clip(steer, -1.0, 1.0)), max(float(speed), 0.0)
