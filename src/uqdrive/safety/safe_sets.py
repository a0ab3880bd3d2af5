"""Safe sets: which closed-loop paths count as safe for η1 (the paper's Definition 1).

A path is judged from its logged positions and the environment's termination, so the same
test applies to any controller. ``roundabout``: the car keeps to a corridor around the
reference route (by default the lane it should be in: the right lane on the arms, the ring's
lane on the ring) for the whole horizon and reaches the first exit. ``straight`` and
``obstacle``: no collision and never off the road.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uqdrive.checks import ConfigError
from uqdrive.sim import ScenarioGeometry


@dataclass(frozen=True)
class Verdict:
    """Outcome of one path; ``left_corridor``/``reached_exit`` are False/True where they do not apply."""

    safe: bool
    collision: bool
    off_road: bool
    left_corridor: bool
    reached_exit: bool


@dataclass(frozen=True)
class SafeSet:
    """A scenario's safe set; ``half_width`` (per route point) is None where only the road matters."""

    kind: str
    route_x: np.ndarray
    route_y: np.ndarray
    half_width: np.ndarray | None
    exit_progress: float | None

    def judge(self, geometry: ScenarioGeometry, x: np.ndarray, y: np.ndarray, termination: str) -> Verdict:
        """Verdict for a path of body-centre positions ``x``, ``y`` that ended with ``termination``."""
        collision, off_road = termination == "collision", termination == "off_road"
        if self.half_width is None:
            return Verdict(not (collision or off_road), collision, off_road, False, True)
        s, lateral = geometry.route.project(np.stack([x, y], axis=1))
        allowed = np.interp(s, geometry.route.s, self.half_width)
        left = bool(np.any(np.abs(lateral) > allowed))
        reached = bool(s.max() >= self.exit_progress)
        return Verdict(not (collision or off_road or left) and reached, collision, off_road, left, reached)

    def boundaries(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Left and right corridor edges [N, 2] for figures (None for road-only safe sets)."""
        if self.half_width is None:
            return None
        heading = np.arctan2(np.gradient(self.route_y), np.gradient(self.route_x))
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        centre = np.stack([self.route_x, self.route_y], axis=1)
        return centre + normal * self.half_width[:, None], centre - normal * self.half_width[:, None]


def check_half_width(half_width: float | None) -> float | None:
    if half_width is None:
        return None
    if isinstance(half_width, bool) or not isinstance(half_width, (int, float)) or not (
            math.isfinite(half_width) and half_width > 0):
        raise ConfigError(f"safety.half_width={half_width!r} must be null (the lane boundaries) or a number of metres > 0")
    return float(half_width)


def lane_half_width(geometry: ScenarioGeometry) -> np.ndarray:
    """Half-width of the lane the route runs in, per route point: half the ring on the ring
    (the route follows its centre line), half a lane on the arms (the route is the right lane's centre)."""
    cfg = geometry.config
    cx, cy, _ = geometry.island
    r = np.hypot(geometry.route.x - cx, geometry.route.y - cy)
    return np.where(r <= cfg.ring_radius + cfg.ring_width / 2, cfg.ring_width / 2, cfg.lane_width / 2)


def safe_set_for(geometry: ScenarioGeometry, half_width: float | None = None) -> SafeSet:
    """The safe set of ``geometry``'s scenario; ``half_width`` (m) replaces the lane boundaries at the roundabout."""
    half_width = check_half_width(half_width)
    route = geometry.route
    if geometry.config.kind != "roundabout":
        return SafeSet(geometry.config.kind, route.x, route.y, None, None)
    cfg = geometry.config
    cx, cy, _ = geometry.island
    on_ring = np.flatnonzero(np.hypot(route.x - cx, route.y - cy) <= cfg.ring_radius + cfg.ring_width / 2)
    exit_progress = float(route.s[on_ring[-1]])  # where the route leaves the ring: the first exit
    widths = lane_half_width(geometry) if half_width is None else np.full(len(route.s), half_width)
    return SafeSet("roundabout", route.x, route.y, widths, exit_progress)
