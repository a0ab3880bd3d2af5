"""Run many rollouts in parallel: the project's process pool (`uqdrive.parallel`, default) or Ray actors
(``executor=ray``), each worker stepping several rollouts in lockstep.

Each worker owns up to ``lockstep`` worlds (`uqdrive.sim.world.World`: the pybullet world, each its own client, or
the Gymnasium world the job's conditions name, judged by `InfoSafeSet`) and one policy with a slot per world for its
whole life. A request's indices are dealt to the workers in chunks of consecutive
indices; a worker runs its chunk ``lockstep`` rollouts at a time, one batched network forward per control
step (`run_rollouts`). A rollout is named only by its index i and uses seed ``base_seed + i``, its draws
come from its own slot's generator and its frame features do not depend on the frames beside it, and
results come back in index order, so η̂1 and every per-rollout outcome are the same whatever the
backend, worker count and lockstep width.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator, Sequence
from typing import Any, Protocol

import torch

from uqdrive.parallel import ProcessPool, RayPool, report
from uqdrive.policy.interface import Command
from uqdrive.policy.recipes import PolicyRecipe
from uqdrive.policy.slots import in_lockstep
from uqdrive.safety.info_safe_set import AnySafeSet, SafeSetOf
from uqdrive.safety.rollout import RolloutResult, run_rollouts
from uqdrive.schema import ConfigError
from uqdrive.sim import CameraConfig, ScenarioConfig, VehicleConfig
from uqdrive.sim.condition import Condition, ConditionSource
from uqdrive.sim.config import GymWorldConfig
from uqdrive.sim.world import World

BACKENDS = ("process", "ray")
LOCKSTEP = 8
"""Rollouts a worker steps at once by default: the trunk's cost per frame at batch 8 is about half its cost
alone (`uqdrive bench rollout --lockstep`), and 8 envs per worker stay small (pybullet clients of one world)."""
CHUNK_WIDTHS = 4
"""A worker's chunk holds at most this many lockstep widths: enough rollouts that slots freed by short
rollouts refill, few enough that results come back (and are logged) every few seconds."""


@dataclasses.dataclass(frozen=True)
class RolloutJob:
    """Everything a worker needs to run rollout i of a cell: the policy (any `PolicyRecipe`), where rollout i
    drives (``where``: a `Condition`, a `Mixture` or an envelope's condition source, asked for rollout i's condition
    by its seed), its seed ``base_seed + i``, the car, camera and horizon."""

    policy: PolicyRecipe
    where: ConditionSource
    base_seed: int
    camera: CameraConfig = dataclasses.field(default_factory=CameraConfig)
    vehicle: VehicleConfig = dataclasses.field(default_factory=VehicleConfig)
    control_hz: float = 15.0
    horizon_s: float = 40.0
    half_width: float | None = None

    def condition(self, index: int) -> Condition:
        """Where rollout ``index`` drives."""
        return self.where.condition(index, self.base_seed + index)


def job_world(
    where: Condition,
    camera: CameraConfig,
    vehicle: VehicleConfig,
    control_hz: float,
    horizon_s: float,
    half_width: float | None = None,
) -> dict[str, Any]:
    """A `RolloutJob`'s car, camera, control rate, horizon and corridor where ``where`` drives, from a stage's
    settings (`uqdrive.sim.location.Location.drive`: the pybullet world's as given; a Gymnasium world's rate and
    horizon are its own, and it has no car, camera or corridor of ours)."""
    return where.place.drive(camera, vehicle, control_hz, horizon_s, half_width)


@dataclasses.dataclass(frozen=True)
class LockstepJob:
    """What a worker pool runs: chunks of ``job``'s rollout indices, ``width`` rollouts at a time."""

    job: RolloutJob
    width: int = 1

    def worker(self) -> RolloutWorker:
        return RolloutWorker(self.job, self.width)


_spare_envs: dict[str, list[World]] = {}
"""Envs a closed worker left in this process, by the settings they were built with (camera, car, control rate,
horizon; for Gymnasium worlds, that they are): the next job with the same settings takes them, since a sweep's cells
differ in weather, noise and location, each a reset away (a new location rebuilds the world on the same pybullet
client, or remakes the Gymnasium env). A stage of many cells so builds each env once per process instead of once per
cell (≈ 0.15 s each); only the last settings' envs are kept."""


def job_env(job: Any, index: int = 0) -> World:
    """A new world for ``job``'s rollout ``index``, with the job's camera, car, control rate and horizon (a
    Gymnasium world's own: `Condition.make_world`)."""
    return job.condition(index).make_world(job.camera, job.vehicle, job.control_hz, job.horizon_s)


class WorkerEnvs:
    """A worker's envs for its whole life, at most ``width``: taken from the process's spares (`_spare_envs`), built
    as a chunk first needs them (a worker given 2 rollouts builds 2 worlds, not ``width``), left to the next job of
    the process at close. An env's state is set by each rollout's reset alone, so where it came from changes no
    result. A job's envs are the worlds its first rollout drives in (`Condition.make_world`)."""

    def __init__(self, job: Any, width: int):
        if width < 1:
            raise ValueError(f"lockstep width={width!r} must be >= 1")
        self.job, self.width = job, width
        self.key = job.condition(0).world_key(job.camera, job.vehicle, job.control_hz, job.horizon_s)
        self.envs: list[World] = _spare_envs.pop(self.key, [])

    def first(self, count: int) -> list[World]:
        """The first ``count`` envs (at most ``width``), built where missing."""
        count, job = min(count, self.width), self.job
        while len(self.envs) < count:
            self.envs.append(job_env(job))
        return self.envs[:count]

    def close(self) -> None:
        """Leave the envs to the next job of this process (closing those an earlier one left)."""
        for spare in _spare_envs.values():
            for env in spare:
                env.close()
        _spare_envs.clear()
        _spare_envs[self.key], self.envs = self.envs, []


class RolloutWorker:
    """Up to ``width`` envs (`WorkerEnvs`) and one policy, reused for every chunk the worker runs, each rollout reset
    to its own condition (one torch thread: the parallelism is across workers, and a second intra-op thread only
    adds contention). The safe set is rebuilt only for a new location (a Gymnasium world's: its `InfoSafeSet`)."""

    def __init__(self, job: RolloutJob, width: int = 1):
        self.slots = WorkerEnvs(job, width)
        torch.set_num_threads(1)
        self.job = job
        self.policy = in_lockstep(job.policy.build(job.control_hz))  # its slots kept from chunk to chunk
        self._scenario: ScenarioConfig | GymWorldConfig | None = None
        self._safe_set: AnySafeSet | None = None

    def safe_set(self, where: Condition) -> AnySafeSet:
        """The safe set of ``where``'s location, for the job's car and corridor."""
        if self._safe_set is None or where.scenario != self._scenario:
            vehicle = self.job.vehicle
            self._safe_set = where.visit(SafeSetOf((vehicle.length, vehicle.width), self.job.half_width))
            self._scenario = where.scenario
        return self._safe_set

    def run(self, indices: Sequence[int]) -> list[RolloutResult]:
        """Rollouts ``indices`` (seeds base_seed + i, each at its condition), in that order."""
        job = self.job
        conditions = [job.condition(i) for i in indices]
        first = conditions[0].scenario
        one_location = all(c.scenario == first for c in conditions)
        return run_rollouts(
            self.slots.first(len(indices)),
            self.policy,
            [job.base_seed + i for i in indices],
            conditions,
            job.half_width,
            self.safe_set(conditions[0]) if one_location else None,  # else judged on each rollout's own
            report,  # the bar moves per rollout, not per chunk
        )

    def close(self) -> None:
        self.slots.close()


def probe_policy(job: RolloutJob) -> Command:
    """Build the job's policy here, decide rollout 0's first frame in the job's own kind of world and step it once,
    so that a policy that cannot be made or answers in the wrong shape, space or range, or a world that does not
    report what its safe set reads at its first step, fails in one line before any rollout; the frame's command
    (what it gives: its draws, for one)."""
    policy = in_lockstep(job.policy.build(job.control_hz))
    where, envs = job.condition(0), WorkerEnvs(job, 1)
    try:
        (env,) = envs.first(1)
        frame = env.reset(job.base_seed, where, render=policy.needs_camera)
        policy.reset(job.base_seed, slot=0, world=env)
        command = policy.act(frame, env.last_info)
        if not env.done:
            env.apply(command)  # the world takes it (an action outside its space fails here) and reports its first step
        return command
    finally:
        envs.close()  # the env is left to the next job of this process (an in-process worker's)


def lockstep_chunks(indices: Sequence[int], workers: int, width: int) -> list[tuple[int, ...]]:
    """``indices`` cut into consecutive chunks: one per worker when they are few (4 rollouts on 2 workers: 2 each),
    at most `CHUNK_WIDTHS` lockstep widths each when they are many."""
    size = max(1, min(CHUNK_WIDTHS * width, math.ceil(len(indices) / workers)))
    return [tuple(indices[i : i + size]) for i in range(0, len(indices), size)]


class ChunkRunner(Protocol):
    def run(self, items: Sequence[tuple[int, ...]]) -> Iterator[list[RolloutResult]]:
        """Each chunk's results, chunk by chunk in order."""

    def close(self) -> None:
        """Release workers."""


class LockstepExecutor:
    """Deals each request's indices to ``runner``'s workers in chunks and yields the results in index order."""

    def __init__(self, runner: ChunkRunner, workers: int, width: int):
        self.runner, self.workers, self.width = runner, workers, width

    def run(self, indices: Sequence[int]) -> Iterator[RolloutResult]:
        for results in self.runner.run(lockstep_chunks(list(indices), self.workers, self.width)):
            yield from results

    def on_report(self, callback: Callable[[int], None]) -> bool:
        """``callback(done)`` as rollouts end in the workers; False where the runner cannot say (Ray: per chunk)."""
        listen = getattr(self.runner, "on_report", None)
        return bool(listen and listen(callback))

    def close(self) -> None:
        self.runner.close()


class Executor(Protocol):
    def run(self, indices: Sequence[int]) -> Iterator[RolloutResult]:
        """Results of rollouts ``indices``, in that order."""

    def on_report(self, callback: Callable[[int], None]) -> bool:
        """Call ``callback(done)`` as rollouts end; True if it will be called."""

    def close(self) -> None:
        """Release workers."""


def make_executor(
    backend: str,
    job: RolloutJob,
    workers: int,
    pool: ProcessPool | None = None,
    *,
    lockstep: int = LOCKSTEP,
    **options: Any,
) -> Executor:
    """``process`` (default; on ``pool`` if given, else on a pool of its own) or ``ray``; each worker steps up to
    ``lockstep`` rollouts at once (results do not depend on it); other ``options`` go to the Ray backend (address).
    """
    if isinstance(lockstep, bool) or not isinstance(lockstep, int) or lockstep < 1:
        raise ConfigError(f"executor.lockstep={lockstep!r}: must be an integer >= 1 (rollouts a worker steps at once)")
    if backend == "process":
        if options:
            raise ConfigError(f"executor options {sorted(options)} apply only to executor.name=ray")
        runner = (pool or ProcessPool(workers)).executor(LockstepJob(job, lockstep), owns_pool=pool is None)
        return LockstepExecutor(runner, (pool.workers if pool else workers), lockstep)
    if backend == "ray":
        return LockstepExecutor(RayPool(LockstepJob(job, lockstep), workers, **options), workers, lockstep)
    raise ConfigError(f"executor.name={backend!r} is not a known backend; choose one of {list(BACKENDS)}")
