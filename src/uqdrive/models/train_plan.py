"""The train stages' schemas and plan: one method's config (`TrainStage`, its `TrainSection`), the replicates'
(`TrainReplicatesStage`, each a `TrainJob`), a fit's result (`FitResult`) and what a run returns (`Trained`). The
stage functions are `uqdrive.pipeline.train_stage`'s."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from omegaconf import OmegaConf

from uqdrive.data.datasets import load_frames
from uqdrive.models.metrics import majority_accuracy
from uqdrive.models.model_stage import ModelStage
from uqdrive.models.pilotnet import Architecture
from uqdrive.models.posterior import Fitted, posterior_settings
from uqdrive.models.trained_record import TrainMetrics
from uqdrive.models.training import TrainingData, compute_features, evaluate, validation_generator
from uqdrive.schema import Count, Str, schema, validate
from uqdrive.stage_schemas import ExecutorSettings, NonEmptySeeds


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


@dataclass(frozen=True)
class FitResult:
    """One replicate fitted and scored on validation (``scores``), with its metrics: what a worker (a process, or a
    Ray actor on another node) hands back to be written where the stage runs."""

    fitted: Fitted
    scores: dict[str, float]
    metrics: TrainMetrics


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
