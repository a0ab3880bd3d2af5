"""Safe sets: which closed-loop paths count as safe for η1 (the paper's Definition 1).

A path is judged from its logged positions and the environment's termination, so the same
test applies to any controller. One rule per scenario kind, and it is the one the figures draw:

- ``roundabout``: the car's body keeps to its lane (the right lane on the arms, the ring's lane
  on the ring) for the whole horizon and reaches the first exit. Judged on the body centre, the
  corridor is the lane's half-width less half the car's width (``half_width`` overrides it), so
  the corridor binds before the car's corners leave the pavement.
- ``obstacle``: no collision, never off the road, and the car either passes the obstacle or
  stops after a hand-over within the horizon. A run that times out before the obstacle has
  answered nothing: it is its own outcome (``goal`` not reached), never safe.
- ``straight``: no collision and never off the road.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uqdrive.sim import ScenarioGeometry

HANDOVER = "handover"  # termination of a run whose warning system braked to a stop and handed over


@dataclass(frozen=True)
class Verdict:
    """Outcome of one path. ``reached_goal``: the first exit (roundabout), past the obstacle (obstacle road),
    always True on a straight road. ``corridor_use``: max |lateral deviation| / corridor half-width (NaN
    where no corridor applies); above 1 the car left the corridor."""

    safe: bool
    collision: bool
    off_road: bool
    left_corridor: bool
    reached_goal: bool
    corridor_use: float


@dataclass(frozen=True)
class SafeSet:
    """A scenario's safe set: ``half_width`` per route point (None where only the road matters) and the
    progress along the route that counts as the goal (None: no goal)."""

    kind: str
    route_x: np.ndarray
    route_y: np.ndarray
    half_width: np.ndarray | None
    goal_progress: float | None

    def judge(self, geometry: ScenarioGeometry, x: np.ndarray, y: np.ndarray, termination: str) -> Verdict:
        """Verdict for a path of body-centre positions ``x``, ``y`` that ended with ``termination``."""
        collision, off_road = termination == "collision", termination == "off_road"
        s, lateral = geometry.route.project(np.stack([x, y], axis=1))
        reached = self.goal_progress is None or bool(s.max() >= self.goal_progress)
        if self.half_width is None:
            stopped = termination == HANDOVER
            return Verdict(not (collision or off_road) and (reached or stopped), collision, off_road, False,
                           reached, math.nan)
        use = float(np.max(np.abs(lateral) / np.interp(s, geometry.route.s, self.half_width)))
        left = use > 1.0
        return Verdict(not (collision or off_road or left) and reached, collision, off_road, left, reached, use)

    def boundaries(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Left and right corridor edges [N, 2] for figures (None for road-only safe sets)."""
        if self.half_width is None:
            return None
        heading = np.arctan2(np.gradient(self.route_y), np.gradient(self.route_x))
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        centre = np.stack([self.route_x, self.route_y], axis=1)
        return centre + normal * self.half_width[:, None], centre - normal * self.half_width[:, None]


def check_half_width(half_width: float | None, key: str = "safety.half_width") -> float | None:
    if half_width is None:
        return None
    if isinstance(half_width, bool) or not isinstance(half_width, (int, float)) or not (
            math.isfinite(half_width) and half_width > 0):
        raise ValueError(f"{key}={half_width!r} must be null (the lane less half the car) or a number of metres > 0")
    return float(half_width)


def lane_half_width(geometry: ScenarioGeometry) -> np.ndarray:
    """Half-width of the lane the route runs in, per route point: half the ring on the ring
    (the route follows its centre line), half a lane on the arms (the route is the right lane's centre)."""
    cfg = geometry.config
    cx, cy, _ = geometry.island
    r = np.hypot(geometry.route.x - cx, geometry.route.y - cy)
    return np.where(r <= cfg.ring_radius + cfg.ring_width / 2, cfg.ring_width / 2, cfg.lane_width / 2)


def obstacle_pass_progress(geometry: ScenarioGeometry, vehicle_length: float) -> float:
    """Metres along the route at which the car's centre is a full car length past the obstacle's centre."""
    obstacle = geometry.obstacles[0]
    s, _ = geometry.route.project(np.array([[obstacle.x, obstacle.y]]))
    return float(s[0]) + (obstacle.size[0] + vehicle_length) / 2


def safe_set_for(geometry: ScenarioGeometry, vehicle_width: float, vehicle_length: float,
                 half_width: float | None = None) -> SafeSet:
    """The safe set of ``geometry``'s scenario for a car of the given size; ``half_width`` (m) replaces the
    lane-less-half-the-car corridor at the roundabout."""
    half_width = check_half_width(half_width)
    route, cfg = geometry.route, geometry.config
    if cfg.kind == "obstacle":
        return SafeSet(cfg.kind, route.x, route.y, None, obstacle_pass_progress(geometry, vehicle_length))
    if cfg.kind != "roundabout":
        return SafeSet(cfg.kind, route.x, route.y, None, None)
    cx, cy, _ = geometry.island
    on_ring = np.flatnonzero(np.hypot(route.x - cx, route.y - cy) <= cfg.ring_radius + cfg.ring_width / 2)
    exit_progress = float(route.s[on_ring[-1]])  # where the route leaves the ring: the first exit
    if half_width is None:
        widths = lane_half_width(geometry) - vehicle_width / 2
        if widths.min() <= 0:
            raise ValueError(f"scenario {cfg.name!r}: a {vehicle_width} m wide car does not fit its lanes")
    else:
        widths = np.full(len(route.s), half_width)
    return SafeSet("roundabout", route.x, route.y, widths, exit_progress)
