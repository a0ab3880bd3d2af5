"""Where an avoid run's progress and distances are measured (`Course`): along uqdrive's obstacle road, or along a
Gymnasium run's own path, chosen by the condition's world (`CourseOf`, a visitor: no code asks which world it has)."""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar

import numpy as np

from uqdrive.safety.rollout import RolloutResult
from uqdrive.sim import ScenarioGeometry
from uqdrive.sim.config import GymWorldConfig


class Course(abc.ABC):
    """Where a run's progress and distances are measured: on uqdrive's obstacle road (`ObstacleRoad`), or, in a
    Gymnasium world, along the run's own path (`OwnPath`). ``fixed_hazard``: distances are to a hazard that stays
    put (the obstacle), so a hand-over has a distance to it."""

    label: ClassVar[str]  # what `distances` measures, for an axis
    fixed_hazard: ClassVar[bool]

    @abc.abstractmethod
    def progress(self, result: RolloutResult) -> np.ndarray:
        """Metres along the course at each pose of the run."""

    @abc.abstractmethod
    def hazard(self, end: float) -> float:
        """Metres along the course of what a distance is measured to, for a run that ended at ``end``."""

    @abc.abstractmethod
    def start_speed(self, cruise: float) -> float:
        """The speed a run starts at (m/s), for a controller that cruises at ``cruise``."""

    def obstacle_box(self) -> np.ndarray:
        """x, y, length, width of the obstacle (empty: none of ours to draw)."""
        return np.zeros(0)

    def road_box(self) -> np.ndarray:
        """x range of the road and its lane edges (y), for drawing the straight obstacle road (empty: none of ours)."""
        return np.zeros(0)


@dataclasses.dataclass(frozen=True)
class ObstacleRoad(Course):
    """uqdrive's obstacle road: progress along its route, distances to the obstacle."""

    geometry: ScenarioGeometry
    label: ClassVar[str] = "distance to the obstacle along the road (m)"
    fixed_hazard: ClassVar[bool] = True

    def progress(self, result: RolloutResult) -> np.ndarray:
        return self.geometry.route.project(np.stack([result.x, result.y], axis=1))[0]

    def hazard(self, end: float) -> float:
        return obstacle_progress(self.geometry)

    def start_speed(self, cruise: float) -> float:
        return self.geometry.config.start_speed

    def obstacle_box(self) -> np.ndarray:
        ob = self.geometry.obstacles[0]
        return np.array([ob.x, ob.y, ob.size[0], ob.size[1]])

    def road_box(self) -> np.ndarray:
        cfg = self.geometry.config
        return np.array([0.0, cfg.road_length, -cfg.lane_width, 0.0, cfg.lane_width * (cfg.num_lanes - 1)])


@dataclasses.dataclass(frozen=True)
class OwnPath(Course):
    """A Gymnasium world's run: metres driven along its own path, distances to where it ended."""

    label: ClassVar[str] = "metres driven before the run ended"
    fixed_hazard: ClassVar[bool] = False

    def progress(self, result: RolloutResult) -> np.ndarray:
        return np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(result.x), np.diff(result.y)))])

    def hazard(self, end: float) -> float:
        return end

    def start_speed(self, cruise: float) -> float:
        """The env's car is not ours: as if it started at cruise speed."""
        return cruise


class CourseOf:
    """The course of a condition's world (a `uqdrive.sim.world.WorldVisitor`)."""

    def road(self, geometry: ScenarioGeometry) -> Course:
        return ObstacleRoad(geometry)

    def gym(self, world: GymWorldConfig) -> Course:
        return OwnPath()


def progress_along(course: Course, result: RolloutResult) -> tuple[np.ndarray, float]:
    """Metres along the course at each decision frame, and where the run ended."""
    s = course.progress(result)
    return s[:-1], float(s[-1])


def obstacle_progress(geometry: ScenarioGeometry) -> float:
    s, _ = geometry.route.project(np.array([[geometry.obstacles[0].x, geometry.obstacles[0].y]]))
    return float(s[0])


def distances(result: RolloutResult, course: Course) -> np.ndarray:
    """Metres to the course's hazard at each decision frame (the obstacle, or where the run ended)."""
    s, end = progress_along(course, result)
    return course.hazard(end) - s
