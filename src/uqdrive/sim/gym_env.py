"""uqdrive's world as a Gymnasium env: ``gymnasium.make("uqdrive/Roundabout-v0", weather="rain", noise=0.05)``.

Importing this module registers one id per scenario kind (``uqdrive/Straight-v0``, ``uqdrive/Obstacle-v0``,
``uqdrive/Roundabout-v0``); ``gymnasium.make("uqdrive.sim.gym_env:uqdrive/Roundabout-v0")`` imports it on the way
(Gymnasium 1.x loads no plugin entry points, so an import is the registration).

- observation: the network's grey frame, uint8 [48, 64] (`preprocess_frame` of the camera's RGB frame, weather
  and sensor noise included); ``render()`` gives that RGB frame (``render_mode="rgb_array"``).
- action: the steering command in [-1, 1] (+ = left), at a fixed ``cruise_speed``: the paper's controllers only
  steer. ``speed_action=True`` adds a second component, the commanded speed in [0, vehicle.max_speed] m/s, for
  drivers that also choose their speed (the autopilot, a handover that brakes to a stop).
- reward: metres of route progress in the step (the pipeline judges paths by their safe set, not by reward).
- terminated: collision, off road or route complete; truncated: the horizon (``horizon_s``).
- info: `DrivingEnv`'s (t, x, y, yaw, speed, steering, collision, off_road, lateral_deviation, progress, termination)
  and ``seed``, the episode's world seed.

``reset(seed=s)`` drives the world of rollout seed ``s``: the same start jitter, weather streaks and sensor noise
as ``DrivingEnv.reset(s, …)``, so a Gymnasium rollout with seed base_seed + i is the pipeline's rollout i. Without a
seed the episode seed is drawn from ``np_random`` (seeded by the last explicit seed, as Gymnasium expects).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from uqdrive.network_input import INPUT_HEIGHT, INPUT_WIDTH, preprocess_frame
from uqdrive.schema import ConfigError

from .config import (
    SCENARIO_KINDS,
    CameraConfig,
    ScenarioConfig,
    Section,
    VehicleConfig,
    WeatherConfig,
    check_noise,
    find_conf,
)
from .env import DrivingEnv

ENV_IDS = {kind: f"uqdrive/{kind.capitalize()}-v0" for kind in SCENARIO_KINDS}
CRUISE_SPEEDS = {"straight": 8.0, "obstacle": 8.0, "roundabout": 6.0}  # m/s: the avoid and safety stages' speeds
_TERMINAL = ("collision", "off_road", "route_complete")  # the rest: "timeout", a truncation


class UqdriveEnv(gymnasium.Env):
    """`DrivingEnv` behind Gymnasium's API (see the module docstring for spaces, reward and info)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 15}

    def __init__(
        self,
        kind: str = "roundabout",
        scenario: str | ScenarioConfig | Mapping[str, Any] | None = None,
        weather: str | WeatherConfig | Mapping[str, Any] | None = None,
        noise: float = 0.0,
        cruise_speed: float = 6.0,
        speed_action: bool = False,
        control_hz: float = 15.0,
        horizon_s: float = 40.0,
        camera: CameraConfig | Mapping[str, Any] | None = None,
        vehicle: VehicleConfig | Mapping[str, Any] | None = None,
        render_mode: str | None = None,
    ):
        if kind not in SCENARIO_KINDS:
            raise ConfigError(f"kind={kind!r}: must be one of {list(SCENARIO_KINDS)}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ConfigError(f"render_mode={render_mode!r}: must be None or 'rgb_array'")
        if not cruise_speed > 0:
            raise ConfigError(f"cruise_speed={cruise_speed!r}: must be > 0 (m/s)")
        self.scenario = _section(ScenarioConfig, scenario if scenario is not None else kind)
        if self.scenario.kind != kind:
            raise ConfigError(f"scenario={self.scenario.name!r} is a {self.scenario.kind} scenario, not a {kind} one")
        self.weather = _section(WeatherConfig, weather) if weather is not None else WeatherConfig()
        self.noise = check_noise(noise)
        self.cruise_speed = float(cruise_speed)
        self.render_mode = render_mode
        self.driving = DrivingEnv(
            _section(CameraConfig, camera or {}), _section(VehicleConfig, vehicle or {}), control_hz, horizon_s
        )
        self.observation_space = spaces.Box(0, 255, (INPUT_HEIGHT, INPUT_WIDTH), np.uint8)
        max_speed = self.driving.vehicle_config.max_speed
        low, high = ([-1.0, 0.0], [1.0, max_speed]) if speed_action else ([-1.0], [1.0])
        self.action_space = spaces.Box(np.array(low, np.float32), np.array(high, np.float32), dtype=np.float32)
        self._frame: np.ndarray | None = None
        self._progress = 0.0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        episode_seed = seed if seed is not None else int(self.np_random.integers(2**63 - 1))
        self._frame = self.driving.reset(episode_seed, self)  # its scenario, weather and noise: a `ResetCondition`
        info = dict(self.driving.last_info, seed=episode_seed)
        self._progress = info["progress"]
        return preprocess_frame(self._frame), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        command = np.asarray(action, np.float64).reshape(-1)
        if command.shape != self.action_space.shape:
            raise ValueError(f"action of shape {command.shape}: expected {self.action_space.shape}")
        speed = float(command[1]) if len(command) == 2 else self.cruise_speed
        self._frame, info = self.driving.step(float(command[0]), speed)
        reward = info["progress"] - self._progress
        self._progress = info["progress"]
        termination = info["termination"]
        return preprocess_frame(self._frame), reward, termination in _TERMINAL, termination == "timeout", dict(info)

    def render(self) -> np.ndarray | None:
        """The camera's RGB frame (uint8 [48, 64, 3]) the observation was made from."""
        if self.render_mode != "rgb_array" or self._frame is None:
            return None
        return self._frame.copy()

    def close(self) -> None:
        self.driving.close()


def _section(cls: type[Section], value: Any) -> Any:
    """A world section from a conf/<group>/ name, a mapping (missing keys take their defaults) or the schema itself."""
    if isinstance(value, cls):
        return value
    if isinstance(value, Mapping):
        return cls.from_config(value)
    group = cls.section
    if isinstance(value, str):
        folder = find_conf() / group
        if not (folder / f"{value}.yaml").is_file():
            names = sorted(p.stem for p in folder.glob("*.yaml"))
            raise ConfigError(f"{group}={value!r}: no conf/{group}/{value}.yaml; choose one of {names}")
        return cls.from_yaml(folder / f"{value}.yaml")
    raise ConfigError(f"{group}={value!r}: expected a conf/{group}/ name, a mapping or a {cls.__name__}")


def register_envs() -> None:
    """Register one id per scenario kind (idempotent: a second import registers nothing again)."""
    for kind, env_id in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                env_id,
                entry_point="uqdrive.sim.gym_env:UqdriveEnv",
                kwargs={"kind": kind, "cruise_speed": CRUISE_SPEEDS[kind]},
            )


register_envs()
