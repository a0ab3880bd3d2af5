"""One collision-avoidance cell (condition × warnings mode): its rollouts, the warning levels and hand-over places
read off them, distances along the obstacle road, the traces the threshold calibration replays, a figure panel.

A Gymnasium world (`OwnPath`) has no road of ours and no fixed hazard: progress is metres driven along the run's
own path, a frame's distance is the metres left before the run ended (where an unsafe run crashed or left the
road), and no hand-over has a distance to an obstacle."""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar

import numpy as np

from uqdrive.avoid.results import Mode
from uqdrive.avoid.trace_replay import Traces
from uqdrive.policy.warnings import LEVELS, WarningRule
from uqdrive.safety.rollout import RolloutResult
from uqdrive.sim import ScenarioGeometry
from uqdrive.sim.config import GymWorldConfig
from uqdrive.uq import Estimate


@dataclasses.dataclass
class Cell:
    """A finished cell: its estimate, rollouts and the warning rule its warnings are raised or counted with.
    ``reused``: every rollout came from an earlier run's log of the same cell."""

    name: str
    condition: str
    mode: Mode
    rule: WarningRule
    estimate: Estimate
    results: list[RolloutResult]
    seconds: float
    reused: bool
    base_seed: int


def levels(cell: Cell, result: RolloutResult) -> np.ndarray:
    """Warning level per frame: as raised (warnings on) or as the cell's rule would have raised them on the same
    draws (off: read from the recorded η2 counts and MI stages)."""
    if not cell.mode.warnings_off:
        return result.warning
    return cell.rule.levels(result.eta2_counts, result.mi_stages)


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


def handed_over(cell: Cell) -> list[bool]:
    """Per run, whether the warnings handed control over (always False with warnings off)."""
    if cell.mode.warnings_off:
        return [False] * len(cell.results)
    handover_levels = [lv for lv, a in zip(LEVELS, cell.rule.config.actions) if a.handover]
    return [bool(np.isin(r.warning, handover_levels).any()) for r in cell.results]


def handover_distances(cell: Cell, course: Course) -> list[float]:
    """Distance to the obstacle at the first hand-over frame of each run that handed over (warnings on; none in a
    Gymnasium world: it has no obstacle)."""
    if cell.mode.warnings_off or not course.fixed_hazard:
        return []
    handover_levels = [lv for lv, a in zip(LEVELS, cell.rule.config.actions) if a.handover]
    out = []
    for r in cell.results:
        fired = np.flatnonzero(np.isin(r.warning, handover_levels))
        if fired.size:
            out.append(float(distances(r, course)[fired[0]]))
    return out


def traces_of(cells: list[Cell], geometries: dict[str, Course], first: int) -> Traces:
    """Rollouts 0 … ``first`` − 1 of the warnings-off ``cells`` as replay input (a number fixed in advance, so
    exact tests on them hold whatever a sequential scheme did next): each frame's recorded η2 counts at the rule's
    looks and MI stages; group g = the g-th cell's condition."""
    runs = []
    for g, cell in enumerate(cells):
        for r in cell.results[:first]:
            s, end = progress_along(geometries[cell.condition], r)
            runs.append((r.eta2_counts, r.mi_stages, s, end, r.safe, g))
    return Traces.from_runs(runs, cells[0].rule.looks)


def panel(cell: Cell, course: Course) -> dict:
    """One figure panel: the cell's paths coloured by mutual information on the road."""
    paths = [
        {"x": r.x[:-1], "y": r.y[:-1], "mi": r.mutual_information, "termination": r.termination} for r in cell.results
    ]
    return {
        "paths": paths,
        "obstacle": course.obstacle_box(),
        "road": course.road_box(),
        "title": f"η̂1 = {cell.estimate.value:.2f} [{cell.estimate.low:.2f}, {cell.estimate.high:.2f}]",
    }
