"""One pool of worker processes for everything the project runs many times over: autopilot episodes
(`collect`, `heldout`), training replicates (`train`) and closed-loop rollouts (`safety`, `avoid`); and its Ray
counterpart (`RayPool`: the same jobs on Ray actors, locally or on a cluster, with ``executor=ray``).

A *job* is a picklable recipe whose ``worker()`` builds the expensive per-process state once (a pybullet
client and its world, a policy); ``worker().run(item)`` does one item (an episode's index, or a chunk of
rollout indices run in lockstep), which carries its own seeds, so results are the same whatever the worker
count. A pool lives as long as its caller wants (a cell, or a whole
stage of many cells), so worker processes build their state once.
"""

from __future__ import annotations

import itertools
import multiprocessing
import socket
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Protocol

from uqdrive.schema import ConfigError

RAY_CONNECT_TIMEOUT_S = 10.0  # a cluster's head answers a TCP connect at once; this long, and it is not there
RAY_MISSING = "executor.name=ray needs Ray, which is not installed: pip install 'uqdrive[ray]' (Ray 2.60.0)"


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
_channel: Any = None  # where this process reports finished parts of an item: a queue to the pool's owner
_current: int | None = None  # the job key of the item this process runs


def report(done: int = 1) -> None:
    """``done`` more parts of the item this process runs have finished (a rollout of a chunk): the pool's owner
    hears it now, not when the whole item returns, so a progress bar moves per rollout. Costs one small pipe write."""
    if _channel is not None and _current is not None:
        _channel.put((_current, done))


def _set_channel(channel: Any) -> None:
    global _channel
    _channel = channel


def _run_keyed(keyed: tuple[int, Job, Any]) -> Any:
    """One item of a job on this process's worker for it. A process keeps the worker of the job it met
    last only: a pool's jobs come one after another (the cells of a sweep, the conditions of an avoid
    stage), so an earlier job's world is done with, and a stage of 36 cells does not hold 36 worlds per
    process. (A job met again is rebuilt; its items do not depend on the worker's history.)"""
    global _current
    key, job, item = keyed
    if key not in _keyed:
        for stale in list(_keyed):
            _keyed.pop(stale).close()
        _keyed[key] = job.worker()
    _current = key
    try:
        return _keyed[key].run(item)
    finally:
        _current = None


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
        self._keys: list[int] = []
        self._listeners: dict[int, Callable[[int], None]] = {}
        self._pool, self._reports, self._listener = None, None, None
        if workers > 1:
            context = _forkserver()
            self._reports = context.SimpleQueue()  # written by each worker's `report`, read by one thread here
            self._pool = ProcessPoolExecutor(
                workers, mp_context=context, initializer=_set_channel, initargs=(self._reports,)
            )
            self._listener = threading.Thread(target=self._listen, name="uqdrive-pool-reports", daemon=True)
            self._listener.start()

    def listen(self, key: int, callback: Callable[[int], None] | None) -> None:
        """``callback(done)`` on every `report` from job ``key``'s items (None: stop)."""
        if callback is None:
            self._listeners.pop(key, None)
        else:
            self._listeners[key] = callback

    def put(self, message: tuple[int, int] | None) -> None:
        """A report of an item run in this process (one worker: no queue between)."""
        self._dispatch(message)

    def _dispatch(self, message: tuple[int, int] | None) -> None:
        if message is not None and (callback := self._listeners.get(message[0])) is not None:
            callback(message[1])

    def _listen(self) -> None:
        while (message := self._reports.get()) is not None:
            self._dispatch(message)

    def executor(self, job: Job, owns_pool: bool = False) -> PooledExecutor:
        """The job's executor; with ``owns_pool`` closing it closes the pool too."""
        key = next(_job_keys)
        self._keys.append(key)
        return PooledExecutor(self, key, job, owns_pool)

    def run(self, key: int, job: Job, items: Sequence[Any]) -> Iterator[Any]:
        keyed = [(key, job, item) for item in items]
        if self._pool is not None:
            yield from self._pool.map(_run_keyed, keyed)
            return
        for one in keyed:  # in this process: its reports come straight here
            previous = _channel
            _set_channel(self)
            try:
                result = _run_keyed(one)
            finally:
                _set_channel(previous)
            yield result

    def release(self, key: int) -> None:
        """Close an in-process job's worker (worker processes drop theirs at the next job, or at close)."""
        if key in _keyed and self._pool is None:
            _keyed.pop(key).close()

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
            self._reports.put(None)  # ends the listener after every report before it
            self._listener.join(timeout=10)
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

    def on_report(self, callback: Callable[[int], None]) -> bool:
        """``callback(done)`` as the job's items report finished parts (`report`); True: reports will come."""
        self.pool.listen(self.key, callback)
        return True

    def close(self) -> None:
        self.pool.listen(self.key, None)
        self.pool.close() if self.owns_pool else self.pool.release(self.key)


class JobActor:
    """A Ray actor: one job's worker (its per-process state built once), for all the items it is given."""

    def __init__(self, job: Job):
        self.worker = job.worker()

    def run(self, item: Any) -> Any:
        return self.worker.run(item)

    def node(self) -> str:
        """The id of the Ray node this actor lives on."""
        import ray

        return ray.get_runtime_context().get_node_id()


class RayPool:
    """One Ray actor per worker, each a `JobActor` of ``job``; ``run(items)`` deals the items to them and yields the
    results in item order, whichever actor finishes first.

    ``address=None`` starts a private local Ray with ``workers`` CPUs (and shuts it down on close); otherwise joins
    that cluster ("auto": the one ``RAY_ADDRESS`` names). The actors read and write the project's files at the paths
    the job names: on a cluster, nodes that share the project folder. (Ray 2.60 has no ``local_mode`` any more.)
    """

    def __init__(self, job: Job, workers: int, address: str | None = None):
        try:
            import ray
            from ray.util import ActorPool
        except ImportError:
            raise ConfigError(RAY_MISSING) from None

        self._ray = ray
        self._started = not ray.is_initialized()
        if self._started:
            _check_reachable(address)
            try:
                ray.init(
                    address=address,
                    num_cpus=None if address else workers,
                    include_dashboard=False,
                    log_to_driver=False,
                    configure_logging=False,
                )
            except ConnectionError as err:  # what Ray raises for an address with no cluster behind it
                reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
                raise ConfigError(_unreachable(address, reason)) from None
        actor = ray.remote(num_cpus=1)(JobActor)
        self._actors = [actor.remote(job) for _ in range(workers)]
        self._pool = ActorPool(self._actors)

    def run(self, items: Sequence[Any]) -> Iterator[Any]:
        yield from self._pool.map(lambda a, item: a.run.remote(item), list(items))

    def nodes(self) -> list[str]:
        """The Ray node of each actor (a cluster spreads them over its nodes)."""
        return self._ray.get([a.node.remote() for a in self._actors])

    def close(self) -> None:
        for a in self._actors:
            self._ray.kill(a)
        self._actors = []
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()

    def __enter__(self) -> RayPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _check_reachable(address: str | None) -> None:
    """Fail in one line on a cluster address nothing listens at: Ray itself retries such an address for minutes."""
    if address in (None, "auto", "local"):  # a local Ray, or the one RAY_ADDRESS names (Ray fails fast if none)
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    try:
        socket.create_connection((host, int(port)), timeout=RAY_CONNECT_TIMEOUT_S).close()
    except (OSError, ValueError) as err:
        raise ConfigError(_unreachable(address, str(err) or type(err).__name__)) from None


def _unreachable(address: str | None, reason: str) -> str:
    return (
        f"executor.address={address!r}: no Ray cluster answers there ({reason}); start one (`ray start --head`) "
        "or set executor.address=null for a local Ray"
    )
