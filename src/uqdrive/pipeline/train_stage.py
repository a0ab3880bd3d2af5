"""The `train` stages: fit one posterior (model=<conf/model yaml>) for one training seed (a replicate), evaluate it
on validation, save and log it; the DVC stage trains every replicate of params.yaml, each as the single-replicate
command (`python stages/train.py model=M seed=r`) composes it, a worker's share of them stacked into one batch
(`Posterior.fit_replicates`: each replicate still draws everything from its own seed).

The model config names its Posterior class by `_target_`; the class checks its settings and fits itself (MCD end
to end on the processed frames; the head methods on the same replicate's MCD trunk features), so these stages
know no method by name.
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import closing
from pathlib import Path

import matplotlib.pyplot as plt
import mlflow
from omegaconf import DictConfig, OmegaConf

from uqdrive.figures import save_figure
from uqdrive.files import write_csv
from uqdrive.models.checkpoint import save_posterior
from uqdrive.models.posterior import Fitted
from uqdrive.models.train_plan import FitResult, Trained, TrainJob, TrainReplicatesStage, TrainStage, fit
from uqdrive.models.trained_record import TrainMetrics
from uqdrive.parallel import PooledExecutor, ProcessPool, RayPool
from uqdrive.records import as_dict, write_record
from uqdrive.schema import validate
from uqdrive.stage import compose_cell, grid
from uqdrive.stage_schemas import ExecutorSettings
from uqdrive.tracking import stage_run


def run_train(cfg: DictConfig) -> TrainMetrics:
    return train_replicates([cfg])[0]


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
