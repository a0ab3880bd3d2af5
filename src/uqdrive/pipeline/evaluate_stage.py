"""The `evaluate` stage: every method on held-out frames of each weather × noise level (the `heldout` stage's
autopilot frames, on episodes the training collection never used), as `uqdrive.models.heldout_eval` measures them;
metrics/evaluate.json, reliability and per-condition plot data, figures, a run per method."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import matplotlib.pyplot as plt
import mlflow
import torch
from omegaconf import DictConfig
from tqdm import tqdm

from uqdrive.data.datasets import FrameSet
from uqdrive.data.heldout import heldout_path, load_heldout
from uqdrive.figures import save_figure
from uqdrive.files import write_csv
from uqdrive.models.agreement import agreement_with_reference
from uqdrive.models.checkpoint import load_posterior
from uqdrive.models.evaluate_plan import EvaluateStage, Evaluation
from uqdrive.models.figure import condition_lines_figure, reliability_grid
from uqdrive.models.heldout_eval import HeldoutCell, HeldoutTable, cell_generator, heldout_cell, noise_key, predict
from uqdrive.models.metrics import reliability_bins
from uqdrive.models.posterior import Posterior
from uqdrive.records import write_record
from uqdrive.schema import validate
from uqdrive.tracking import stage_run

PLOTTED = [
    ("accuracy", "accuracy"),
    ("ece", "ECE"),
    ("mean_mutual_information", "mean MI (nats)"),
    ("mean_eta2", "mean η2"),
    ("auroc_mi", "AUROC of MI for wrong class"),
    ("auroc_one_minus_eta2", "AUROC of 1 − η2 for wrong class"),
]
REFERENCE = "hmc"  # the reference posterior every method is compared with, when it is evaluated
AGREEMENT_PLOTTED = [
    (f"{REFERENCE}_tv_distance", "mean TV distance to HMC's predictive"),
    (f"{REFERENCE}_argmax_agreement", "decision (argmax) agreement with HMC"),
    (f"{REFERENCE}_mi_spearman", "Spearman ρ of MI with HMC's"),
]


def check_inputs(stage: EvaluateStage) -> dict[str, Path]:
    """Model file of each method; raises before any work, naming every missing file and how to make it."""
    models = {m: Path(stage.paths.models) / m / f"{stage.replicate}.pt" for m in stage.methods}
    missing = [
        f"{path}: train it first (`python stages/train.py model={m} seed={stage.seed}`, or dvc repro)"
        for m, path in models.items()
        if not path.exists()
    ]
    scenario = stage.scenario.name
    missing += [
        f"{heldout_path(stage.evaluate.heldout_dir, scenario, w, x)}: collect it first (`python stages/collect.py "
        f"--config-name heldout scenario={scenario} weather={w} noise={x}`, or dvc repro heldout)"
        for w in stage.weathers
        for x in stage.noises
        if not heldout_path(stage.evaluate.heldout_dir, scenario, w, x).exists()
    ]
    if missing:
        raise FileNotFoundError("evaluate is missing its inputs:\n  " + "\n  ".join(missing))
    return models


def evaluate(stage: EvaluateStage, posteriors: dict[str, Posterior], frames: dict[tuple[str, float], FrameSet]):
    """Every method × condition; with HMC among them, each method's agreement with HMC's predictive (HMC's own
    against a second, independent set of its draws: the noise floor)."""
    settings, centres = stage.evaluate, stage.experiment.bins.centres
    cells = [(m, w, x) for m in stage.methods for w in stage.weathers for x in stage.noises]

    def run(method: str, weather: str, noise: float, name: str) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        generator = cell_generator(stage.seed, name, weather, noise)
        s = settings
        return predict(posteriors[method], frames[weather, noise], s.samples, s.eps, s.batch_size, centres, generator)

    table: dict = {}
    reliability, predictives = {}, {}
    for m, w, x in tqdm(cells, desc="evaluate", unit="cell", disable=not stage.progress):
        probs, eta2, mi = run(m, w, x, m)
        labels = frames[w, x].labels
        table.setdefault(m, {}).setdefault(w, {})[noise_key(x)] = heldout_cell(probs, labels, eta2, mi)
        reliability[m, w, x] = reliability_bins(probs, labels)
        predictives[m, w, x] = probs, mi
    if REFERENCE in stage.methods:
        for m, w, x in cells:
            probs, mi = predictives[m, w, x] if m != REFERENCE else run(m, w, x, f"{m}-repeat")[::2]
            agreement = agreement_with_reference(probs, mi, *predictives[REFERENCE, w, x])
            table[m][w][noise_key(x)].update({f"{REFERENCE}_{k}": v for k, v in agreement.items()})
    typed = {m: {w: {k: HeldoutCell(**c) for k, c in by.items()} for w, by in ws.items()} for m, ws in table.items()}
    return Evaluation(HeldoutTable(typed), reliability)


def reliability_rows(stage: EvaluateStage, evaluation: Evaluation) -> list[dict]:
    """The non-empty bins of every cell's reliability diagram (DVC plot data: x=confidence, y=accuracy)."""
    rows = []
    for (m, w, x), bins in evaluation.reliability.items():
        for k in torch.nonzero(bins["frames"]).flatten().tolist():
            rows.append(
                {
                    "series": f"{m} {w} {noise_key(x)}",
                    "method": m,
                    "weather": w,
                    "noise": x,
                    "bin": k,
                    "bin_low": float(bins["low"][k]),
                    "bin_high": float(bins["high"][k]),
                    "confidence": float(bins["confidence"][k]),
                    "accuracy": float(bins["accuracy"][k]),
                    "frames": int(bins["frames"][k]),
                }
            )
    return rows


def condition_rows(stage: EvaluateStage, table: HeldoutTable) -> list[dict]:
    """One row per method × condition, every metric (DVC plot data)."""
    return [
        {
            "series": f"{m} {w} {noise_key(x)}",
            "method": m,
            "weather": w,
            "noise": x,
            **{k: v for k, v in dataclasses.asdict(table.cell(m, w, x)).items() if k != "auroc_note"},
        }
        for m in stage.methods
        for w in stage.weathers
        for x in stage.noises
    ]


def plot(stage: EvaluateStage, evaluation: Evaluation) -> dict[str, plt.Figure]:
    """A reliability grid per method, the metrics along the conditions, and agreement with HMC."""
    table, where = evaluation.table, stage.scenario.name
    conditions = [(w, x) for w in stage.weathers for x in stage.noises]
    labels = [f"{w} σ={x:g}" for w, x in conditions]
    figures = {}
    for m in stage.methods:
        panels = {
            (noise_key(x), w): {
                **{k: v.numpy() for k, v in evaluation.reliability[m, w, x].items()},
                "ece": table.cell(m, w, x).ece,
            }
            for w, x in conditions
        }
        keys = [noise_key(x) for x in stage.noises]
        title = f"{m}: reliability on held-out frames at the {where}"
        figures[f"reliability_{m}"] = reliability_grid(panels, keys, list(stage.weathers), title)

    def lines(plotted: list[tuple[str, str]]) -> dict:
        return {
            m: {k: [getattr(table.cell(m, w, x), k) for w, x in conditions] for k, _ in plotted} for m in stage.methods
        }

    title = f"Held-out frames at the {where}: methods across weather × sensor noise"
    figures["conditions"] = condition_lines_figure(lines(PLOTTED), labels, PLOTTED, title)
    if REFERENCE in stage.methods:
        title = f"Agreement with HMC on held-out frames at the {where} (hmc: two independent draw sets)"
        figures[f"agreement_{REFERENCE}"] = condition_lines_figure(
            lines(AGREEMENT_PLOTTED), labels, AGREEMENT_PLOTTED, title
        )
    return figures


def log(cfg: DictConfig, stage: EvaluateStage, table: HeldoutTable, paths: dict[str, Path]) -> None:
    """A run per method: its metrics by condition (`<weather>/noise<σ>/<metric>`), its reliability grid and the
    shared figures and tables."""
    own = {f"reliability_{m}" for m in stage.methods}
    shared = [p for k, p in paths.items() if k not in own]
    for m in stage.methods:
        with stage_run(stage.paths.root, "evaluate", cfg, run_name=f"{m}-{stage.replicate}"):
            mlflow.log_param("method", m)
            mlflow.log_metrics(
                {
                    f"{w}/{noise_key(x)}/{k}": float(v)
                    for w in stage.weathers
                    for x in stage.noises
                    for k, v in dataclasses.asdict(table.cell(m, w, x)).items()
                    if isinstance(v, (int, float))
                }
            )
            for path in (paths[f"reliability_{m}"], *shared):
                mlflow.log_artifact(str(path))


def run_evaluate(cfg: DictConfig) -> HeldoutTable:
    """Evaluate every method of `methods` on the held-out frames of every weather × noise: load, evaluate, plot,
    write (plot data, figures, then the metrics file), log."""
    stage = validate(EvaluateStage, cfg)
    bins, scenario, folder = stage.experiment.bins, stage.scenario.name, stage.evaluate.heldout_dir
    models = check_inputs(stage)
    posteriors = {m: load_posterior(path, expected_method=m, expected_classes=bins) for m, path in models.items()}
    conditions = [(w, x) for w in stage.weathers for x in stage.noises]
    frames = {
        (w, x): load_heldout(heldout_path(folder, scenario, w, x), scenario, w, x, bins)
        for w, x in tqdm(conditions, desc="evaluate: load frames", unit="condition", disable=not stage.progress)
    }
    evaluation = evaluate(stage, posteriors, frames)
    figures = plot(stage, evaluation)
    plots = Path(stage.evaluate.plots_dir)
    paths = {
        "reliability_csv": write_csv(plots / "reliability.csv", reliability_rows(stage, evaluation)),
        "conditions_csv": write_csv(plots / "conditions.csv", condition_rows(stage, evaluation.table)),
        **{name: save_figure(fig, plots / "figures" / f"{name}.png") for name, fig in figures.items()},
        "metrics": write_record(stage.evaluate.out, evaluation.table),
    }
    log(cfg, stage, evaluation.table, paths)
    return evaluation.table
