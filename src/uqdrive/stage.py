"""What every stage's Hydra entry point does around its work (`stage_main`) and after it (`run_stage`), and how a grid
stage runs its cells in one process (`run_cells`).

A grid stage (`safety`: method × replicate × location × weather × noise; `heldout`: weather × noise) runs its cells
in one process, on one pool of workers: a process per cell paid the imports (≈ 10 s), the workers' start (≈ 5 s)
and DVC's bookkeeping per cell. Each cell's config is composed as the single-cell command composes it (`python
stages/safety.py model=M scenario=L weather=W noise=S`), so a cell has the same result, files and config hash
either way.
"""

from __future__ import annotations

import atexit
import ctypes
import difflib
import functools
import itertools
import os
import shutil
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, nullcontext
from pathlib import Path
from typing import Any, Protocol, TypeVar

from hydra import compose
from hydra.errors import HydraException
from omegaconf import DictConfig
from omegaconf.errors import OmegaConfBaseException
from tqdm import tqdm

from uqdrive.resolvers import register_resolvers
from uqdrive.schema import ConfigError, config_error, validate

StageResult = TypeVar("StageResult")


def stage_main(main: Callable[..., StageResult]) -> Callable[..., StageResult]:
    """Wrap a stage's Hydra task function; put it under ``@hydra.main`` (Hydra unwraps it to find the config).

    - Registers the config resolvers for each job: Hydra's joblib launcher hands every job in a worker
      process the launching process's resolver registry, which has none of ours.
    - A bad config value (a `ConfigError`, also one a resolver raised) prints ``error: <message>`` on
      stderr and exits with 2: one line, no traceback (Hydra prints one for any exception leaving the
      task function). Checks run before any output is opened, so such a run has written nothing, and the run
      folder Hydra made for it (`outputs/<date>/<time>`: its own config and log) is removed.
    """

    @functools.wraps(main)
    def run(*args, **kwargs) -> StageResult:
        global _task_started
        _task_started = True
        register_resolvers()
        try:
            return main(*args, **kwargs)
        except Exception as err:
            cause = config_error(err)
            if cause is None:
                raise
            print(f"error: {cause}", file=sys.stderr, flush=True)
            _remove_rejected_run_folder()
            raise SystemExit(2) from None

    return run


def _remove_rejected_run_folder() -> None:
    """Remove a single run's Hydra folder when it holds nothing but Hydra's own files (its config and job log),
    then its date folder and `outputs/` if they are left empty."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    if not HydraConfig.initialized() or HydraConfig.get().mode != RunMode.RUN:
        return
    folder = Path(HydraConfig.get().runtime.output_dir)
    if not folder.is_dir() or any(p.name != ".hydra" and p.suffix != ".log" for p in folder.iterdir()):
        return
    shutil.rmtree(folder, ignore_errors=True)
    for parent in (folder.parent, folder.parent.parent):
        if parent.name and parent.is_dir() and not any(parent.iterdir()):
            parent.rmdir()


_task_started = False  # set by `stage_main`: an error before it is Hydra's (composing the config from the overrides)


def run_stage(main: Callable[[], object], *register_schemas: Callable[[], None]) -> None:
    """Run a stage script's Hydra entry point, then end the process as Python would, less the interpreter's
    teardown: executors shut down and other threads joined, the atexit handlers run (logging, MLflow, Hydra's
    sweep parent run), output flushed, then `os._exit`. With torch, MLflow and pandas loaded, freeing every module
    at exit took 1.8 s (torch alone) to 3.8 s (the train stage's imports) a process, measured on a loaded
    machine: seconds per DVC stage that change nothing. An error leaves by its `SystemExit` (Hydra's, or
    `stage_main`'s) as before.

    An override Hydra cannot apply (a key no config has, a group option that does not exist, bad syntax) is a
    config error too: one line and exit code 2, as `stage_main` reports the stage's own checks."""
    for register in register_schemas:  # the defaults of the config groups this stage composes (ConfigStore)
        register()
    register_resolvers()  # also for what Hydra does before the task (`--cfg job --resolve`, `--help`)
    os.environ.setdefault("HYDRA_FULL_ERROR", "1")  # Hydra raises instead of printing its multi-line report
    try:
        main()
    except (HydraException, OmegaConfBaseException) as err:
        if _task_started:
            raise
        print(f"error: {unknown_key(err) or one_line(err)}", file=sys.stderr, flush=True)
        raise SystemExit(2) from None
    threading._shutdown()  # what the interpreter's exit does first (so does multiprocessing's): executors shut down
    atexit._run_exitfuncs()
    sys.stdout.flush()
    sys.stderr.flush()
    ctypes.CDLL(None).fflush(None)  # C libraries' buffered output (pybullet's), which os._exit would drop
    os._exit(0)


def unknown_key(err: BaseException | None) -> str | None:
    """An override of a key no config has (``safety.thet=0.1``) as the schema check words the ``+safety.thet=0.1``
    form: ``safety.thet: unknown key; did you mean 'theta'? known keys: …`` (None for any other error). OmegaConf's
    error behind Hydra's names the key and the section it is missing from."""
    from omegaconf import DictConfig

    while err is not None:
        parent, key = getattr(err, "parent_node", None), getattr(err, "key", None)
        if isinstance(parent, DictConfig) and isinstance(key, str) and key not in parent:
            known = [k for k in parent.keys() if k != "hydra"]
            close = difflib.get_close_matches(key, known, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            return f"{getattr(err, 'full_key', None) or key}: unknown key; {hint}known keys: {', '.join(known)}"
        err = err.__cause__
    return None


def one_line(err: BaseException) -> str:
    """Hydra's report of an override it could not apply, and its cause, as one line (OmegaConf's
    ``full_key``/``object_type`` lines dropped: the message names the key)."""
    parts = []
    while err is not None:
        text = str(err).split("Config search path:")[0]  # after the options of a group: where Hydra looked
        lines = [line.strip().rstrip(".") for line in text.splitlines()]
        parts += [line for line in lines if line and not line.startswith(("full_key:", "object_type", "Set the env"))]
        err = err.__cause__
    return "; ".join(dict.fromkeys(parts))


GridCell = Mapping[str, object]


class Shared(Protocol):
    """What a grid stage's cells share and the stage closes at its end (a worker pool, a cell runner)."""

    def close(self) -> None: ...


S = TypeVar("S", bound=Shared)


def grid(**axes: Sequence[object]) -> list[dict[str, object]]:
    """Every combination of the axes' values, the last axis varying fastest: grid(a=[1, 2], b=[3]) ==
    [{a: 1, b: 3}, {a: 2, b: 3}]."""
    return [dict(zip(axes, values)) for values in itertools.product(*axes.values())]


def cell_overrides(overrides: Sequence[str], cell: GridCell) -> list[str]:
    """A cell's overrides: the sweep's own (but those of the cell's keys and `sweep.*`), then the cell's."""

    def key(override: str) -> str:
        return override.split("=", 1)[0].lstrip("+~")

    kept = [o for o in overrides if key(o) not in cell and key(o).split(".")[0] != "sweep"]
    return [*kept, *(f"{key}={value}" for key, value in cell.items())]


def compose_cell(config_name: str, overrides: Sequence[str], cell: GridCell) -> DictConfig:
    try:
        return compose(config_name, cell_overrides(overrides, cell))
    except HydraException as err:  # e.g. a weather params.yaml names that conf/weather/ lacks
        reason = str(err).strip().splitlines()[0]
        raise ConfigError(f"sweep cell {' '.join(f'{k}={v}' for k, v in cell.items())}: {reason}") from err


def run_cells(
    config_name: str,
    overrides: Sequence[str],
    cells: Sequence[GridCell],
    schema: type,
    run: Callable[[DictConfig, S], StageResult],
    shared: S,
    progress: bool,
    around: Callable[[], AbstractContextManager[object]] = nullcontext,
    check: Callable[[Any], object] | None = None,
) -> Iterator[tuple[DictConfig, StageResult]]:
    """``run(config, shared)`` for each cell's config of ``config_name``; yields each config and result as the cell
    finishes. ``overrides``: the stage's command-line overrides, passed on to every cell. Every config is
    composed and checked against ``schema`` (and, as validated, by ``check``: e.g. that its model file loads)
    before the first cell runs, and only then is ``around`` entered (the cells' parent run: a rejected sweep opens
    nothing). ``shared`` is closed at the end (also on an error, or when
    the caller stops early).
    Needs an initialised Hydra (a `@hydra.main` job, or `initialize_config_dir`)."""
    from uqdrive.tracking import JOB_START_ENV  # here: a script's spawned workers import this module, not MLflow

    try:
        configs = [compose_cell(config_name, overrides, cell) for cell in cells]
        for config in configs:
            validated = validate(schema, config)
            if check is not None:
                check(validated)
        with around():
            for config in tqdm(configs, desc=f"{config_name} cells", unit="cell", disable=not progress):
                os.environ[JOB_START_ENV] = str(int(time.time() * 1000))  # the cell's MLflow run starts with it
                yield config, run(config, shared)
    finally:
        os.environ.pop(JOB_START_ENV, None)
        shared.close()
