"""Simulated driving world (pybullet): scenarios, car, camera and weather, autopilot, ``DrivingEnv``."""

from .autopilot import Autopilot, AutopilotAction
from .config import (
    SCENARIO_KINDS,
    AutopilotConfig,
    CameraConfig,
    ScenarioConfig,
    VehicleConfig,
    WeatherConfig,
    check_noise,
)
from .env import TERMINATIONS, DrivingEnv
from .geometry import ScenarioGeometry, build_geometry
from .paving import PavedArea
from .route import Route
from .vehicle import KinematicBicycle, VehicleState

__all__ = [
    "SCENARIO_KINDS",
    "TERMINATIONS",
    "Autopilot",
    "AutopilotAction",
    "AutopilotConfig",
    "CameraConfig",
    "DrivingEnv",
    "KinematicBicycle",
    "PavedArea",
    "Route",
    "ScenarioConfig",
    "ScenarioGeometry",
    "VehicleConfig",
    "VehicleState",
    "WeatherConfig",
    "build_geometry",
    "check_noise",
]
