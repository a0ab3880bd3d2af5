"""One pool of worker processes for everything the project runs many times over: autopilot episodes
(`collect`, `heldout`) and closed-loop rollouts (`safety`, `avoid`).

A *job* is a picklable recipe whose ``worker()`` builds the expensive per-process state once (a pybullet
client and its world, a policy); ``worker().run(item)`` does one item (an episode's index, or a chunk of
rollout indices run in lockstep), which carries its own seeds, so results are the same whatever the worker
count. A pool lives as long as its caller wants (a cell, or a whole
stage of many cells), so worker processes build their state once.
"""

from __future__ import annotations

import itertools
import multiprocessing
from collections.abc import Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Protocol


class Worker(Protocol):
    def run(self, item: Any) -> Any:
        """One item of the job (an index, or a chunk of them)."""

    def close(self) -> None:
        """Release what the worker holds (its pybullet client)."""


class Job(Protocol):
    def worker(self) -> Worker:
        """Build the per-process state that runs this job's items."""


_keyed: dict[int, Worker] = {}  # this process's worker, by job key
_job_keys = itertools.count()  # unique in the process, so two pools never share a key


def _run_keyed(keyed: tuple[int, Job, Any]) -> Any:
    """One item of a job on this process's worker for it. A process keeps the worker of the job it met
    last only: a pool's jobs come one after another (the cells of a sweep, the conditions of an avoid
    stage), so an earlier job's world is done with, and a stage of 36 cells does not hold 36 worlds per
    process. (A job met again is rebuilt; its items do not depend on the worker's history.)"""
    key, job, item = keyed
    if key not in _keyed:
        for stale in list(_keyed):
            _keyed.pop(stale).close()
        _keyed[key] = job.worker()
    return _keyed[key].run(item)


PRELOAD = [
    "torch",
    "uqdrive.sim.bullet",  # pybullet, imported without its build-time banner (which would land in a progress bar)
    "uqdrive.safety.executors",
    "uqdrive.pipeline.collect_stage",
    "uqdrive.pipeline.train_stage",
]


def _forkserver() -> multiprocessing.context.ForkServerContext:
    """Workers forked from one server process that imported the heavy modules once (torch, pybullet, the
    project's workers): a new pool's processes start in milliseconds, where spawned ones paid ~5 s of imports
    each. The server imports nothing else of this process and holds no threads, so a fork of it is clean."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(PRELOAD)
    return context


class ProcessPool:
    """Worker processes kept for as long as the pool: each builds a job's worker when it meets the job,
    so the start-up (imports, model, world) is paid once per process and job, not once per item.
    ``executor(job)`` runs one job's items; with 1 worker everything runs in this process.
    """

    def __init__(self, workers: int):
        if workers < 1:
            raise ValueError(f"workers={workers!r} must be >= 1")
        self.workers = workers
        self._pool = None if workers == 1 else ProcessPoolExecutor(workers, mp_context=_forkserver())
        self._keys: list[int] = []

    def executor(self, job: Job, owns_pool: bool = False) -> PooledExecutor:
        """The job's executor; with ``owns_pool`` closing it closes the pool too."""
        key = next(_job_keys)
        self._keys.append(key)
        return PooledExecutor(self, key, job, owns_pool)

    def run(self, key: int, job: Job, items: Sequence[Any]) -> Iterator[Any]:
        keyed = [(key, job, item) for item in items]
        yield from map(_run_keyed, keyed) if self._pool is None else self._pool.map(_run_keyed, keyed)

    def release(self, key: int) -> None:
        """Close an in-process job's worker (worker processes drop theirs at the next job, or at close)."""
        if key in _keyed and self._pool is None:
            _keyed.pop(key).close()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        for key in self._keys:
            self.release(key)

    def __enter__(self) -> ProcessPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class PooledExecutor:
    """The items of one job on a `ProcessPool`, results in item order; closing it closes the pool only if it owns it."""

    def __init__(self, pool: ProcessPool, key: int, job: Job, owns_pool: bool = False):
        self.pool, self.key, self.job, self.owns_pool = pool, key, job, owns_pool

    def run(self, items: Sequence[Any]) -> Iterator[Any]:
        yield from self.pool.run(self.key, self.job, items)

    def close(self) -> None:
        self.pool.close() if self.owns_pool else self.pool.release(self.key)
