"""MLflow helpers: one SQLite store at the project root, artefacts beside it, absolute URIs.

Every stage opens its run through `stage_run`, which logs the composed Hydra config
(flattened) as params, so any two runs can be compared column by column in the UI.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import mlflow
from hydra.experimental.callback import Callback
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig, OmegaConf

MAX_PARAM_CHARS = 6000  # MLflow's limit on one param value


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
    with mlflow.start_run(experiment_id=experiment_id, run_name=run_name, tags=dict(tags or {})) as run:
        mlflow.log_params(flatten(config))
        yield run


class CreateStoreCallback(Callback):
    """Hydra callback: create the store and the stage's experiment in the parent process, once,
    before a multirun's (possibly parallel) jobs start — see `ensure_experiment`."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        ensure_experiment(config.paths.root, config.hydra.job.name)
