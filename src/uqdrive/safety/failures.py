"""A cell's failing rollouts as typed records: what an engineer reads first, replays (`uqdrive replay`) and groups
into modes (`uqdrive.analysis.failure_modes`).

Each record says which rollout failed (index and seed), under which condition, how it ended (the termination and
the safe-set rule it broke), where (the step and pose of the failure and the route segment there), how badly (the
margin) and what the controller saw then (its warning tier, η2 and mutual information at that step, and whether any
warning fired before). The path's digest lets a replay prove it re-drove the very same path.
"""

from __future__ import annotations

import abc
import dataclasses
import hashlib
import math
from collections.abc import Callable, Sequence

import numpy as np

from uqdrive.records import record
from uqdrive.safety.executors import RolloutJob
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.safe_sets import SafeSet, safe_set_for
from uqdrive.sim import ScenarioGeometry
from uqdrive.sim.config import GymWorldConfig

NO_PLACE = "episode"  # a Gymnasium world has no route: its failures are placed by time (early, middle, late)


@record
class RolloutFailure:
    """One failing rollout (see the module docstring). ``step``: the control step at which it failed (its first
    lane exit, else where it ended); ``x``, ``y``: the pose there; ``progress``: metres along the route (None off a
    route); ``segment``: the part of the route (or of the episode) it failed in; ``cause``: the broken rule
    (collision, off road, left lane, short of the goal, handed over, unsafe in a Gymnasium world's predicate);
    ``warned``: a warning fired at or before that step; ``path_sha256``: digest of the path's poses."""

    index: int
    seed: int
    condition: str
    termination: str
    cause: str
    step: int
    steps: int
    x: float
    y: float
    progress: float | None
    segment: str
    margin: float | None
    warning: int
    warned: bool
    eta2: float | None
    mutual_information: float | None
    path_sha256: str


def path_digest(x: np.ndarray, y: np.ndarray) -> str:
    """sha256 of a path's poses as float64 bytes: equal exactly when the path is the same bit for bit."""
    poses = np.stack([np.asarray(x, np.float64), np.asarray(y, np.float64)], axis=1)
    return hashlib.sha256(np.ascontiguousarray(poses).tobytes()).hexdigest()


def failure_cause(result: RolloutResult) -> str:
    """The safe-set rule a failing rollout broke, the most severe first."""
    if result.verdict.collision:
        return "collision"
    if result.verdict.off_road:
        return "off road"
    if result.verdict.left_corridor:
        return "left lane" if not math.isnan(result.verdict.corridor_use) else "unsafe"
    if result.termination == "handover":
        return "handed over"
    return "short of the goal"


class FailurePlacer(abc.ABC):
    """Places a failure in its run: the pose it failed at and the part of the run there. ``route``: the reference
    route [N, 2] and ``edges``: the safe set's, that a picture of the failure draws (none in a Gymnasium world)."""

    route: np.ndarray = np.zeros((0, 2))
    edges: tuple[np.ndarray, ...] = ()

    def step(self, result: RolloutResult) -> int:
        """The pose index of the failure: where the run ended."""
        return max(len(result.x) - 1, 0)

    @abc.abstractmethod
    def place(self, result: RolloutResult, pose: int) -> tuple[float | None, str]:
        """Metres along the route at ``pose`` (None off a route) and the segment there."""


class RoadPlacer(FailurePlacer):
    """Places a failure on its road: the safe set's first lane exit, the route segment it lies in."""

    def __init__(self, geometry: ScenarioGeometry, safe_set: SafeSet):
        self.geometry, self.safe_set = geometry, safe_set
        self.segments = route_segments(geometry, safe_set)
        self.route = geometry.route.points
        self.edges = safe_set.boundaries() or ()

    def step(self, result: RolloutResult) -> int:
        """The body's first lane exit where it left its lane, else the last pose."""
        if result.verdict.left_corridor and len(result.yaw) == len(result.x):
            exit_pose = self.safe_set.first_exit(self.geometry, result.x, result.y, result.yaw)
            if exit_pose is not None:
                return exit_pose
        return super().step(result)

    def place(self, result: RolloutResult, pose: int) -> tuple[float | None, str]:
        s, _ = self.geometry.route.project(np.array([[result.x[pose], result.y[pose]]]))
        progress = float(s[0])
        name = next((name for name, start in reversed(self.segments) if progress >= start), self.segments[0][0])
        return round(progress, 3), name


class EpisodePlacer(FailurePlacer):
    """Places a failure of a Gymnasium world, which has no route of ours, by its step within ``horizon_steps``."""

    def __init__(self, horizon_steps: int):
        self.horizon_steps = max(1, horizon_steps)

    def place(self, result: RolloutResult, pose: int) -> tuple[float | None, str]:
        """No progress; a third of the horizon."""
        third = min(2, 3 * pose // self.horizon_steps)
        return None, f"{('early', 'middle', 'late')[third]} in the {NO_PLACE}"


def route_segments(geometry: ScenarioGeometry, safe_set: SafeSet | None) -> list[tuple[str, float]]:
    """The route's named parts as (name, start in metres), in order (`ScenarioGeometry.parts`: the roundabout's
    approach, ring and exit arm; the obstacle road before and past the obstacle, for the safe set's car; a straight
    road whole)."""
    return geometry.parts(None if safe_set is None else safe_set.car_size[0])


def failure_records(
    results: Sequence[RolloutResult],
    condition: Callable[[int], str],
    placer: Callable[[int], FailurePlacer],
    base_seed: int,
) -> list[RolloutFailure]:
    """The failing rollouts of ``results`` (rollout i has seed ``base_seed`` + i; ``condition(i)``: its label,
    ``placer(i)``: the placer of its road), worst margin first (a run with no margin, a Gymnasium world's, after
    those with one, by index)."""
    records = []
    for r in results:
        if not r.verdict.safe:
            index = r.seed - base_seed
            records.append(_record(r, index, condition(index), placer(index)))
    return sorted(records, key=lambda f: (f.margin is None, f.margin if f.margin is not None else 0.0, f.index))


def _record(result: RolloutResult, index: int, condition: str, placer: FailurePlacer) -> RolloutFailure:
    pose = placer.step(result)
    progress, segment = placer.place(result, pose)
    command = min(pose, result.steps - 1)  # the command decided at that pose (the last one past the end)
    warnings = np.asarray(result.warning)

    def at(values: np.ndarray) -> float | None:
        value = float(values[command]) if 0 <= command < len(values) else math.nan
        return None if math.isnan(value) else round(value, 6)

    return RolloutFailure(
        index=index,
        seed=int(result.seed),
        condition=condition,
        termination=result.termination,
        cause=failure_cause(result),
        step=int(pose),
        steps=int(result.steps),
        x=round(float(result.x[pose]), 4) if len(result.x) else math.nan,
        y=round(float(result.y[pose]), 4) if len(result.y) else math.nan,
        progress=progress,
        segment=segment,
        margin=None if math.isnan(result.verdict.margin) else round(float(result.verdict.margin), 6),
        warning=int(warnings[command]) if 0 <= command < len(warnings) else -1,
        warned=bool((warnings[: command + 1] >= 0).any()) if command >= 0 else False,
        eta2=at(result.eta2),
        mutual_information=at(result.mutual_information),
        path_sha256=path_digest(result.x, result.y),
    )


@dataclasses.dataclass(frozen=True)
class _PlacerOf:
    """The placer where a job's rollout drives (a `uqdrive.sim.world.WorldVisitor`): on its road, by the job's safe
    set; in a Gymnasium world, by its horizon."""

    job: RolloutJob

    def road(self, geometry: ScenarioGeometry) -> FailurePlacer:
        car, half_width = self.job.vehicle, self.job.half_width
        return RoadPlacer(geometry, safe_set_for(geometry, car.width, car.length, half_width))

    def gym(self, world: GymWorldConfig) -> FailurePlacer:
        return EpisodePlacer(world.horizon_steps)


def placer_for(job: RolloutJob, index: int = 0) -> FailurePlacer:
    """The placer of rollout ``index``'s failures, on the road and safe set it is judged by."""
    return job.condition(index).visit(_PlacerOf(job))


def job_failures(job: RolloutJob, results: Sequence[RolloutResult]) -> list[RolloutFailure]:
    """The failure records of a job's rollouts, each labelled with the condition it drove and placed on its road
    (a mixture's rollouts drive several)."""
    placers: dict[str, FailurePlacer] = {}

    def placer(index: int) -> FailurePlacer:
        where = job.condition(index)
        key = where.location
        if key not in placers:
            placers[key] = placer_for(job, index)
        return placers[key]

    return failure_records(results, lambda i: job.condition(i).label, placer, job.base_seed)
