"""The one cell runner of every closed-loop stage (the offline-safety sweep, collision avoidance, the operating
envelope): a cell's identity, its rollout log, the executor's lifetime and the progress bar.

A cell's identity hashes everything its rollouts depend on and nothing they do not (worker count, backend, output
paths): the model file's bytes, the job (world, policy, seeds), what consumes the outcomes (estimator or test), and
every source file a rollout runs, in one place (`cell_key`) — the runner's own import closure (executors, controllers,
the simulator, the estimators), the stage module that shapes the cell's result, and the modules loaded by name, which
no static import reaches: the posterior's (named by the model file), a Gymnasium world's env and hooks
(`world_modules`); a user's policy by its digest. uqdrive's modules count by their import closure, a user's package by
all of its sources. A cell that drives a Gymnasium world has that world's identity in place of its config
(`uqdrive.sim.gym_world.world_identity`: the config and the versions of the env's packages). Finished rollouts are
appended to the cell's log under that identity; a rerun replays them and simulates only the rest, and a log of another
identity is started afresh.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, Generic, TypeVar

from tqdm import tqdm

from uqdrive.deps import SRC, file_digest, files_digest, import_closure, user_sources
from uqdrive.models.checkpoint import read_checkpoint
from uqdrive.parallel import ProcessPool
from uqdrive.safety.cells import EstimatorSettings, OutcomeStream
from uqdrive.safety.executors import LOCKSTEP, RolloutJob, make_executor
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.rollout_log import RolloutLog
from uqdrive.sim.condition import Condition, source_conditions, source_identity
from uqdrive.uq import Estimate

Outcome = TypeVar("Outcome")
RUNNER = Path(__file__).resolve().relative_to(SRC)  # this module, inside the package folder


def code_digest(modules: Sequence[str] = (), src: Path | None = None) -> str:
    """sha256 of the project files a rollout runs: this module's import closure plus ``modules`` (dotted names)
    and theirs, read from ``src`` (the folder holding the package; default: the one this code runs from)."""
    src = src or SRC
    return files_digest(import_closure(src / RUNNER, modules, src), src)


def model_module(model_path: str | Path) -> str:
    """The module of the posterior class a model file names (`target`): code no static import reaches."""
    return str(read_checkpoint(model_path)["target"]).rpartition(".")[0]


def external(where: Any) -> list[Condition]:
    """The conditions of a job's source whose world is more than uqdrive's code and config (`Condition.external`)."""
    return [c for c in source_conditions(where) if c.external]


def where_identity(where: Any) -> Any:
    """A condition source as its identity sees it (`uqdrive.sim.condition.source_identity`)."""
    return source_identity(where)


def job_identity(job: Any) -> dict:
    """The job as plain data, less the model file's path (its bytes are hashed instead: a retrained model at the
        same path is a new cell, the same model elsewhere is not; a user's policy likewise: its ``NOT_IDENTITY`` fields
    are left out, its ``digest`` of bytes or source is in); where it drives a Gymnasium world, that world's
        identity (`where_identity`)."""
    fields = dict(job.__dict__)
    policy = getattr(job, "policy", None)
    if policy is not None and dataclasses.is_dataclass(policy):
        skip = {"model_path", *getattr(policy, "NOT_IDENTITY", ())}  # files by their bytes, not where they lie
        fields["policy"] = {k: v for k, v in policy.__dict__.items() if k not in skip}
    if external(fields.get("where")):
        fields["where"] = where_identity(fields["where"])
    return fields


def cell_key(job: Any, consumer: Mapping[str, Any], model_path: str | Path | None, stage_module: str) -> str:
    """The identity hash of a cell: model bytes, job, ``consumer`` (the estimator's or test's settings), and the code
    of every module its rollouts run — the runner's closure, the stage's, and the modules loaded by name (the
    posterior's, a Gymnasium world's env and hooks): uqdrive's files by their closure, a user package's by all its
    sources (`uqdrive.deps.user_sources`), so an edit anywhere in either is a new cell. A user's policy is in the
    job by its own digest (its class's package, the files its settings name)."""
    worlds = [module for where in external(getattr(job, "where", None)) for module in where.loaded_modules()]
    modules = [stage_module, *([model_module(model_path)] if model_path else []), *worlds]
    identity = {
        "model_sha256": file_digest(model_path) if model_path else None,
        "code": code_digest(modules),
        "user_code": user_sources(modules),
        "job": job_identity(job),
        "consumer": dict(consumer),
    }
    return hashlib.sha256(json.dumps(identity, sort_keys=True, default=str).encode()).hexdigest()[:16]


def estimate_key(job: RolloutJob, settings: EstimatorSettings, stage_module: str) -> str:
    """The identity hash of a cell that estimates η1 of a `RolloutJob` by ``settings``."""
    return cell_key(job, settings.__dict__, getattr(job.policy, "model_path", "") or None, stage_module)


@dataclasses.dataclass(frozen=True)
class CellRun(Generic[Outcome]):
    """A finished cell: what its consumer concluded, the rollouts it read in index order, wall time, identity.
    ``reused``: every rollout was replayed from the cell's log (nothing simulated); ``unread``: rollouts run ahead
    of the consumer that it never asked for (`OutcomeStream`)."""

    name: str
    key: str
    outcome: Outcome
    results: list[RolloutResult]
    seconds: float
    reused: bool
    unread: int = 0


class CellRunner:
    """Runs cells one after another on one backend; with the process backend, on one pool of workers for the
    runner's life (a stage's cells share it: the workers pay their imports once). A context manager."""

    def __init__(self, backend: str, workers: int, options: Mapping[str, Any] | None = None, progress: bool = True):
        self.backend, self.workers, self.options, self.progress = backend, workers, dict(options or {}), progress
        self.pool = ProcessPool(workers) if backend == "process" else None

    @property
    def batch(self) -> int:
        """Rollouts that fill every worker's lockstep slots once."""
        return self.workers * LOCKSTEP

    @classmethod
    def of(cls, executor: Any, progress: bool = True) -> CellRunner:
        """From a stage's validated `executor` section (name, workers, options())."""
        return cls(executor.name, executor.workers, executor.options(), progress)

    def run(
        self,
        name: str,
        job: Any,
        key: str,
        log_path: str | Path,
        base_seed: int,
        consume: Callable[[OutcomeStream], Outcome],
        total: int,
        reuse: Mapping[int, RolloutResult] | None = None,
        ahead: int = 0,
        floor: int = 0,
    ) -> CellRun[Outcome]:
        """``consume(draw)`` over the cell's rollouts (``draw(count)``: the next count outcomes, 0/1, in index
        order); ``total``: the most rollouts it may ask for (the progress bar's length, and the most run);
        ``ahead``: after the consumer's first look, run batches doubling up to that many (`OutcomeStream`); ``floor``:
        rollouts the cell runs whatever the consumer reads (a sample fixed in advance, for paired tests and
        replays): its results are the first max(read, floor), the consumer's conclusion only what it read."""
        executor = make_executor(self.backend, job, self.workers, self.pool, **self.options)
        bar = tqdm(total=total, desc=name, unit="rollout", disable=not self.progress, leave=False)
        live = self.progress and executor.on_report(bar.update)  # ticks per rollout as workers finish them

        def progress(fresh: Iterator[RolloutResult]) -> Iterator[RolloutResult]:
            for result in fresh:  # one bar over the cell, however many looks a sequential consumer takes
                if not live:
                    bar.update()
                yield result

        start = time.perf_counter()
        try:
            draws = OutcomeStream(
                executor, RolloutLog(log_path, key, base_seed), reuse, progress, ahead, max(total, floor)
            )
            bar.update(len(draws.kept))
            outcome = consume(draws)
            draws.run_to(floor)
        finally:
            bar.close()
            executor.close()
        seconds = time.perf_counter() - start
        results = draws.kept[: max(len(draws.results), floor)]
        unread = len(draws.kept) - len(results)
        return CellRun(name, key, outcome, results, seconds, reused=draws.fresh == 0, unread=unread)

    def estimate(
        self,
        name: str,
        job: RolloutJob,
        settings: EstimatorSettings,
        key: str,
        log_path: str | Path,
        reuse: Mapping[int, RolloutResult] | None = None,
        floor: int = 0,
    ) -> CellRun[Estimate]:
        """η̂1 of one cell of a `RolloutJob` by ``settings``' scheme (``key``: `estimate_key`). The cell runs ahead
        of the estimator (`OutcomeStream`), which matters for a sequential scheme: it looks every few rollouts, fewer
        than the workers' lockstep slots; the estimate reads the same outcomes in the same order (a fixed-n scheme
        asks for all of them at once, so nothing runs ahead of it). ``floor``: see `run`."""
        return self.run(
            name,
            job,
            key,
            log_path,
            settings.base_seed,
            settings.estimate,
            settings.planned_rollouts(),
            reuse,
            self.batch,
            floor,
        )

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()
            self.pool = None

    def __enter__(self) -> CellRunner:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
