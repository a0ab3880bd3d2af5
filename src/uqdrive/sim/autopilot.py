"""Pure-pursuit autopilot that produces the training data.

It follows the scenario route (lane change around the obstacle, first exit at the
roundabout). Seeded steering perturbations push the car off the route; the label stays the
autopilot's own unperturbed command, so the data also teaches how to recover.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .config import AutopilotConfig, VehicleConfig
from .route import Route


@dataclasses.dataclass(frozen=True)
class AutopilotAction:
    """steer: applied (maybe perturbed) in [-1, 1], + = left; label: unperturbed steer; speed in m/s."""

    steer: float
    speed: float
    label: float
    perturbed: bool


class SteeringPerturbation:
    """Seeded pushes off an expert's steering (``perturb_*`` of `AutopilotConfig`): now and then, for
    ``perturb_duration_s``, an offset is added to the label; the label stays the expert's, so the data also shows
    how to come back. Used by the autopilot and by a Gymnasium world's expert (`uqdrive.sim.episodes`)."""

    def __init__(self, config: AutopilotConfig, control_hz: float, seed: int):
        self.config = config
        self._rng = np.random.default_rng(seed)
        self._steps = max(1, int(round(config.perturb_duration_s * control_hz)))
        self._left = 0
        self._offset = 0.0

    def apply(self, label: float) -> tuple[float, bool]:
        """The steer to apply for the expert's ``label`` this step, and whether it is perturbed."""
        cfg = self.config
        # one uniform draw per step, perturbing or not, so the stream never depends on the path
        u = self._rng.random(2)
        if self._left == 0 and u[0] < cfg.perturb_prob:
            self._left = self._steps
            self._offset = cfg.perturb_magnitude * (0.5 + 0.5 * abs(2 * u[1] - 1)) * (1 if u[1] >= 0.5 else -1)
        perturbed = self._left > 0
        steer = float(np.clip(label + self._offset, -1.0, 1.0)) if perturbed else label
        if perturbed:
            self._left -= 1
        return steer, perturbed


class Autopilot:
    """Pure pursuit from the rear axle towards a speed-dependent lookahead point on the route."""

    def __init__(
        self,
        route: Route,
        vehicle: VehicleConfig,
        config: AutopilotConfig | None = None,
        control_hz: float = 15.0,
        seed: int = 0,
    ):
        self.route = route
        self.vehicle = vehicle
        self.config = config or AutopilotConfig()
        self.max_steer = math.radians(vehicle.max_steer_deg)
        self._curv = np.abs(route.curvature())
        self._perturbation = SteeringPerturbation(self.config, control_hz, seed)

    def _speed(self, s: float, v: float) -> float:
        cfg = self.config
        ahead = (self.route.s >= s) & (self.route.s <= s + 2.0 * v + 6.0)
        kappa = float(self._curv[ahead].max()) if ahead.any() else 0.0
        limit = math.sqrt(cfg.max_lateral_accel / kappa) if kappa > 1e-6 else cfg.target_speed
        return float(min(cfg.target_speed, max(cfg.min_speed, limit)))

    def act(self, info: dict) -> AutopilotAction:
        """Command for the state in ``info`` (x, y, yaw, speed of the body centre)."""
        cfg = self.config
        x, y, yaw, v = info["x"], info["y"], info["yaw"], info["speed"]
        half = self.vehicle.wheelbase / 2
        rx, ry = x - half * math.cos(yaw), y - half * math.sin(yaw)
        s = self.route.project_point(rx, ry)[0]
        lookahead = cfg.lookahead_base + cfg.lookahead_gain * v
        tx, ty, _ = self.route.sample(s + lookahead)
        dx, dy = float(tx) - rx, float(ty) - ry
        alpha = math.atan2(dy, dx) - yaw
        dist = max(math.hypot(dx, dy), 1e-6)
        angle = math.atan2(2.0 * self.vehicle.wheelbase * math.sin(alpha), dist)
        label = float(np.clip(angle / self.max_steer, -1.0, 1.0))
        steer, perturbed = self._perturbation.apply(label)
        return AutopilotAction(steer, self._speed(s + half, v), label, perturbed)
