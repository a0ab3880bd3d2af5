"""``DrivingEnv``: one closed-loop driving environment for the autopilot and learned controllers."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from uqdrive.schema import ConfigError

from .autopilot import Autopilot
from .bullet import connect_direct
from .camera import Camera
from .config import (
    STOPPED_SPEED,
    AutopilotConfig,
    CameraConfig,
    ScenarioConfig,
    VehicleConfig,
    WeatherConfig,
    check_noise,
)
from .geometry import ScenarioGeometry, build_geometry
from .route import Route
from .scene import Scene
from .vehicle import KinematicBicycle, VehicleState
from .world import Expert, R, ResetCondition, World, WorldVisitor

TERMINATIONS = ("", "collision", "off_road", "route_complete", "timeout")


class DrivingEnv(World):
    """Kinematic car in a static pybullet world, seen through a front camera.

    Each env owns a DIRECT pybullet client, so envs in different workers never interfere.
    The world is rebuilt only when the scenario config changes. ``reset(seed)`` fixes the
    start pose and the sensor randomness, so the same seed and commands give the same path
    and the same images.
    """

    def __init__(
        self,
        camera: CameraConfig | None = None,
        vehicle: VehicleConfig | None = None,
        control_hz: float = 15.0,
        horizon_s: float = 40.0,
    ):
        if not control_hz > 0:
            raise ConfigError(f"control_hz={control_hz!r} must be > 0")
        if not horizon_s > 0:
            raise ConfigError(f"horizon_s={horizon_s!r} must be > 0")
        super().__init__()
        self.camera_config = camera or CameraConfig()
        self.vehicle_config = vehicle or VehicleConfig()
        self.control_hz = float(control_hz)
        self.dt = 1.0 / self.control_hz
        self.horizon_s = float(horizon_s)
        self.client = connect_direct()
        self.camera = Camera(self.client, self.camera_config)
        self.model = KinematicBicycle(self.vehicle_config)
        self._scenario: ScenarioConfig | None = None
        self._geometry: ScenarioGeometry | None = None
        self._scene: Scene | None = None
        self._state: VehicleState | None = None

    # -- lifecycle ------------------------------------------------------------------------
    def reset(self, seed: int, where: ResetCondition | None = None, render: bool = True) -> np.ndarray | None:
        """Start an episode at ``where`` (a road's scenario, a weather, none: the default one, and ``noise``, the
        Gaussian pixel-noise sigma in units of full intensity); returns the first observation (None when ``render``
        is False)."""
        scenario = getattr(where, "scenario", None)
        if not isinstance(scenario, ScenarioConfig):
            raise TypeError(f"scenario must be a ScenarioConfig, got {type(scenario).__name__}")
        self.noise = check_noise(where.noise)
        self.weather = where.weather or WeatherConfig()
        self.render_enabled = bool(render)
        if self._scenario != scenario:
            self._geometry = build_geometry(scenario)
            self._scene = Scene(self.client, self._geometry, self.vehicle_config)
            self._scenario = dataclasses.replace(scenario)
        pose_rng, streak_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3))
        self._streak_rng, self._noise_rng = streak_rng, noise_rng
        x0, y0, yaw0 = self._geometry.start
        d_long, d_lat, d_yaw = pose_rng.uniform(-1.0, 1.0, size=3) * [
            scenario.start_jitter_longitudinal,
            scenario.start_jitter_lateral,
            math.radians(scenario.start_jitter_yaw_deg),
        ]
        x = x0 + d_long * math.cos(yaw0) - d_lat * math.sin(yaw0)
        y = y0 + d_long * math.sin(yaw0) + d_lat * math.cos(yaw0)
        self._state = VehicleState(x, y, yaw0 + d_yaw, min(scenario.start_speed, self.vehicle_config.max_speed))
        self._t = 0.0
        self._applied = 0.0
        self._done = False
        self._start_log()
        self.last_info = self._evaluate()
        return self._observe()

    def step(self, steer: float, speed: float) -> tuple[np.ndarray | None, dict]:
        """Advance one control period.

        steer: in [-1, 1] (clipped), road-wheel angle = steer * max_steer; positive = left
        (counter-clockwise yaw). speed: commanded speed in m/s, tracked within accel/brake limits.
        """
        if self._done:
            raise RuntimeError("episode is over (or was never started); call reset() first")
        self._state = self.model.step(self._state, steer, speed, self.dt)
        self._t += self.dt
        self._applied = min(max(float(steer), -1.0), 1.0)  # np.clip's value, nan included, without its cost
        info = self._evaluate()
        self.last_info = info
        return self._observe(), info

    def _evaluate(self) -> dict:
        st, geo, world = self._state, self._geometry, self._scene
        world.set_ego_pose(st.x, st.y, st.yaw)
        collision = world.in_collision(st.x, st.y)
        off_road = not geo.paved.covers(self.model.corners(st))
        progress, lateral = geo.route.project_point(st.x, st.y)
        if collision:
            termination = "collision"
        elif off_road:
            termination = "off_road"
        elif progress >= geo.route.length - self._scenario.finish_margin:
            termination = "route_complete"
        elif self._t >= self.horizon_s - 1e-9:
            termination = "timeout"
        else:
            termination = ""
        self._done = termination != ""
        self._log_step((self._t, st.x, st.y, st.yaw, st.speed, self._applied))
        return {
            "t": self._t,
            "x": st.x,
            "y": st.y,
            "yaw": st.yaw,
            "speed": st.speed,
            "steering": self._applied,
            "steer_angle": st.steer_angle,
            "collision": collision,
            "off_road": off_road,
            "lateral_deviation": lateral,
            "progress": progress,
            "done": self._done,
            "termination": termination,
        }

    def _observe(self) -> np.ndarray | None:
        if not self.render_enabled:
            return None
        st = self._state
        self._scene.cull(*self.camera.view_wedge(st.x, st.y, st.yaw))
        return self.camera.render(
            st.x, st.y, st.yaw, self.weather, self._scene.road_lookup, self._streak_rng, self.noise, self._noise_rng
        )

    # -- accessors ------------------------------------------------------------------------
    @property
    def geometry(self) -> ScenarioGeometry:
        if self._geometry is None:
            raise RuntimeError("no scenario yet; call reset() first")
        return self._geometry

    @property
    def route(self) -> Route:
        return self.geometry.route

    @property
    def scene(self) -> Scene:
        if self._scene is None:
            raise RuntimeError("no scenario yet; call reset() first")
        return self._scene

    @property
    def lane(self) -> ScenarioGeometry:
        """The road's lane: the scenario's route."""
        return self.geometry

    @property
    def stopped_speed(self) -> float:
        return STOPPED_SPEED

    @property
    def car_size(self) -> tuple[float, float]:
        return self.vehicle_config.length, self.vehicle_config.width

    def expert(self, autopilot: AutopilotConfig, seed: int) -> Expert:
        """uqdrive's autopilot on this scenario's route, seeded by the episode: its label and speed."""
        pilot = Autopilot(self.route, self.vehicle_config, autopilot, self.control_hz, seed=seed)

        def command(info: dict) -> tuple[float, float]:
            action = pilot.act(info)
            return action.label, action.speed

        return command

    def visit(self, visitor: WorldVisitor[R]) -> R:
        return visitor.road(self.geometry)

    def close(self) -> None:
        if self.client is not None:
            self.client.disconnect()
            self.client = None
