"""The `train` stage: fit one posterior (model=<conf/model yaml>), evaluate it on validation, save and log it.

The model config names its Posterior class by `_target_`; the class checks its settings and fits
itself (MCD end to end on the processed frames; the head methods on `models/mcd.pt`'s fixed trunk
features), so this stage knows no method by name.
"""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib.pyplot as plt
import mlflow
import torch
from omegaconf import DictConfig, OmegaConf

from uqdrive.checks import ConfigError
from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import load_frames
from uqdrive.files import write_csv, write_json
from uqdrive.models.checkpoint import save_posterior
from uqdrive.models.metrics import majority_accuracy
from uqdrive.models.pilotnet import Architecture
from uqdrive.models.posterior import Posterior, posterior_from_config
from uqdrive.models.training import TrainingData, compute_features, evaluate, settings_from
from uqdrive.plots import save_figure
from uqdrive.tracking import stage_run


def model_from_config(cfg: DictConfig) -> tuple[type[Posterior], object]:
    """The Posterior class `model._target_` names and its checked settings (the model keys besides name, _target_)."""
    cls = posterior_from_config(cfg.model)
    model_cfg = OmegaConf.to_container(cfg.model, resolve=True)
    return cls, settings_from(cls.Settings, {k: v for k, v in model_cfg.items() if k not in ("name", "_target_")})


def run_train(cfg: DictConfig) -> dict:
    cls, settings = model_from_config(cfg)
    method = cls.method
    eval_samples = int(cfg.train.eval_samples)
    if eval_samples < 1:
        raise ConfigError(f"train.eval_samples={eval_samples} must be ≥ 1")
    bins = SteeringBins(**cfg.experiment.bins)
    processed = Path(cfg.paths.processed)
    train = load_frames(processed / "train.parquet", bins.num_classes)
    val = load_frames(processed / "val.parquet", bins.num_classes)
    generator = torch.Generator().manual_seed(int(cfg.seed))
    threads = int(cfg.train.threads)
    if threads < 1:
        raise ConfigError(f"train.threads={threads} must be ≥ 1")
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(threads)
    data = TrainingData(
        train,
        val,
        bins,
        Architecture(**OmegaConf.to_container(cfg.arch, resolve=True)),
        Path(cfg.train.base_model),
        eval_samples,
    )
    try:
        started = time.perf_counter()
        fitted = cls.fit(settings, data, generator, bool(cfg.progress))
        seconds = time.perf_counter() - started
        model, curve, extra = fitted.posterior.eval(), fitted.curve, fitted.extra
        scores = evaluate(model, compute_features(model, val), val.labels, eval_samples, generator)
    finally:
        torch.set_num_threads(previous_threads)
    metrics = {
        "method": method,
        **{f"val_{k}": v for k, v in scores.items()},
        "majority_baseline_accuracy": majority_accuracy(train.labels, val.labels, bins.num_classes),
        "train_frames": len(train),
        "val_frames": len(val),
        "eval_samples": eval_samples,
        "seed": int(cfg.seed),
        "train_seconds": seconds,
        **extra,
    }
    model_path = save_posterior(model, Path(cfg.paths.models) / f"{method}.pt", metadata={"metrics": metrics})
    plots = Path(cfg.paths.plots) / "train"
    curve_csv = write_csv(plots / f"{method}_curve.csv", curve)  # DVC plots: x=step, y=val_accuracy
    curve_png = save_figure(curve_figure(curve, method, cls.curve_unit), plots / f"{method}_curve.png")
    metrics_json = Path(cfg.paths.metrics) / "train" / f"{method}.json"
    write_json(metrics_json, metrics)

    with stage_run(cfg.paths.root, "train", cfg, run_name=method):
        mlflow.log_metrics({k: float(v) for k, v in metrics.items() if isinstance(v, (int, float))})
        for row in curve:
            mlflow.log_metrics({f"curve_{k}": float(v) for k, v in row.items() if k != "step"}, step=int(row["step"]))
        for path in (curve_csv, curve_png, metrics_json, model_path):
            mlflow.log_artifact(str(path))
    return metrics


def curve_figure(rows: list[dict], method: str, unit: str) -> plt.Figure:
    step = [r["step"] for r in rows]
    fig, (loss_ax, acc_ax) = plt.subplots(1, 2, figsize=(9, 3.2))
    loss_ax.plot(step, [r["train_loss"] for r in rows], label="train loss")
    loss_ax.plot(step, [r["val_nll"] for r in rows], label="val NLL")
    loss_ax.set_xlabel(unit)
    loss_ax.legend()
    acc_ax.plot(step, [r["val_accuracy"] for r in rows])
    acc_ax.set_xlabel(loss_ax.get_xlabel())
    acc_ax.set_ylabel("val accuracy")
    fig.suptitle(f"{method} learning curve")
    return fig
