"""Closed-loop rollouts at conditions of an envelope's space: a job (`uqdrive.parallel.Job`) whose rollout i
drives at condition i of its source with seed ``base_seed + i``.

Two sources: the conditions phase one chose (`Listed`), and uniform draws in a region (`UniformIn`), where
condition i comes from rollout i's seed alone, so rollout i has the same world and outcome in any process, in
any order, and when a rerun replays it from the cell's log.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import torch

from uqdrive.envelope.space import ConditionSpace, World
from uqdrive.safety.executors import PolicySpec, WorkerEnvs
from uqdrive.safety.rollout import RolloutResult, run_rollouts
from uqdrive.safety.safe_sets import SafeSet, safe_set_for
from uqdrive.sim import CameraConfig, ScenarioConfig, VehicleConfig, build_geometry

CONDITION_STREAM = 0xE17E  # the condition's own random stream of a rollout seed, apart from the episode's


@dataclasses.dataclass(frozen=True)
class Listed:
    """Rollout i at the i-th of these conditions (points of the unit cube)."""

    points: tuple[tuple[float, ...], ...]

    def point(self, index: int, seed: int) -> np.ndarray:
        return np.asarray(self.points[index], dtype=float)


@dataclasses.dataclass(frozen=True)
class UniformIn:
    """Rollout i at a condition drawn uniformly in the box [low, high) of the unit cube, from its seed."""

    low: tuple[float, ...]
    high: tuple[float, ...]

    def point(self, index: int, seed: int) -> np.ndarray:
        u = np.random.default_rng([CONDITION_STREAM, seed]).random(len(self.low))
        return np.asarray(self.low) + u * (np.asarray(self.high) - np.asarray(self.low))


@dataclasses.dataclass(frozen=True)
class ConditionJob:
    """Everything a worker needs to run rollout i of an envelope cell (a phase-one round or a region)."""

    policy: PolicySpec
    space: ConditionSpace
    source: Listed | UniformIn
    base_seed: int
    camera: CameraConfig = dataclasses.field(default_factory=CameraConfig)
    vehicle: VehicleConfig = dataclasses.field(default_factory=VehicleConfig)
    control_hz: float = 15.0
    horizon_s: float = 40.0
    half_width: float | None = None

    def point(self, index: int) -> np.ndarray:
        """Rollout ``index``'s condition in the unit cube."""
        return self.source.point(index, self.base_seed + index)

    def world(self, index: int) -> World:
        return self.space.world(self.point(index))

    def worker(self, width: int = 1) -> ConditionWorker:
        return ConditionWorker(self, width)


class ConditionWorker:
    """Up to ``width`` envs (`WorkerEnvs`) and one policy for all of a job's chunks, run in lockstep
    (`run_rollouts`), each rollout reset to its own world (one torch thread: the parallelism is across workers);
    the safe set is rebuilt only for a new location."""

    def __init__(self, job: ConditionJob, width: int = 1):
        self.slots = WorkerEnvs(job, width)
        torch.set_num_threads(1)
        self.job = job
        self.policy = job.policy.build(job.control_hz)
        self._scenario: ScenarioConfig | None = None
        self._safe_set: SafeSet | None = None

    def safe_set(self, scenario: ScenarioConfig) -> SafeSet:
        if self._safe_set is None or scenario != self._scenario:
            vehicle = self.job.vehicle
            self._safe_set = safe_set_for(build_geometry(scenario), vehicle.width, vehicle.length, self.job.half_width)
            self._scenario = scenario
        return self._safe_set

    def run(self, indices: Sequence[int]) -> list[RolloutResult]:
        """Rollouts ``indices`` (seeds base_seed + i, each at its condition), in that order."""
        job = self.job
        worlds = [job.world(i) for i in indices]
        first = worlds[0]
        one_location = all(w.scenario == first.scenario for w in worlds)
        return run_rollouts(
            self.slots.first(len(indices)),
            self.policy,
            [job.base_seed + i for i in indices],
            first.scenario,
            first.weather,
            first.noise,
            job.half_width,
            self.safe_set(first.scenario) if one_location else None,  # else judged on each rollout's own
            worlds=[(w.scenario, w.weather, w.noise) for w in worlds],
        )

    def close(self) -> None:
        self.slots.close()
