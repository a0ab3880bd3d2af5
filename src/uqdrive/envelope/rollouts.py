"""Closed-loop rollouts at conditions of an envelope's space: a job (`uqdrive.parallel.Job`) whose rollout i
drives at condition i of its source with seed ``base_seed + i``.

Two sources: the conditions phase one chose (`Listed`), and uniform draws in a region (`UniformIn`), where
condition i comes from rollout i's seed alone, so rollout i has the same world and outcome in any process, in
any order, and when a rerun replays it from the cell's log.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from uqdrive.envelope.space import ConditionSpace, World
from uqdrive.safety.executors import PolicySpec
from uqdrive.safety.rollout import RolloutResult, run_rollout
from uqdrive.safety.safe_sets import SafeSet, safe_set_for
from uqdrive.sim import CameraConfig, DrivingEnv, VehicleConfig, build_geometry

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

    def worker(self) -> ConditionWorker:
        return ConditionWorker(self)


class ConditionWorker:
    """One env and one policy for all of a job's rollouts (one torch thread: the parallelism is across
    workers); the safe set is rebuilt only when a rollout's location differs from the last one's."""

    def __init__(self, job: ConditionJob):
        torch.set_num_threads(1)
        self.job = job
        self.env = DrivingEnv(job.camera, job.vehicle, job.control_hz, job.horizon_s)
        self.policy = job.policy.build(job.control_hz)
        self._scenario = None
        self._safe_set: SafeSet | None = None

    def run(self, index: int) -> RolloutResult:
        job = self.job
        world = job.world(index)
        if world.scenario != self._scenario:
            geometry = build_geometry(world.scenario)
            self._safe_set = safe_set_for(geometry, job.vehicle.width, job.vehicle.length, job.half_width)
            self._scenario = world.scenario
        seed = job.base_seed + index
        return run_rollout(
            self.env, self.policy, seed, world.scenario, world.weather, world.noise, safe_set=self._safe_set
        )

    def close(self) -> None:
        self.env.close()
