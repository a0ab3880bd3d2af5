"""Safe sets: which closed-loop paths count as safe for η1 (the paper's Definition 1).

A path is judged from its logged positions and the environment's termination, so the same
test applies to any controller. One rule per scenario kind, and it is the one the figures draw:

- ``roundabout``: the car's body (its four corners, from the logged pose) keeps to its lane (the
  right lane on the arms, the ring's lane on the ring; ``half_width`` overrides the lane) for the
  whole horizon and reaches the first exit. The lane lies inside the pavement, so this rule binds
  before the environment's off-road check (a corner off the pavement) can: the rule that decides
  is the one the figures draw. (Judged on the body centre instead, a car turning too little left
  the pavement with its front corner while its centre was well inside the lane.)
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
class PathVerdict:
    """Outcome of one path. ``reached_goal``: the first exit (roundabout), past the obstacle (obstacle road),
    always True on a straight road. ``corridor_use``: the largest |lateral deviation| of a body corner over
    the lane half-width there (NaN where no lane rule applies); above 1 the car's body left its lane.
    ``margin``: how far inside the safe set the path stayed at its worst, in lane half-widths — the robustness of
    "always in the lane and eventually at the exit" (signal-temporal-logic style): min(1 − corridor_use, how far
    past the exit it got); ≥ 0 exactly when the path is safe (0 at the boundary). NaN where no lane rule applies."""

    safe: bool
    collision: bool
    off_road: bool
    left_corridor: bool
    reached_goal: bool
    corridor_use: float
    margin: float = math.nan


@dataclass(frozen=True)
class SafeSet:
    """A scenario's safe set for a car of ``car_size`` (length, width): ``half_width`` of the lane per route
    point (None where only the road matters) and the progress along the route that counts as the goal
    (None: no goal)."""

    kind: str
    route_x: np.ndarray
    route_y: np.ndarray
    half_width: np.ndarray | None
    goal_progress: float | None
    car_size: tuple[float, float]

    def judge(
        self, geometry: ScenarioGeometry, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, termination: str
    ) -> PathVerdict:
        """The verdict on a path of body-centre poses ``x``, ``y``, ``yaw`` that ended with ``termination``."""
        collision, off_road = termination == "collision", termination == "off_road"
        s, _ = geometry.route.project(np.stack([x, y], axis=1))
        reached = self.goal_progress is None or bool(s.max() >= self.goal_progress)
        if self.half_width is None:
            stopped = termination == HANDOVER
            return PathVerdict(
                not (collision or off_road) and (reached or stopped), collision, off_road, False, reached, math.nan
            )
        corners = body_corners(np.asarray(x), np.asarray(y), np.asarray(yaw), *self.car_size)
        corner_s, lateral = geometry.route.project(corners)
        use = float(np.max(np.abs(lateral) / np.interp(corner_s, geometry.route.s, self.half_width)))
        left = use > 1.0
        safe = not (collision or off_road or left) and reached
        return PathVerdict(safe, collision, off_road, left, reached, use, self._margin(geometry, s, use, safe))

    def first_exit(self, geometry: ScenarioGeometry, x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> int | None:
        """The first pose whose body leaves the lane (`judge`'s corridor rule), None if none does or no lane rule
        applies: where a failure record places a lane exit."""
        if self.half_width is None or len(x) == 0:
            return None
        corners = body_corners(np.asarray(x), np.asarray(y), np.asarray(yaw), *self.car_size)
        corner_s, lateral = geometry.route.project(corners)
        outside = (np.abs(lateral) / np.interp(corner_s, geometry.route.s, self.half_width)).reshape(4, -1) > 1.0
        poses = np.flatnonzero(outside.any(axis=0))
        return int(poses[0]) if len(poses) else None

    def time_to_boundary(
        self, geometry: ScenarioGeometry, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, speed: np.ndarray
    ) -> float:
        """The least time over a path's poses in which the car could reach its lane's edge at its speed there: min
        over the poses it moved at of (metres from its body's nearest corner to the edge) / speed, 0 once the body
        is out. A lower bound on the time to the edge (the car's speed towards it is at most its speed), so small
        means close to leaving; NaN where no lane rule applies (a road-only safe set) or the car never moved."""
        moving = np.asarray(speed, float) > 1e-6
        if self.half_width is None or not moving.any():
            return math.nan
        corners = body_corners(np.asarray(x), np.asarray(y), np.asarray(yaw), *self.car_size)
        corner_s, lateral = geometry.route.project(corners)
        room = (np.interp(corner_s, geometry.route.s, self.half_width) - np.abs(lateral)).reshape(4, -1).min(axis=0)
        return float(np.min(np.maximum(room[moving], 0.0) / np.asarray(speed, float)[moving]))

    def _margin(self, geometry: ScenarioGeometry, progress: np.ndarray, use: float, safe: bool) -> float:
        """min(1 − corridor_use, metres past the goal in lane half-widths), clipped to ≤ 0 for an unsafe path."""
        goal = math.inf
        if self.goal_progress is not None:
            half = float(np.interp(self.goal_progress, geometry.route.s, self.half_width))
            goal = (float(progress.max()) - self.goal_progress) / half
        margin = min(1.0 - use, goal)
        return margin if safe else min(margin, 0.0)

    def boundaries(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Left and right corridor edges [N, 2] for figures (None for road-only safe sets)."""
        if self.half_width is None:
            return None
        heading = np.arctan2(np.gradient(self.route_y), np.gradient(self.route_x))
        normal = np.stack([-np.sin(heading), np.cos(heading)], axis=1)
        centre = np.stack([self.route_x, self.route_y], axis=1)
        return centre + normal * self.half_width[:, None], centre - normal * self.half_width[:, None]


def body_corners(x: np.ndarray, y: np.ndarray, yaw: np.ndarray, length: float, width: float) -> np.ndarray:
    """The four footprint corners of every pose, [4 N, 2] (as the vehicle model's own ``corners``)."""
    c, s = np.cos(yaw), np.sin(yaw)
    out = [
        np.stack([x + c * u - s * v, y + s * u + c * v], axis=1)
        for u, v in (
            (length / 2, width / 2),
            (length / 2, -width / 2),
            (-length / 2, -width / 2),
            (-length / 2, width / 2),
        )
    ]
    return np.concatenate(out)


def obstacle_pass_progress(geometry: ScenarioGeometry, vehicle_length: float) -> float:
    """Metres along the route at which the car's centre is a full car length past the obstacle's centre."""
    return geometry.obstacle_passed(vehicle_length)


def safe_set_for(
    geometry: ScenarioGeometry, vehicle_width: float, vehicle_length: float, half_width: float | None = None
) -> SafeSet:
    """The safe set of ``geometry``'s scenario for a car of the given size: its corridor and goal as its kind has
    them (`ScenarioGeometry.corridor_half_widths`, `.goal_progress`); ``half_width`` (m) replaces the lane's
    half-width at the roundabout."""
    route, car = geometry.route, (float(vehicle_length), float(vehicle_width))
    widths, goal = geometry.corridor_half_widths(half_width), geometry.goal_progress(vehicle_length)
    return SafeSet(geometry.config.kind, route.x, route.y, widths, goal, car)
