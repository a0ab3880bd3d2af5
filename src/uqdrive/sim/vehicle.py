"""Kinematic bicycle model of the ego car, integrated in numpy.

Kinematic rather than pybullet dynamics: the controller only commands steering and speed,
closed-form integration is bit-for-bit deterministic across processes and workers, and it
costs microseconds, which matters for hundreds of rollouts per cell.
"""

from __future__ import annotations

import dataclasses
import math

from .config import VehicleConfig


@dataclasses.dataclass
class VehicleState:
    """Pose of the body centre (x, y, yaw counter-clockwise from +x), speed and road-wheel angle."""

    x: float
    y: float
    yaw: float
    speed: float
    steer_angle: float = 0.0


class KinematicBicycle:
    """Rear-axle bicycle model; the body centre sits wheelbase/2 ahead of the rear axle.

    ``steer`` in [-1, 1] maps to a road-wheel angle ``steer * max_steer``; positive steers
    left (counter-clockwise yaw, z up). Speed follows the command within accel/brake limits;
    the wheel angle follows the command with a first-order lag.
    """

    def __init__(self, config: VehicleConfig):
        self.config = config
        self.max_steer = math.radians(config.max_steer_deg)

    def rear_axle(self, state: VehicleState) -> tuple[float, float]:
        half = self.config.wheelbase / 2
        return state.x - half * math.cos(state.yaw), state.y - half * math.sin(state.yaw)

    def corners(self, state: VehicleState) -> list[tuple[float, float]]:
        """Footprint corners (front-left, front-right, rear-right, rear-left)."""
        c, s = math.cos(state.yaw), math.sin(state.yaw)
        hl, hw = self.config.length / 2, self.config.width / 2
        return [
            (state.x + c * u - s * v, state.y + s * u + c * v) for u, v in ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))
        ]

    def step(self, state: VehicleState, steer: float, speed: float, dt: float) -> VehicleState:
        cfg = self.config
        steer = min(1.0, max(-1.0, float(steer)))
        target_angle = steer * self.max_steer
        if cfg.steer_time_constant > 0:
            alpha = 1.0 - math.exp(-dt / cfg.steer_time_constant)
            angle = state.steer_angle + alpha * (target_angle - state.steer_angle)
        else:
            angle = target_angle
        target_speed = min(cfg.max_speed, max(0.0, float(speed)))
        dv = min(cfg.max_accel * dt, max(-cfg.max_brake * dt, target_speed - state.speed))
        v = state.speed + dv
        dist = 0.5 * (state.speed + v) * dt
        kappa = math.tan(angle) / cfg.wheelbase
        rx, ry = self.rear_axle(state)
        yaw = state.yaw
        dyaw = kappa * dist
        if abs(dyaw) > 1e-9:  # exact arc for constant curvature over the step
            rx += (math.sin(yaw + dyaw) - math.sin(yaw)) / kappa
            ry += (math.cos(yaw) - math.cos(yaw + dyaw)) / kappa
        else:
            rx += dist * math.cos(yaw)
            ry += dist * math.sin(yaw)
        yaw = math.atan2(math.sin(yaw + dyaw), math.cos(yaw + dyaw))
        half = cfg.wheelbase / 2
        return VehicleState(rx + half * math.cos(yaw), ry + half * math.sin(yaw), yaw, v, angle)
