"""The `train` stages: fit one posterior (model=<conf/model yaml>) for one training seed (a replicate), evaluate it
on validation, save and log it; the DVC stage trains every replicate of params.yaml, each as the single-replicate
command (`python stages/train.py model=M seed=r`) composes it, a worker's share of them stacked into one batch
(`Posterior.fit_replicates`: each replicate still draws everything from its own seed).

The model config names its Posterior class by `_target_`; the class checks its settings and fits itself (MCD end
to end on the processed frames; the head methods on the same replicate's MCD trunk features), so these stages
know no method by name.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import mlflow
import torch
from omegaconf import DictConfig, OmegaConf

from uqdrive.data.datasets import load_frames
from uqdrive.figures import save_figure
from uqdrive.files import write_csv
from uqdrive.models.checkpoint import save_posterior
from uqdrive.models.metrics import majority_accuracy
from uqdrive.models.pilotnet import Architecture
from uqdrive.models.posterior import Fitted, posterior_settings
from uqdrive.models.trained_record import TrainMetrics
from uqdrive.models.training import TrainingData, compute_features, evaluate, validation_generator
from uqdrive.parallel import PooledExecutor, ProcessPool, RayPool
from uqdrive.records import as_dict, write_record
from uqdrive.schema import Count, Str, schema, validate
from uqdrive.stage import compose_cell, grid
from uqdrive.stage_schemas import ExecutorSettings, ModelStage, NonEmptySeeds
from uqdrive.tracking import stage_run


@schema
class TrainSection:
    """Training sizes; the per-method ones reach the model's settings through conf/model/ (checked there)."""

    base_model: Str
    eval_samples: Count
    threads: Count
    workers: Count  # replicates trained side by side (`run_train_replicates`)
    mcd: dict[str, Any]
    vi: dict[str, Any]
    hmc: dict[str, Any]
    ensemble: dict[str, Any]
    laplace: dict[str, Any]


@schema(root=True)
class TrainStage(ModelStage):
    arch: Architecture
    train: TrainSection
    executor: ExecutorSettings  # where `run_train_replicates` fits its groups (one replicate trains here)


def run_train(cfg: DictConfig) -> TrainMetrics:
    return train_replicates([cfg])[0]


@dataclass(frozen=True)
class FitResult:
    """One replicate fitted and scored on validation (``scores``), with its metrics: what a worker (a process, or a
    Ray actor on another node) hands back to be written where the stage runs."""

    fitted: Fitted
    scores: dict[str, float]
    metrics: TrainMetrics


def fit(stages: list[TrainStage]) -> list[FitResult]:
    """Fit one method's replicates as one batch (`Posterior.fit_replicates`: stacked where the method allows) and
    score each on validation."""
    cls, settings = posterior_settings(stages[0].model)
    first, bins = stages[0], stages[0].experiment.bins
    if (
        any(posterior_settings(s.model) != (cls, settings) for s in stages)
        or len({s.paths.processed for s in stages}) > 1
    ):
        raise ValueError("replicates trained as one batch must share the model settings and the processed frames")
    processed = Path(first.paths.processed)
    train = load_frames(processed / "train.parquet", bins.num_classes)
    val = load_frames(processed / "val.parquet", bins.num_classes)
    data = [TrainingData(train, val, bins, s.arch, Path(s.train.base_model), s.train.eval_samples) for s in stages]
    generators = [torch.Generator().manual_seed(s.seed) for s in stages]
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(first.train.threads)
    try:
        started = time.perf_counter()
        fits = cls.fit_replicates(settings, data, generators, first.progress)
        seconds = (time.perf_counter() - started) / len(fits)
        scores = [
            evaluate(f.posterior.eval(), compute_features(f.posterior, val), val.labels, d.eval_samples, g)
            for f, d, g in zip(fits, data, (validation_generator(s.seed) for s in stages))
        ]
    finally:
        torch.set_num_threads(previous_threads)
    baseline = majority_accuracy(train.labels, val.labels, bins.num_classes)
    return [
        FitResult(f, score, _metrics(f, score, stage, seconds, baseline, (len(train), len(val), len(fits))))
        for f, score, stage in zip(fits, scores, stages)
    ]


def _metrics(
    fitted: Fitted, scores: dict, stage: TrainStage, seconds: float, baseline: float, sizes: tuple[int, int, int]
) -> TrainMetrics:
    """A replicate's record: its validation scores, the data's sizes, its seed and its share of the batch's time."""
    train_frames, val_frames, batched = sizes
    return TrainMetrics(
        method=fitted.posterior.method,
        **{f"val_{k}": v for k, v in scores.items()},
        majority_baseline_accuracy=baseline,
        train_frames=train_frames,
        val_frames=val_frames,
        eval_samples=stage.train.eval_samples,
        seed=stage.seed,
        train_seconds=seconds,
        batched_replicates=batched,
        **fitted.extra,
    )


def train_replicates(configs: Sequence[DictConfig]) -> list[TrainMetrics]:
    """Fit one method's replicates (configs that differ by seed only) as one batch, then save, write and log each as
    its own run. Returns their metrics."""
    stages = [validate(TrainStage, cfg) for cfg in configs]
    return [record(cfg, stage, result) for cfg, stage, result in zip(configs, stages, fit(stages))]


def record(cfg: DictConfig, stage: TrainStage, result: FitResult) -> TrainMetrics:
    """A fitted replicate written and logged (`write_replicate`); its metrics."""
    write_replicate(cfg, stage, result.fitted, result.metrics)
    return result.metrics


def write_replicate(cfg: DictConfig, stage: TrainStage, fitted: Fitted, metrics: TrainMetrics) -> None:
    """A trained replicate's model, learning curve and metrics files, then its MLflow run."""
    model, curve, values = fitted.posterior, fitted.curve, as_dict(metrics)
    replicate, paths = stage.replicate, stage.paths
    model_path = save_posterior(model, Path(paths.models) / f"{replicate}.pt", metadata={"metrics": values})
    plots = Path(paths.plots)
    curve_csv = write_csv(plots / f"{replicate}_curve.csv", curve)  # DVC plots: x=step, y=val_accuracy
    curve_png = save_figure(curve_figure(curve, metrics.method, model.curve_unit), plots / f"{replicate}_curve.png")
    metrics_json = write_record(Path(paths.metrics) / f"{replicate}.json", metrics)
    run_name = f"{stage.experiment.name}-{metrics.method}-{replicate}"
    with stage_run(paths.root, "train", cfg, run_name=run_name):
        mlflow.log_metrics({k: float(v) for k, v in values.items() if isinstance(v, (int, float))})
        for row in curve:
            mlflow.log_metrics({f"curve_{k}": float(v) for k, v in row.items() if k != "step"}, step=int(row["step"]))
        for path in (curve_csv, curve_png, metrics_json, model_path):
            mlflow.log_artifact(str(path))


def describe(m: TrainMetrics) -> str:
    """The line a stage prints for a trained replicate."""
    return (
        f"train {m.method} seed {m.seed}: val accuracy {m.val_accuracy:.3f} (majority baseline "
        f"{m.majority_baseline_accuracy:.3f}), NLL {m.val_nll:.3f}, ECE {m.val_ece:.3f} in {m.train_seconds:.0f} s"
    )


def curve_figure(rows: list[dict], method: str, unit: str) -> plt.Figure:
    """Loss and validation accuracy per step; points are marked, so a curve of one step still shows."""
    step = [r["step"] for r in rows]
    fig, (loss_ax, acc_ax) = plt.subplots(1, 2, figsize=(9, 3.2))
    loss_ax.plot(step, [r["train_loss"] for r in rows], ".-", label="train loss")
    loss_ax.plot(step, [r["val_nll"] for r in rows], ".-", label="val NLL")
    loss_ax.set_xlabel(unit)
    loss_ax.legend()
    acc_ax.plot(step, [r["val_accuracy"] for r in rows], ".-")
    acc_ax.set_xlabel(loss_ax.get_xlabel())
    acc_ax.set_ylabel("val accuracy")
    fig.suptitle(f"{method} learning curve")
    return fig


@schema(root=True)
class TrainReplicatesStage(TrainStage):
    """`stages/train_replicates.py`: one posterior for every training seed of `replicates`."""

    replicates: NonEmptySeeds


@dataclass(frozen=True)
class TrainJob:
    """The replicates' configs, resolved (a worker has no Hydra), in groups: item i fits group i as one batch
    (`fit`); what it hands back is written where the stage runs."""

    groups: tuple[tuple[dict, ...], ...]

    def worker(self) -> TrainJob:
        return self

    def run(self, index: int) -> list[FitResult]:
        return fit([validate(TrainStage, OmegaConf.create(c)) for c in self.groups[index]])

    def close(self) -> None:
        """Nothing held between items."""


@dataclass(frozen=True)
class Trained:
    """Every replicate of one method, in replicate order."""

    replicates: list[TrainMetrics]


def run_train_replicates(cfg: DictConfig, overrides: Sequence[str]) -> Trained:
    """Every replicate of ``cfg.replicates``, in ``train.workers`` groups of consecutive seeds, each group one batch
    on a worker of its own (a core each: stacking replicates saves per-replicate overhead, a second core doubles
    throughput): processes here, or Ray actors with ``executor=ray`` (on a cluster, nodes that share the project
    folder). The groups, and so every model, are the same on either backend. Each replicate's config is checked
    before any trains; each is written and logged here as its batch comes back. Returns their metrics in replicate
    order."""
    stage = validate(TrainReplicatesStage, cfg)
    configs = [compose_cell("train", overrides, cell) for cell in grid(seed=stage.replicates)]
    stages = [validate(TrainStage, config) for config in configs]
    resolved = [OmegaConf.to_container(c, resolve=True) for c in configs]
    groups = min(stage.train.workers, len(configs))
    bounds = [round(i * len(configs) / groups) for i in range(groups + 1)]
    job = TrainJob(tuple(tuple(resolved[start:end]) for start, end in zip(bounds, bounds[1:])))
    trained = []
    with closing(_pool(stage.executor, job, groups)) as pool:
        for start, results in zip(bounds, pool.run(range(groups))):
            trained += [record(configs[start + i], stages[start + i], r) for i, r in enumerate(results)]
    return Trained(trained)


def _pool(executor: ExecutorSettings, job: TrainJob, groups: int) -> PooledExecutor | RayPool:
    """Where the groups are fitted: ``groups`` processes, or Ray actors (at most ``executor.workers``)."""
    if executor.name == "ray":
        return RayPool(job, min(executor.workers, groups), **executor.options())
    return ProcessPool(groups).executor(job, owns_pool=True)
