"""Where a condition drives, one type per world (`Location`): a road of uqdrive's pybullet world (`RoadLocation`, a
`ScenarioConfig`) or a Gymnasium world (`GymLocation`, a `GymWorldConfig`).

Everything whose answer depends on which world a rollout drives in is a method here: the world to make and which
worlds one key interchanges, the car, camera, rate, horizon and corridor a job drives with (`drive`), whether the
agent sees the env's own spaces, a weather's name there, what a cell's identity records beyond uqdrive's code, and a
visitor's answer (`visit`: an upper layer's operation on a road's geometry or in a Gymnasium world; `choose`: a
stage's question on the location's config). `location_of` is the one place that tells the two configs apart; no code
outside `uqdrive.sim` asks which world it has.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable
from typing import Any, Generic, Protocol

from .config import CameraConfig, GymWorldConfig, ScenarioConfig, VehicleConfig, WeatherConfig
from .env import DrivingEnv
from .geometry import build_geometry
from .gym_world import GymWorld, world_identity, world_modules
from .world import R, World, WorldVisitor

NO_WEATHER = "env"  # a Gymnasium world's weather in cell names and records: the env's own, none of ours


class LocationVisitor(Protocol[R]):
    """A stage's question whose answer depends on the world, on the location's own config: one method per world,
    called by the location it is handed to (`Location.choose`)."""

    def road(self, scenario: ScenarioConfig) -> R:
        """The answer on a road of uqdrive's pybullet world."""
        ...

    def gym(self, world: GymWorldConfig) -> R:
        """The answer in a Gymnasium world."""
        ...


@dataclasses.dataclass(frozen=True)
class ByWorld(Generic[R]):
    """A `LocationVisitor` made of two functions, one per world (a stage's check or choice of a few lines)."""

    road: Callable[[ScenarioConfig], R]
    gym: Callable[[GymWorldConfig], R]


def nothing(config: object) -> None:
    """A `ByWorld` answer for the world that has nothing to do."""


class Location(abc.ABC):
    """A location of one world: its config (``config``), its name, and every answer that differs by world."""

    config: ScenarioConfig | GymWorldConfig

    @property
    def name(self) -> str:
        return self.config.name

    @property
    @abc.abstractmethod
    def native(self) -> bool:
        """Whether rollouts here drive an env as it is: the agent sees its observation and acts in its action space."""

    @property
    @abc.abstractmethod
    def external(self) -> bool:
        """Whether rollouts here run code and config beyond uqdrive's and the condition's fields (a Gymnasium
        world's env and hooks), which a cell's identity then records (`external_identity`, `loaded_modules`)."""

    @abc.abstractmethod
    def weather_name(self, weather: WeatherConfig | None) -> str:
        """A weather's name here, in cell names and records."""

    @abc.abstractmethod
    def make_world(self, camera: CameraConfig, vehicle: VehicleConfig, control_hz: float, horizon_s: float) -> World:
        """A new world to drive this location in."""

    @abc.abstractmethod
    def world_key(self, camera: CameraConfig, vehicle: VehicleConfig, control_hz: float, horizon_s: float) -> str:
        """The worlds `make_world` makes with one key interchange (a reset sets everything else)."""

    @abc.abstractmethod
    def drive(self, camera: CameraConfig, vehicle: VehicleConfig, control_hz: float, horizon_s: float,
              half_width: float | None = None) -> dict[str, Any]:  # fmt: skip
        """The car (``vehicle``), ``camera``, ``control_hz``, ``horizon_s`` and corridor (``half_width``; None: the
        lane, or none) a job here drives with, from a stage's settings: a `RolloutJob`'s keyword arguments."""

    @abc.abstractmethod
    def visit(self, visitor: WorldVisitor[R]) -> R:
        """``visitor``'s answer here: on the road (its geometry built here), or in the Gymnasium world."""

    @abc.abstractmethod
    def choose(self, visitor: LocationVisitor[R]) -> R:
        """``visitor``'s answer for this location's config."""

    def external_identity(self) -> dict[str, Any] | None:
        """The world's identity beyond uqdrive's code (`uqdrive.sim.gym_world.world_identity`); None: nothing."""
        return None

    def loaded_modules(self) -> list[str]:
        """The modules rollouts here load by name, which no static import reaches (`world_modules`)."""
        return []


@dataclasses.dataclass(frozen=True)
class RoadLocation(Location):
    """A road of uqdrive's pybullet world (its scenario), driven by uqdrive's car, seen by its camera, in a weather."""

    config: ScenarioConfig

    native = False
    external = False

    def weather_name(self, weather: WeatherConfig | None) -> str:
        return NO_WEATHER if weather is None else weather.name

    def make_world(self, camera: CameraConfig, vehicle: VehicleConfig, control_hz: float, horizon_s: float) -> World:
        return DrivingEnv(camera, vehicle, control_hz, horizon_s)

    def world_key(self, camera: CameraConfig, vehicle: VehicleConfig, control_hz: float, horizon_s: float) -> str:
        return repr((camera, vehicle, control_hz, horizon_s))  # the pybullet worlds of one camera, car, rate, horizon

    def drive(self, camera: CameraConfig, vehicle: VehicleConfig, control_hz: float, horizon_s: float,
              half_width: float | None = None) -> dict[str, Any]:  # fmt: skip
        return {"camera": camera, "vehicle": vehicle, "control_hz": control_hz, "horizon_s": horizon_s,
                "half_width": half_width}  # fmt: skip

    def visit(self, visitor: WorldVisitor[R]) -> R:
        return visitor.road(build_geometry(self.config))

    def choose(self, visitor: LocationVisitor[R]) -> R:
        return visitor.road(self.config)


@dataclasses.dataclass(frozen=True)
class GymLocation(Location):
    """A Gymnasium world (its config): the env is the whole world, with its own rate, horizon and car, no weather of
    ours and no corridor."""

    config: GymWorldConfig

    external = True

    @property
    def native(self) -> bool:
        return self.config.native

    def weather_name(self, weather: WeatherConfig | None) -> str:
        return NO_WEATHER

    def make_world(self, camera: CameraConfig, vehicle: VehicleConfig, control_hz: float, horizon_s: float) -> World:
        return GymWorld(self.config)

    def world_key(self, camera: CameraConfig, vehicle: VehicleConfig, control_hz: float, horizon_s: float) -> str:
        return "gym"  # every Gymnasium world: a reset remakes its env for another config

    def drive(self, camera: CameraConfig, vehicle: VehicleConfig, control_hz: float, horizon_s: float,
              half_width: float | None = None) -> dict[str, Any]:  # fmt: skip
        """The world's own rate and horizon (``horizon_steps``); no car, camera or corridor of ours (defaults, so
        that no setting its rollouts do not read enters a cell's identity)."""
        hz = float(self.config.control_hz)
        return {"camera": CameraConfig(), "vehicle": VehicleConfig(), "control_hz": hz,
                "horizon_s": self.config.horizon_steps / hz, "half_width": None}  # fmt: skip

    def visit(self, visitor: WorldVisitor[R]) -> R:
        return visitor.gym(self.config)

    def choose(self, visitor: LocationVisitor[R]) -> R:
        return visitor.gym(self.config)

    def external_identity(self) -> dict[str, Any] | None:
        return world_identity(self.config)

    def loaded_modules(self) -> list[str]:
        return world_modules(self.config)


def location_of(config: ScenarioConfig | GymWorldConfig) -> Location:
    """The location a config names: a Gymnasium world's, or a road's."""
    return GymLocation(config) if isinstance(config, GymWorldConfig) else RoadLocation(config)
