"""The `train` stage: fit one posterior (model=mcd|vi|hmc), evaluate it on validation, save and log it.

MCD trains end to end on the processed frames. VI and HMC load `models/mcd.pt`, compute its
trunk features once for each split, and fit their Bayesian head on that cache.
"""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib.pyplot as plt
import mlflow
import torch
from omegaconf import DictConfig, OmegaConf

from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import FrameSet, load_frames
from uqdrive.files import write_csv, write_json
from uqdrive.models.checkpoint import check_method, load_posterior, save_posterior
from uqdrive.models.mcd import MCDPosterior
from uqdrive.models.metrics import majority_accuracy
from uqdrive.models.pilotnet import Architecture, init_weights
from uqdrive.models.posterior import Posterior
from uqdrive.models.training import (
    HMCSettings,
    MCDSettings,
    VISettings,
    compute_features,
    evaluate,
    sample_hmc,
    settings_from,
    train_mcd,
    train_vi,
)
from uqdrive.models.vi import VIPosterior
from uqdrive.plots import save_figure
from uqdrive.tracking import stage_run

SETTINGS = {"mcd": MCDSettings, "vi": VISettings, "hmc": HMCSettings}


def run_train(cfg: DictConfig) -> dict:
    method = check_method(cfg.model.name)
    model_cfg = OmegaConf.to_container(cfg.model, resolve=True)
    settings = settings_from(SETTINGS[method], {k: v for k, v in model_cfg.items() if k != "name"})
    eval_samples = int(cfg.train.eval_samples)
    if eval_samples < 1:
        raise ValueError(f"train.eval_samples={eval_samples} must be ≥ 1")
    bins = SteeringBins(**cfg.experiment.bins)
    processed = Path(cfg.paths.processed)
    train = load_frames(processed / "train.parquet", bins.num_classes)
    val = load_frames(processed / "val.parquet", bins.num_classes)
    generator = torch.Generator().manual_seed(int(cfg.seed))
    threads = int(cfg.train.threads)
    if threads < 1:
        raise ValueError(f"train.threads={threads} must be ≥ 1")
    previous_threads = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        model, curve, val_features, extra, seconds = _fit(method, settings, cfg, bins, train, val, generator, eval_samples)
        scores = evaluate(model.eval(), val_features, val.labels, eval_samples, generator)
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
    curve_png = save_figure(curve_figure(curve, method), plots / f"{method}_curve.png")
    metrics_json = Path(cfg.paths.metrics) / "train" / f"{method}.json"
    write_json(metrics_json, metrics)

    with stage_run(cfg.paths.root, "train", cfg, run_name=method):
        mlflow.log_metrics({k: float(v) for k, v in metrics.items() if isinstance(v, (int, float))})
        for row in curve:
            mlflow.log_metrics({f"curve_{k}": float(v) for k, v in row.items() if k != "step"}, step=int(row["step"]))
        for path in (curve_csv, curve_png, metrics_json, model_path):
            mlflow.log_artifact(str(path))
    return metrics


def _fit(method: str, settings: MCDSettings | VISettings | HMCSettings, cfg: DictConfig, bins: SteeringBins,
         train: FrameSet, val: FrameSet, generator: torch.Generator,
         eval_samples: int) -> tuple[Posterior, list[dict], torch.Tensor, dict, float]:
    """Train one method; returns (posterior, learning curve, val features, method metrics, seconds)."""
    progress = bool(cfg.progress)
    started = time.perf_counter()
    extra: dict[str, float] = {}
    if method == "mcd":
        arch = Architecture(**OmegaConf.to_container(cfg.arch, resolve=True))
        model = init_weights(MCDPosterior(arch, bins, settings.init_p, settings.temperature), generator)
        curve = train_mcd(model, train, val, settings, generator, eval_samples, progress)
        val_features = compute_features(model, val)
        extra = {f"dropout_p{k + 1}": p for k, p in enumerate(model.dropout_rates())}
    else:
        base = load_posterior(cfg.train.base_model, expected_method="mcd", expected_classes=bins)
        train_features, val_features = compute_features(base, train), compute_features(base, val)
        if method == "vi":
            model = VIPosterior.from_mcd(base, settings.prior_sigma, settings.init_sigma)
            curve = train_vi(model, train_features, train.labels, val_features, val.labels, settings, generator,
                             eval_samples, progress)
            extra = {"posterior_sigma_mean": model.posterior_sigma_mean()}
        else:
            model, extra, curve = sample_hmc(base, train_features, train.labels, val_features, val.labels, settings,
                                             generator, progress)
    return model, curve, val_features, extra, time.perf_counter() - started


def curve_figure(rows: list[dict], method: str) -> plt.Figure:
    step = [r["step"] for r in rows]
    fig, (loss_ax, acc_ax) = plt.subplots(1, 2, figsize=(9, 3.2))
    loss_ax.plot(step, [r["train_loss"] for r in rows], label="train loss")
    loss_ax.plot(step, [r["val_nll"] for r in rows], label="val NLL")
    loss_ax.set_xlabel("iteration" if method == "hmc" else "epoch")
    loss_ax.legend()
    acc_ax.plot(step, [r["val_accuracy"] for r in rows])
    acc_ax.set_xlabel(loss_ax.get_xlabel())
    acc_ax.set_ylabel("val accuracy")
    fig.suptitle(f"{method} learning curve")
    return fig
