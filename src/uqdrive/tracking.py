"""MLflow helpers: one SQLite store at the project root, artefacts beside it, absolute URIs.

What the records must get right:
- the store is created (its schema migrated) under a file lock, by whichever process comes first;
  two processes migrating one new SQLite file at once corrupt it;
- the artefacts follow the project: MLflow writes absolute artefact URIs into the store (it resolves a relative
  one when it makes an experiment or run), so whoever opens the store of a copied, cloned or moved project folder
  first rewrites the old folder's prefix to this one's (`open_store`), rather than reading the original's files;
- experiments are named `<prefix>/<stage>` (`experiment_name`); every run says where it came from: the git
  commit, the DVC experiment (`dvc exp run` sets DVC_EXP_NAME), pipeline or ad hoc (`provenance_tags`);
- artefacts keep one file name across cells (`log_artifact_as`), so MLflow's Compare view lines them up;
- a stage writes its outputs first and logs them after (`stage_run`): a logging failure warns and
  never loses a result;
- a run's start time is its job's (Hydra's job start), so durations are true;
- params are the stage's own config section and the keys runs are compared by, not every key;
- a sweep's parent run ends FINISHED, FAILED or KILLED, never stays RUNNING.
"""

from __future__ import annotations

import atexit
import dataclasses
import functools
import math
import os
import shutil
import signal
import sqlite3
import subprocess
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import closing, contextmanager, suppress
from pathlib import Path
from typing import Any

import mlflow
from filelock import FileLock
from filelock import Timeout as LockTimeout
from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from mlflow.exceptions import MlflowException
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig, OmegaConf
from sqlalchemy.exc import SQLAlchemyError

from uqdrive.runs_view import metric_names, runs_link, view_tag

MAX_PARAM_CHARS = 6000  # MLflow's limit on one param value
LOCK_TIMEOUT_S = 600.0  # a migration takes seconds; a lock held this long is a stuck process
INTERRUPT_GRACE_S = 20.0  # after Ctrl-C or SIGTERM, clean-up time before the signal's default action ends a sweep
PREFIX_ENV = "UQDRIVE_MLFLOW_PREFIX"  # experiments' prefix when the config's tracking.experiment_prefix is null
DEFAULT_PREFIX = "uqdrive"
DVC_EXPERIMENT_ENV = "DVC_EXP_NAME"  # set by `dvc exp run` (https://dvc.org/doc/user-guide/env)
ORIGIN_TAG = "uqdrive.origin"  # pipeline: a `dvc repro`/`dvc exp run` stage (outputs=pipeline); adhoc: any other run
ADHOC_NAME_PREFIX = "adhoc · "  # an ad-hoc run's name starts with it, so the runs table tells the two apart
PARENT_RUN_ENV = "UQDRIVE_MLFLOW_PARENT_RUN"  # "<experiment id>:<run id>" of the sweep's parent run
JOB_START_ENV = "UQDRIVE_JOB_START_MS"  # set at Hydra's job start: the run's start time
# The keys runs are compared by, logged under these short names (config key, or the first present of several;
# ``{stage}`` for the stage's own section; absent keys are skipped), each once: a section key logged here is not
# logged again under its full name.
COMPARED_BY = {
    "method": "model.name",
    "experiment": "experiment.name",
    "weather": "weather.name",
    "noise": "noise",
    "location": ("gym_world.name", "scenario.name"),  # a Gymnasium world's name, else the pybullet scenario's
    "profile": "profile_name",
    "replicate": "seed",  # the training seed
    "cell_scheme": "{stage}.scheme",  # how each cell estimates η1 ...
    "cell_theta": "{stage}.theta",  # ... and its precision
    "family_gamma": "{stage}.gamma",  # the γ a family-wise sweep splits (each cell's own: cell_gamma, its record's)
}
VIEW_PARAMS = ("method", "location", "weather", "noise", "replicate")  # the runs table's param columns
RENAMED = {"{stage}.draws.": "frame_draws."}  # the posterior draws per frame: apart from the cell's θ and γ
SECTIONS = {"train": ("train", "model", "arch")}  # a stage's own config sections, when not just its name
# The numbers each experiment is judged by (metrics of these short names), at a fixed precision. MLflow 3.17's runs
# table shows no metric column until a user picks one (its default columns are Created, Dataset, Duration, …), so
# the run's name carries them, after what tells sibling runs apart (the Run Name column shows about 20 characters:
# the condition first), and the experiment's shared view (`runs_view`) shows them as columns. A run missing one of a
# form's metrics keeps its name.
KEY_METRICS = {
    "safety": "η1={eta1:.2f} [{eta1_low:.2f}, {eta1_high:.2f}]",
    "avoid": "η1={eta1:.2f} [{eta1_low:.2f}, {eta1_high:.2f}]",
    "train": "acc={val_accuracy:.3f}",
    "collect": "complete={route_complete_fraction:.2f}",
    "preprocess": "frames={train_frames:.0f}",
    "certify": "η1 in [{eta1_low:.2f}, {eta1_high:.2f}] n={rollouts:.0f}",
}
# Where the block's logging calls go when the store could not be opened: nowhere (every call fails and is
# skipped), rather than a fresh store made outside the lock.
DEFAULT_EXPERIMENT_ID = "0"
UNTRACKED_URI = "file:///dev/null/uqdrive-untracked"
# MLflow 3's UI opens an experiment of no declared kind on its GenAI traces page (empty here): ours are model runs.
EXPERIMENT_KIND = {"mlflow.experimentKind": "custom_model_development"}
LOGGING_ERRORS = (MlflowException, SQLAlchemyError, sqlite3.Error, OSError, LockTimeout)
ARTEFACTS = "mlartifacts"  # the artefact folder, beside mlflow.db
NOTE_TAG = "mlflow.note.content"  # the run page's Description
CERTIFIED_ALIAS = "certified"  # the registered model's alias on the last version `uqdrive certify` certified


def numeric_metrics(values: Mapping[str, Any]) -> dict[str, float]:
    """The entries MLflow can log as metrics: finite-or-inf numbers (not flags, not NaN), as floats."""
    return {
        k: float(v)
        for k, v in values.items()
        if isinstance(v, (int, float)) and not isinstance(v, bool) and not math.isnan(v)
    }


def store_uris(root: str | Path) -> tuple[str, str]:
    """(tracking URI, artefact root URI) for a project root; absolute so every process agrees."""
    root = Path(root).resolve()
    return f"sqlite:///{root / 'mlflow.db'}", (root / ARTEFACTS).as_uri()


def store_lock(root: str | Path) -> FileLock:
    """The lock every process holds while it first opens (and so may create) the store."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    return FileLock(str(root / "mlflow.db.lock"), timeout=LOCK_TIMEOUT_S)


def experiment_name(stage: str, config: DictConfig | Mapping[str, Any] | None = None) -> str:
    """`<prefix>/<stage>`: the prefix is the config's ``tracking.experiment_prefix``, else $UQDRIVE_MLFLOW_PREFIX,
    else `uqdrive`, so two projects (or studies) sharing one MLflow server keep apart."""
    configured = _select(config, "tracking.experiment_prefix")
    return f"{configured or os.environ.get(PREFIX_ENV) or DEFAULT_PREFIX}/{stage}"


def _select(config: DictConfig | Mapping[str, Any] | None, key: str) -> Any:
    if config is None:
        return None
    config = config if isinstance(config, DictConfig) else OmegaConf.create(dict(config))
    return OmegaConf.select(config, key, default=None)


def open_store(root: str | Path) -> MlflowClient:
    """The project's store, created (schema migrated) if new and its artefact URIs moved to this folder if the
    project was copied, cloned or moved; call it holding `store_lock`."""
    client = MlflowClient(store_uris(root)[0])  # opening a new store migrates its schema
    client.search_experiments(max_results=1)
    _drop_empty_default(client)
    _follow_moved_project(root)
    return client


def _drop_empty_default(client: MlflowClient) -> None:
    """Delete the experiment `Default` (id 0) MLflow makes in every new store while it holds no run: no run of ours
    goes there, and the UI would list it first, empty."""
    with suppress(*LOGGING_ERRORS):
        default = client.get_experiment(DEFAULT_EXPERIMENT_ID)
        if default.lifecycle_stage == "active" and not client.search_runs([default.experiment_id], max_results=1):
            client.delete_experiment(DEFAULT_EXPERIMENT_ID)


def _follow_moved_project(root: str | Path) -> None:
    """Rewrite artefact URIs under another folder's ``mlartifacts`` (the one this store was made in) to this
    project's: MLflow keeps them absolute in the experiments and runs tables, and has no call to change them."""
    here = store_uris(root)[1]
    with closing(sqlite3.connect(Path(root) / "mlflow.db")) as db, db:
        locations = [row[0] for row in db.execute("SELECT artifact_location FROM experiments")]
        folder = f"/{ARTEFACTS}/"
        moved = {loc[: loc.rindex(folder) + len(folder) - 1] for loc in locations if folder in loc}
        for old in moved - {here}:
            for table, column in (("experiments", "artifact_location"), ("runs", "artifact_uri")):
                db.execute(
                    f"UPDATE {table} SET {column} = ? || substr({column}, ?) WHERE substr({column}, 1, ?) = ?",
                    (here, len(old) + 1, len(old) + 1, f"{old}/"),
                )


def follow_project(root: str | Path, port: int | str = 5000) -> None:
    """Open the project's store under its lock (`open_store`): what `make ui` does first, so the UI of a copied or
    cloned project shows this folder's artefacts before any stage has run in it; then print each experiment's link,
    which opens its runs with the key metrics as columns."""
    with store_lock(root):
        client = open_store(root)
        experiments = client.search_experiments()
    for experiment in sorted(experiments, key=lambda e: e.name):
        print(f"  {experiment.name}: {runs_link(experiment.experiment_id, port)}")


def experiment_tags(name: str) -> dict[str, str]:
    """What every experiment carries: its kind (model runs) and its shared view of its stage's key metrics and the
    keys runs are compared by."""
    stage = name.rsplit("/", 1)[-1]
    return {**EXPERIMENT_KIND, **view_tag(metric_names(KEY_METRICS.get(stage, "")), VIEW_PARAMS)}


def ensure_experiment(root: str | Path, name: str) -> str:
    """Create the store and the experiment if needed, under the store's lock; returns the experiment id."""
    tracking_uri, artifact_root = store_uris(root)
    mlflow.set_tracking_uri(tracking_uri)
    with store_lock(root):
        client = open_store(root)
        experiment = client.get_experiment_by_name(name)
        tags = experiment_tags(name)
        if experiment is None:
            return client.create_experiment(name, artifact_location=f"{artifact_root}/{name}", tags=tags)
        for key, value in tags.items():  # a store made by older code
            if experiment.tags.get(key) != value:
                client.set_experiment_tag(experiment.experiment_id, key, value)
        return experiment.experiment_id


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


def run_params(config: DictConfig | Mapping[str, Any], stage: str, root: str | Path) -> dict[str, str]:
    """The stage's own config sections, flattened, and the keys runs are compared by; paths inside the
    project are shown relative to it."""
    config = config if isinstance(config, DictConfig) else OmegaConf.create(dict(config))
    params: dict[str, str] = {}
    for section in SECTIONS.get(stage, (stage,)):
        value = OmegaConf.select(config, section, default=None)
        if isinstance(value, DictConfig):
            params.update(flatten(value, prefix=f"{section}."))
    for name, keys in COMPARED_BY.items():
        for key in (keys,) if isinstance(keys, str) else keys:
            key = key.format(stage=stage)
            value = OmegaConf.select(config, key, default=None)
            if value is not None and not isinstance(value, DictConfig):
                params.pop(key, None)
                params[name] = str(value)
                break
    for old, new in RENAMED.items():
        old = old.format(stage=stage)
        params = {(new + k.removeprefix(old) if k.startswith(old) else k): v for k, v in params.items()}
    prefix = f"{Path(root).resolve()}{os.sep}"
    return {k: v.replace(prefix, "") for k, v in params.items()}


@dataclasses.dataclass(frozen=True)
class UntrackedRun:
    """Stands in for the run when the store cannot be opened: ``info.run_id`` is None."""

    run_id: None = None

    @property
    def info(self) -> UntrackedRun:
        return self


@contextmanager
def stage_run(
    root: str | Path,
    stage: str,
    config: DictConfig | Mapping[str, Any],
    run_name: str | None = None,
    tags: Mapping[str, str] | None = None,
) -> Iterator[mlflow.ActiveRun | UntrackedRun]:
    """An MLflow run in experiment `<prefix>/<stage>`, started when the job started, with the stage's params and
    where it came from (`provenance_tags`; an ad-hoc run's name starts with `ADHOC_NAME_PREFIX`).

    Enter it after the stage's outputs are on disk. A tracking failure (store, lock, artefact copy)
    inside it warns and ends the block; the outputs stay and the stage goes on.
    """
    started = int(os.environ.get(JOB_START_ENV) or time.time() * 1000)
    tags = {**provenance_tags(root, config), **(tags or {})}
    run_name = _origin_prefix(tags) + (run_name or stage)
    created = None
    try:
        experiment_id = ensure_experiment(root, experiment_name(stage, config))
        tags.update(_nested(experiment_id))
        created = MlflowClient(store_uris(root)[0]).create_run(
            experiment_id, start_time=started, tags=tags, run_name=run_name
        )
    except LOGGING_ERRORS as err:
        warnings.warn(
            f"MLflow: no run logged for {stage} {run_name} ({err}); the outputs on disk are complete",
            stacklevel=3,
        )
    if created is None:
        mlflow.set_tracking_uri(UNTRACKED_URI)
        try:
            with suppress(*LOGGING_ERRORS):
                yield UntrackedRun()
        finally:
            mlflow.set_tracking_uri(store_uris(root)[0])
        return
    try:
        with mlflow.start_run(run_id=created.info.run_id) as run:  # ends FAILED if the block raises
            mlflow.log_params(run_params(config, stage, root))
            yield run
            _name_with_key_metric(run.info.run_id, stage, run_name)
    except LOGGING_ERRORS as err:
        _terminate(root, created.info.run_id, "FAILED")
        warnings.warn(
            f"MLflow: logging {stage} {run_name} failed ({err}); the outputs on disk are complete", stacklevel=3
        )


def _name_with_key_metric(run_id: str, stage: str, run_name: str) -> None:
    """End the run's name with the experiment's key metrics, so the runs table shows them without set-up."""
    client = mlflow.MlflowClient()
    with suppress(KeyError):
        shown = KEY_METRICS[stage].format(**client.get_run(run_id).data.metrics)
        client.update_run(run_id, name=f"{run_name} · {shown}")


def provenance_tags(root: str | Path, config: DictConfig | Mapping[str, Any]) -> dict[str, str]:
    """Where a run came from: the git commit the project is at, the DVC experiment it runs in, and whether it is a
    pipeline stage (dvc.yaml passes outputs=pipeline) or an ad-hoc run (`ORIGIN_TAG`)."""
    tags = {ORIGIN_TAG: "pipeline" if _select(config, "outputs") == "pipeline" else "adhoc"}
    commit = git_commit(str(Path(root).resolve()))
    if commit:
        tags["mlflow.source.git.commit"] = commit
    if os.environ.get(DVC_EXPERIMENT_ENV):
        tags["uqdrive.dvc_experiment"] = os.environ[DVC_EXPERIMENT_ENV]
    tags[NOTE_TAG] = run_note(tags)
    return tags


def run_note(tags: Mapping[str, str]) -> str:
    """The run page's Description (MLflow shows the `mlflow.note.content` tag there, and the git commit tag
    nowhere): the commit, the DVC experiment and whether the pipeline ran it."""
    commit = tags.get("mlflow.source.git.commit")
    parts = [f"git commit `{commit}`" if commit else "not a git checkout (no commit)"]
    if tags.get("uqdrive.dvc_experiment"):
        parts.append(f"DVC experiment `{tags['uqdrive.dvc_experiment']}`")
    parts.append("a pipeline stage (dvc.yaml)" if tags.get(ORIGIN_TAG) == "pipeline" else "an ad-hoc run")
    return "; ".join(parts)


def _origin_prefix(tags: Mapping[str, str]) -> str:
    return ADHOC_NAME_PREFIX if tags.get(ORIGIN_TAG) == "adhoc" else ""


@functools.cache
def git_commit(root: str) -> str | None:
    """The commit checked out at ``root`` (None outside a git work tree, or without git)."""
    try:
        found = subprocess.run(["git", "-C", root, "rev-parse", "HEAD"], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return found.stdout.strip() if found.returncode == 0 else None


def log_artifact_as(path: str | Path, name: str) -> None:
    """Log ``path`` under the file ``name`` in the active run: a cell's files are named by the cell on disk, but
    MLflow's Compare view lines runs' artefacts up by name, so every cell logs e.g. `paths.png` (its cell: a tag)."""
    with tempfile.TemporaryDirectory() as folder:
        stable = Path(folder) / name
        shutil.copyfile(path, stable)
        mlflow.log_artifact(str(stable))


@contextmanager
def stage_parent_run(
    root: str | Path, stage: str, config: DictConfig | Mapping[str, Any], overrides: Sequence[str], name: str
) -> Iterator[None]:
    """A parent run over one invocation of a grid stage (every cell's run in `<prefix>/<stage>` nests under it):
    FINISHED when the block ends, FAILED on an error, KILLED on an interrupt or an early stop. A tracking failure
    warns and the cells run on, unnested."""
    tags = {**provenance_tags(root, config), "uqdrive.overrides": " ".join(overrides)}
    enclosing = os.environ.get(PARENT_RUN_ENV)  # a Hydra multirun's parent run, if this invocation is one of its jobs
    try:
        experiment_id = ensure_experiment(root, experiment_name(stage, config))
        tags.update(_nested(experiment_id))
        parent = MlflowClient(store_uris(root)[0]).create_run(
            experiment_id, tags=tags, run_name=_origin_prefix(tags) + name
        )
    except LOGGING_ERRORS as err:
        warnings.warn(f"MLflow: no parent run for {name} ({err}); each cell logs its own run", stacklevel=3)
        yield
        return
    os.environ[PARENT_RUN_ENV] = f"{experiment_id}:{parent.info.run_id}"
    status = "KILLED"
    try:
        yield
        status = "FINISHED"
    except Exception:
        status = "FAILED"
        raise
    finally:
        if enclosing is None:
            os.environ.pop(PARENT_RUN_ENV, None)
        else:  # the multirun's next job nests under its parent again
            os.environ[PARENT_RUN_ENV] = enclosing
        _terminate(root, parent.info.run_id, status)


def _nested(experiment_id: str) -> dict[str, str]:
    """The parent-run tag of a run made inside a parent run of this experiment (`PARENT_RUN_ENV`), else none."""
    enclosing = os.environ.get(PARENT_RUN_ENV, "")
    return {"mlflow.parentRunId": enclosing.split(":", 1)[1]} if enclosing.startswith(f"{experiment_id}:") else {}


def _terminate(root: str | Path, run_id: str, status: str) -> None:
    try:
        MlflowClient(store_uris(root)[0]).set_terminated(run_id, status=status)
    except LOGGING_ERRORS as err:
        warnings.warn(f"MLflow: could not mark run {run_id} {status} ({err})", stacklevel=2)


class CreateStoreCallback(Callback):
    """Hydra callback for tracking: creates the store and the stage's experiment before a multirun's
    jobs start, and notes each job's start time for its run (`JOB_START_ENV`).

    With ``tracking.parent_run: true`` in the stage's config it also opens the sweep's parent run and
    hands its id to the jobs through the environment (`PARENT_RUN_ENV`, inherited by joblib's worker
    processes), so each job's run is its child. The parent ends FINISHED when the sweep ends, KILLED on
    SIGINT/SIGTERM, FAILED when the process exits otherwise (a job's error ends a Hydra sweep).
    """

    def __init__(self) -> None:
        self._parent: tuple[str, str] | None = None  # (project root, run id) while the sweep runs
        self._handlers: dict[int, Any] = {}  # the signal handlers replaced while the sweep runs

    def on_job_start(self, config: DictConfig, **kwargs: Any) -> None:
        os.environ[JOB_START_ENV] = str(int(time.time() * 1000))

    def on_job_end(self, config: DictConfig, job_return: Any, **kwargs: Any) -> None:
        os.environ.pop(JOB_START_ENV, None)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        root = _project_root(config)
        experiment_id = ensure_experiment(root, experiment_name(config.hydra.job.name, config))
        if not OmegaConf.select(config, "tracking.parent_run", default=False):
            return
        client = MlflowClient(store_uris(root)[0])
        overrides = " ".join(config.hydra.overrides.task)
        tags = provenance_tags(root, config)
        run = client.create_run(
            experiment_id,
            run_name=f"{_origin_prefix(tags)}sweep {config.hydra.job.name}",
            tags={**tags, "uqdrive.sweep_dir": str(config.hydra.sweep.dir), "uqdrive.overrides": overrides},
        )
        self._parent = (root, run.info.run_id)
        os.environ[PARENT_RUN_ENV] = f"{experiment_id}:{run.info.run_id}"
        atexit.register(self._end_parent, "FAILED")
        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                self._handlers[signum] = signal.signal(signum, self._interrupted(signal.getsignal(signum)))

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        self._end_parent("FINISHED")

    def _end_parent(self, status: str) -> None:
        if self._parent is not None:
            root, run_id = self._parent
            self._parent = None
            os.environ.pop(PARENT_RUN_ENV, None)
            _terminate(root, run_id, status)
        for signum, handler in self._handlers.items():
            signal.signal(signum, handler)
        self._handlers.clear()

    def _interrupted(self, previous: Any) -> Any:
        return interrupt_handler(previous, lambda: self._end_parent("KILLED"))


def interrupt_handler(previous: Any, on_signal: Callable[[], None], grace_s: float = INTERRUPT_GRACE_S) -> Any:
    """A signal handler that runs `on_signal`, then does what `previous` did (Python's SIGINT handler raises
    KeyboardInterrupt, so clean-up code runs). Library code can swallow that exception (a sweep interrupted
    while importing its stage's modules ran on to its end, on a loaded machine): should the process still
    run `grace_s` later, it ends by the signal's default action. A second Ctrl-C ends it at once."""

    def handle(signum: int, frame: Any) -> None:
        on_signal()
        signal.signal(signum, signal.SIG_DFL)
        timer = threading.Timer(grace_s, os.kill, (os.getpid(), signum))
        timer.daemon = True
        timer.start()
        if callable(previous):
            previous(signum, frame)
        elif previous != signal.SIG_IGN:
            raise SystemExit(128 + signum)

    return handle


def _project_root(config: DictConfig) -> str:
    """`paths.root`, which defaults to ${hydra:runtime.cwd}: outside a job (at multirun start and
    end) that resolver needs the Hydra config registered first."""
    if not HydraConfig.initialized():
        HydraConfig.instance().set_config(config)
    return str(config.paths.root)


def register_certified(policy: str | Path, tags: Mapping[str, str], certified: bool) -> str | None:
    """Log the policy file in the active run and make it a version of the registered model named after the file
    (`<stem>`), the certificate as the version's tags; a certified version takes the alias `certified`, so the
    registry says which version passed. Returns the version (None when logging failed: a warning, the verdict on
    disk stands)."""
    run = mlflow.active_run()
    if run is None:
        return None
    name = Path(policy).stem
    try:
        mlflow.log_artifact(str(policy), artifact_path="policy")
        client = mlflow.MlflowClient()
        with suppress(MlflowException):  # it exists already
            client.create_registered_model(name, description="policies `uqdrive certify` decided on")
        source = f"{run.info.artifact_uri}/policy/{Path(policy).name}"
        version = client.create_model_version(name, source, run_id=run.info.run_id, tags=dict(tags)).version
        if certified:
            client.set_registered_model_alias(name, CERTIFIED_ALIAS, version)
    except LOGGING_ERRORS as err:  # the block's own failure warns, its run ends FAILED: this one only warns
        warnings.warn(f"MLflow: {policy} not registered ({err}); the verdict on disk is complete", stacklevel=2)
        return None
    return str(version)
