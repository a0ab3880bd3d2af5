"""MLflow helpers: one SQLite store at the project root, artefacts beside it, absolute URIs.

Every stage opens its run through `stage_run`, which logs the composed Hydra config
(flattened) as params, so any two runs can be compared column by column in the UI.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import mlflow
from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig, OmegaConf

MAX_PARAM_CHARS = 6000  # MLflow's limit on one param value
PARENT_RUN_ENV = "UQDRIVE_MLFLOW_PARENT_RUN"  # "<experiment id>:<run id>" of the sweep's parent run


def store_uris(root: str | Path) -> tuple[str, str]:
    """(tracking URI, artefact root URI) for a project root; absolute so every process agrees."""
    root = Path(root).resolve()
    return f"sqlite:///{root / 'mlflow.db'}", (root / "mlartifacts").as_uri()


def flatten(config: Mapping[str, Any] | DictConfig, prefix: str = "") -> dict[str, str]:
    """Nested config → {"a.b.c": "value"}; lists stay one param so sweeps compare as one column."""
    if isinstance(config, DictConfig):
        config = OmegaConf.to_container(config, resolve=True)
    flat: dict[str, str] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(flatten(value, prefix=f"{name}."))
        else:
            flat[name] = str(value)[:MAX_PARAM_CHARS]
    return flat


def ensure_experiment(root: str | Path, name: str) -> str:
    """Create the store and the experiment if needed; returns the experiment id.

    Call this once in a parent process before parallel jobs start: concurrent first-time
    creation of the SQLite store races in its schema migration.
    """
    tracking_uri, artifact_root = store_uris(root)
    mlflow.set_tracking_uri(tracking_uri)
    client = MlflowClient(tracking_uri)
    experiment = client.get_experiment_by_name(name)
    if experiment is not None:
        return experiment.experiment_id
    return client.create_experiment(name, artifact_location=f"{artifact_root}/{name}")


@contextmanager
def stage_run(root: str | Path, stage: str, config: DictConfig | Mapping[str, Any],
              run_name: str | None = None, tags: Mapping[str, str] | None = None) -> Iterator[mlflow.ActiveRun]:
    """An MLflow run in experiment `stage` with the flattened config logged as params."""
    experiment_id = ensure_experiment(root, stage)
    tags = dict(tags or {})
    parent = os.environ.get(PARENT_RUN_ENV, "")
    if parent.startswith(f"{experiment_id}:"):  # a job of a sweep of this stage: nest it under the sweep's run
        tags.setdefault("mlflow.parentRunId", parent.split(":", 1)[1])
    with mlflow.start_run(experiment_id=experiment_id, run_name=run_name, tags=tags) as run:
        mlflow.log_params(flatten(config))
        yield run


class CreateStoreCallback(Callback):
    """Hydra callback: create the store and the stage's experiment in the parent process, once,
    before a multirun's (possibly parallel) jobs start — see `ensure_experiment`.

    With ``tracking.parent_run: true`` in the stage's config it also opens the sweep's parent
    run and hands its id to the jobs through the environment (`PARENT_RUN_ENV`, inherited by
    joblib's worker processes), so each job's run is its child.
    """

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        root = _project_root(config)
        experiment_id = ensure_experiment(root, config.hydra.job.name)
        if not OmegaConf.select(config, "tracking.parent_run", default=False):
            return
        client = MlflowClient(store_uris(root)[0])
        overrides = " ".join(config.hydra.overrides.task)
        run = client.create_run(experiment_id, run_name=f"sweep {config.hydra.job.name}",
                                tags={"uqdrive.sweep_dir": str(config.hydra.sweep.dir), "uqdrive.overrides": overrides})
        os.environ[PARENT_RUN_ENV] = f"{experiment_id}:{run.info.run_id}"

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        parent = os.environ.pop(PARENT_RUN_ENV, "")
        if parent:
            MlflowClient(store_uris(_project_root(config))[0]).set_terminated(parent.split(":", 1)[1])


def _project_root(config: DictConfig) -> str:
    """`paths.root`, which defaults to ${hydra:runtime.cwd}: outside a job (at multirun start and
    end) that resolver needs the Hydra config registered first."""
    if not HydraConfig.initialized():
        HydraConfig.instance().set_config(config)
    return str(config.paths.root)
