"""Run many rollouts in parallel: the project's process pool (`uqdrive.parallel`, default) or Ray actors
(``executor=ray``).

Each worker owns one `DrivingEnv` (its own pybullet client) and one policy for its whole life;
a rollout is named only by its index i and uses seed ``base_seed + i``, and results come back
in index order, so η̂1 and every per-rollout outcome are the same whatever the backend and
worker count.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, Protocol

import torch

from uqdrive.data.binning import SteeringBins
from uqdrive.models.checkpoint import load_posterior
from uqdrive.parallel import ProcessPool
from uqdrive.safety.controller import AutopilotPolicy, ConstantPolicy, Controller, Policy
from uqdrive.safety.rollout import RolloutResult, run_rollout
from uqdrive.safety.safe_sets import SafeSet, safe_set_for
from uqdrive.safety.warnings import WarningConfig, WarningController
from uqdrive.schema import ConfigError
from uqdrive.sim import AutopilotConfig, CameraConfig, DrivingEnv, ScenarioConfig, VehicleConfig, WeatherConfig

BACKENDS = ("process", "ray")
POLICIES = ("bnn", "autopilot", "constant")


@dataclasses.dataclass(frozen=True)
class PolicySpec:
    """A picklable recipe for a policy, built once in each worker.

    kind: ``bnn`` (posterior from ``model_path``), ``autopilot`` or ``constant`` (``steer``).
    ``warnings``: a ``bnn`` policy with the warning system (its ``samples`` must be the warning
    config's Chernoff n).
    """

    kind: str
    speed: float
    model_path: str = ""
    method: str = ""
    bins: SteeringBins = dataclasses.field(default_factory=SteeringBins)
    samples: int = 1
    eps: float = 0.1
    steer: float = 0.0
    autopilot: AutopilotConfig = dataclasses.field(default_factory=AutopilotConfig)
    warnings: WarningConfig | None = None

    def __post_init__(self) -> None:
        if self.kind not in POLICIES:
            raise ValueError(f"policy kind {self.kind!r} is not known; choose one of {list(POLICIES)}")
        if self.warnings is not None and (self.kind != "bnn" or self.samples != self.warnings.samples):
            raise ValueError(
                f"a policy with warnings must be kind 'bnn' with samples={self.warnings.samples} "
                f"(chernoff_n of warning.theta, warning.gamma), got kind={self.kind!r}, "
                f"samples={self.samples}"
            )

    def build(self, control_hz: float) -> Policy:
        if self.kind == "bnn":
            posterior = load_posterior(Path(self.model_path), expected_method=self.method, expected_classes=self.bins)
            if self.warnings is not None:
                return WarningController(posterior, self.bins, self.warnings, self.eps, self.speed, control_hz)
            return Controller(posterior, self.bins, self.samples, self.eps, self.speed)
        if self.kind == "autopilot":
            return AutopilotPolicy(self.autopilot)
        return ConstantPolicy(self.steer, self.speed)


@dataclasses.dataclass(frozen=True)
class RolloutJob:
    """Everything a worker needs to run rollout i of a sweep cell."""

    policy: PolicySpec
    scenario: ScenarioConfig
    weather: WeatherConfig
    noise: float
    base_seed: int
    camera: CameraConfig = dataclasses.field(default_factory=CameraConfig)
    vehicle: VehicleConfig = dataclasses.field(default_factory=VehicleConfig)
    control_hz: float = 15.0
    horizon_s: float = 40.0
    half_width: float | None = None

    def worker(self) -> RolloutWorker:
        return RolloutWorker(self)


class RolloutWorker:
    """One env + one policy, reused for every rollout the worker runs (one torch thread: the
    parallelism is across workers, and a second intra-op thread only adds contention)."""

    def __init__(self, job: RolloutJob):
        torch.set_num_threads(1)
        self.job = job
        self.env = DrivingEnv(job.camera, job.vehicle, job.control_hz, job.horizon_s)
        self.policy = job.policy.build(job.control_hz)
        self.env.reset(job.base_seed, job.scenario, job.weather, job.noise, render=False)  # builds the world
        self.safe_set: SafeSet = safe_set_for(self.env.geometry, job.vehicle.width, job.vehicle.length, job.half_width)

    def run(self, index: int) -> RolloutResult:
        job = self.job
        seed = job.base_seed + index
        return run_rollout(self.env, self.policy, seed, job.scenario, job.weather, job.noise, safe_set=self.safe_set)

    def close(self) -> None:
        self.env.close()


class Executor(Protocol):
    def run(self, indices: Sequence[int]) -> Iterator[RolloutResult]:
        """Results of rollouts ``indices``, in that order."""

    def close(self) -> None:
        """Release workers."""


class RayExecutor:
    """One Ray actor per worker, each a `RolloutWorker`.

    ``address=None`` starts a private local Ray with ``workers`` CPUs (and shuts it down on
    close); otherwise joins that cluster. (Ray 2.60 has no ``local_mode`` any more.)
    """

    def __init__(self, job: RolloutJob, workers: int, address: str | None = None):
        try:
            import ray
            from ray.util import ActorPool
        except ImportError as err:
            raise ImportError("executor.name=ray needs Ray: pip install ray==2.60.0") from err

        self._ray = ray
        self._started = not ray.is_initialized()
        if self._started:
            ray.init(
                address=address,
                num_cpus=None if address else workers,
                include_dashboard=False,
                log_to_driver=False,
                configure_logging=False,
            )
        actor = ray.remote(num_cpus=1)(RolloutWorker)
        self._actors = [actor.remote(job) for _ in range(workers)]
        self._pool = ActorPool(self._actors)

    def run(self, indices: Sequence[int]) -> Iterator[RolloutResult]:
        yield from self._pool.map(lambda a, i: a.run.remote(i), list(indices))

    def close(self) -> None:
        for a in self._actors:
            self._ray.kill(a)
        self._actors = []
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()


def make_executor(
    backend: str, job: RolloutJob, workers: int, pool: ProcessPool | None = None, **options: Any
) -> Executor:
    """``process`` (default; on ``pool`` if given, else on a pool of its own) or ``ray``; ``options`` go to
    the Ray backend (address)."""
    if backend == "process":
        if options:
            raise ConfigError(f"executor options {sorted(options)} apply only to executor.name=ray")
        return (pool or ProcessPool(workers)).executor(job, owns_pool=pool is None)
    if backend == "ray":
        return RayExecutor(job, workers, **options)
    raise ConfigError(f"executor.name={backend!r} is not a known backend; choose one of {list(BACKENDS)}")
