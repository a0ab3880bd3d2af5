"""Ordered parallel map over processes, each with its own long-lived state (e.g. a pybullet client).

Results come back in input order and every item carries its own seed, so the output is the
same whatever the worker count.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import Any, TypeVar

from uqdrive.checks import ConfigError

T = TypeVar("T")
R = TypeVar("R")


def map_ordered(
    fn: Callable[[T], R],
    items: Iterable[T],
    workers: int,
    initializer: Callable[..., None] | None = None,
    initargs: tuple[Any, ...] = (),
) -> Iterator[R]:
    """Like `map(fn, items)`; with workers > 1, runs in `spawn`ed processes set up by `initializer`.

    `fn` and `initializer` must be importable module-level functions. Lazily yields results
    in order, so a caller can stream them to disk and show progress.
    """
    if not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers={workers!r} must be an integer >= 1")
    if workers == 1:
        if initializer is not None:
            initializer(*initargs)
        yield from map(fn, items)
        return
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context, initializer=initializer, initargs=initargs) as pool:
        yield from pool.map(fn, items)
