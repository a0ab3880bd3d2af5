"""The DVC stages that run a grid of cells (`safety`: method × location × weather × noise; `heldout`: weather ×
noise) in one process, on one pool of workers.

A process per cell (a DVC stage per cell, as before) paid the imports (≈ 10 s), the workers' start (≈ 5 s)
and DVC's own bookkeeping per cell: on the quick profile about as long as a safety cell's 19 rollouts, ≈ 11 of
`make repro`'s 43 minutes. Here they are paid once per stage. Each cell's config is composed as the single-cell
command composes it (`python stages/safety.py model=M scenario=L weather=W noise=S`), so a cell has the same
result, files and config hash either way.
"""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Protocol, TypeVar

from hydra import compose
from hydra.errors import HydraException
from omegaconf import DictConfig
from tqdm import tqdm

from uqdrive.schema import ConfigError, validate
from uqdrive.tracking import JOB_START_ENV

R = TypeVar("R")
Cell = Mapping[str, object]


class Shared(Protocol):
    """What a grid stage's cells share and the stage closes at its end (a worker pool, a cell runner)."""

    def close(self) -> None: ...


S = TypeVar("S", bound=Shared)


def grid(**axes: Sequence[object]) -> list[dict[str, object]]:
    """Every combination of the axes' values, the last axis varying fastest: grid(a=[1, 2], b=[3]) ==
    [{a: 1, b: 3}, {a: 2, b: 3}]."""
    return [dict(zip(axes, values)) for values in itertools.product(*axes.values())]


def cell_overrides(overrides: Sequence[str], cell: Cell) -> list[str]:
    """A cell's overrides: the sweep's own (but those of the cell's keys and `sweep.*`), then the cell's."""

    def key(override: str) -> str:
        return override.split("=", 1)[0].lstrip("+~")

    kept = [o for o in overrides if key(o) not in cell and key(o).split(".")[0] != "sweep"]
    return [*kept, *(f"{key}={value}" for key, value in cell.items())]


def compose_cell(config_name: str, overrides: Sequence[str], cell: Cell) -> DictConfig:
    try:
        return compose(config_name, cell_overrides(overrides, cell))
    except HydraException as err:  # e.g. a weather params.yaml names that conf/weather/ lacks
        reason = str(err).strip().splitlines()[0]
        raise ConfigError(f"sweep cell {' '.join(f'{k}={v}' for k, v in cell.items())}: {reason}") from err


def run_cells(
    config_name: str,
    overrides: Sequence[str],
    cells: Sequence[Cell],
    schema: type,
    run: Callable[[DictConfig, S], R],
    shared: S,
    progress: bool,
) -> Iterator[tuple[DictConfig, R]]:
    """``run(config, shared)`` for each cell's config of ``config_name``; yields each config and result as the cell
    finishes. ``overrides``: the stage's command-line overrides, passed on to every cell. Every config is
    composed and checked against ``schema`` before the first cell runs. ``shared`` is closed at the end (also on
    an error, or when the caller stops early).
    Needs an initialised Hydra (a `@hydra.main` job, or `initialize_config_dir`)."""
    try:
        configs = [compose_cell(config_name, overrides, cell) for cell in cells]
        for config in configs:
            validate(schema, config)
        for config in tqdm(configs, desc=f"{config_name} cells", unit="cell", disable=not progress):
            os.environ[JOB_START_ENV] = str(int(time.time() * 1000))  # the cell's MLflow run starts with it
            yield config, run(config, shared)
    finally:
        os.environ.pop(JOB_START_ENV, None)
        shared.close()
