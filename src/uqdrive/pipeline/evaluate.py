"""The `evaluate` stage: every method on held-out frames of each weather × noise level.

Per (method, condition) cell: accuracy, NLL, ECE and Brier score of the posterior predictive, the mean
mutual information and decision confidence η2 over the frames, and how well MI and 1 − η2 rank frames
with a wrong class above right ones (AUROC), and, when HMC (the asymptotically exact reference) is among the
methods, agreement with HMC's predictive on the same frames (keys `hmc_*`: total-variation distance, argmax
agreement, Spearman correlation of MI; HMC's own row compares two independent draw sets: the Monte-Carlo
noise floor). The frames are the `heldout` stage's autopilot frames
(conf/heldout.yaml), preprocessed exactly as the training frames were.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from pathlib import Path

import mlflow
import numpy as np
import torch
from omegaconf import DictConfig
from tqdm import tqdm

from uqdrive.data.binning import SteeringBins
from uqdrive.data.datasets import FrameSet, frames_from_table
from uqdrive.data.preprocess import Split, preprocess_raw
from uqdrive.data.tables import RAW_SCHEMA, read_table
from uqdrive.files import write_csv, write_json
from uqdrive.models.agreement import agreement_with_reference
from uqdrive.models.checkpoint import load_posterior
from uqdrive.models.metrics import classification_metrics, mistake_auroc, reliability_bins
from uqdrive.models.posterior import Posterior
from uqdrive.pipeline.configs import Experiment, Named, NonEmptyMethodNames, NonEmptyNames, NonEmptyNoises, Stage
from uqdrive.plots import condition_lines_figure, reliability_grid, save_figure
from uqdrive.resolvers import noise_label
from uqdrive.schema import Count, Positive, Str, schema, validate
from uqdrive.tracking import stage_run
from uqdrive.uq import frame_measures

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


@schema
class EvaluateSection:
    heldout_dir: Str
    samples: Count  # posterior draws per frame
    eps: Positive  # η2's ball, steering units
    batch_size: Count
    out: Str
    plots_dir: Str


@schema(root=True)
class EvaluateStage(Stage):
    experiment: Experiment
    scenario: Named  # where the held-out frames were collected
    methods: NonEmptyMethodNames
    weathers: NonEmptyNames
    noises: NonEmptyNoises
    evaluate: EvaluateSection


@dataclass(frozen=True)
class Condition:
    """One weather × noise cell; file names and keys format the noise as the heldout stage does (`noise_label`:
    0 and 0.0 are one level)."""

    weather: str
    noise: float

    @property
    def key(self) -> str:
        return f"noise{noise_label(self.noise)}"

    @property
    def label(self) -> str:
        return f"{self.weather} σ={self.noise:g}"

    def heldout_path(self, folder: Path, scenario: str) -> Path:
        return folder / f"{scenario}-{self.weather}-{self.key}.parquet"


def conditions_from(stage: EvaluateStage) -> list[Condition]:
    """weathers × noises."""
    return [Condition(w, n) for w in stage.weathers for n in stage.noises]


def check_inputs(cfg: DictConfig, methods: list[str], conditions: list[Condition]) -> dict[str, Path]:
    """Model file of each method; raises before any work, naming every missing file and how to make it."""
    models = {m: Path(cfg.paths.models) / m / f"{cfg.replicate}.pt" for m in methods}
    missing = [
        f"{path}: train it first (`python stages/train.py model={m} seed={cfg.seed}`, or dvc repro)"
        for m, path in models.items()
        if not path.exists()
    ]
    folder = Path(cfg.evaluate.heldout_dir)
    missing += [
        f"{c.heldout_path(folder, cfg.scenario.name)}: collect it first (`python stages/collect.py "
        f"--config-name heldout scenario={cfg.scenario.name} weather={c.weather} noise={c.noise}`, "
        f"or dvc repro heldout)"
        for c in conditions
        if not c.heldout_path(folder, cfg.scenario.name).exists()
    ]
    if missing:
        raise FileNotFoundError("evaluate is missing its inputs:\n  " + "\n  ".join(missing))
    return models


def load_heldout(path: Path, scenario: str, condition: Condition, bins: SteeringBins) -> FrameSet:
    """Held-out autopilot frames → network inputs and class labels, through the training preprocessing;
    refuses a file recorded in another scenario or condition than its name says."""
    raw = read_table(path, RAW_SCHEMA)
    recorded = {col: set(raw.column(col).to_pylist()) for col in ("scenario", "weather", "noise")}
    if (
        recorded["scenario"] != {scenario}
        or recorded["weather"] != {condition.weather}
        or not np.allclose(sorted(recorded["noise"]), [condition.noise], atol=1e-6)
    ):
        raise ValueError(
            f"{path} holds frames of scenario {sorted(recorded['scenario'])}, weather "
            f"{sorted(recorded['weather'])}, noise {sorted(recorded['noise'])}; expected {scenario}, "
            f"{condition.weather}, {condition.noise}: collect it again (dvc repro heldout)"
        )
    table, _ = preprocess_raw(raw, bins, Split(val_fraction=0.0))
    return frames_from_table(table, bins.num_classes, str(path))


def cell_generator(seed: int, method: str, condition: Condition) -> torch.Generator:
    """A cell's draws depend on the seed and its name only: adding a weather leaves the other cells as they were."""
    key = zlib.crc32(f"{method}-{condition.weather}-{condition.key}".encode())
    return torch.Generator().manual_seed(int(np.random.SeedSequence([seed, key]).generate_state(1)[0]))


@torch.no_grad()
def predict(
    posterior: Posterior, frames: FrameSet, settings: EvaluateSection, centres: np.ndarray, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Predictive probabilities [B, C], η2 [B] and mutual information [B] of every frame, batch by batch
    (only one batch's [samples, batch, C] draws are held at a time)."""
    probs, eta2, mi = [], [], []
    for x, _ in frames.batches(settings.batch_size):
        samples = posterior.sample_probs(x, settings.samples, generator)
        measures = frame_measures(samples, centres, settings.eps)
        probs.append(samples.mean(0))
        eta2.append(measures.eta2)
        mi.append(measures.mutual_information)
    return torch.cat(probs), torch.cat(eta2), torch.cat(mi)


def cell_metrics(probs: torch.Tensor, labels: torch.Tensor, eta2: torch.Tensor, mi: torch.Tensor) -> dict:
    """The metrics of one cell; an AUROC that is undefined (no wrong or no right frame) is None, with the reason."""
    wrong = probs.argmax(1) != labels
    mistakes = int(wrong.sum())
    aurocs = {"auroc_mi": mistake_auroc(mi, wrong), "auroc_one_minus_eta2": mistake_auroc(1 - eta2, wrong)}
    note = None
    if mistakes in (0, len(labels)):
        note = (
            f"AUROC undefined: {'no' if mistakes == 0 else 'every'} frame of {len(labels)} has a wrong class, "
            f"and ranking mistakes above right frames needs both"
        )
    return {
        **classification_metrics(probs, labels),
        "mean_mutual_information": float(mi.mean()),
        "mean_eta2": float(eta2.mean()),
        **{k: None if math.isnan(v) else v for k, v in aurocs.items()},
        "auroc_note": note,
        "frames": len(labels),
        "mistakes": mistakes,
    }


def _reliability_rows(series: str, method: str, condition: Condition, bins: dict[str, torch.Tensor]) -> list[dict]:
    """The non-empty bins of one cell's reliability diagram as CSV rows."""
    return [
        {
            "series": series,
            "method": method,
            "weather": condition.weather,
            "noise": condition.noise,
            "bin": k,
            "bin_low": float(bins["low"][k]),
            "bin_high": float(bins["high"][k]),
            "confidence": float(bins["confidence"][k]),
            "accuracy": float(bins["accuracy"][k]),
            "frames": int(bins["frames"][k]),
        }
        for k in torch.nonzero(bins["frames"]).flatten().tolist()
    ]


def write_outputs(
    cfg: DictConfig, table: dict, reliability: dict, methods: list[str], conditions: list[Condition]
) -> dict[str, Path]:
    """DVC plot data (reliability.csv: x=confidence, y=accuracy; conditions.csv: one row per method ×
    condition), the figures (a reliability grid per method, metrics along the conditions) and, last, the
    metrics JSON."""
    plots = Path(cfg.evaluate.plots_dir)
    series = {(m, c): f"{m} {c.weather} {c.key}" for m in methods for c in conditions}
    reliability_rows = [
        row for m in methods for c in conditions for row in _reliability_rows(series[m, c], m, c, reliability[m, c])
    ]
    condition_rows = [
        {
            "series": series[m, c],
            "method": m,
            "weather": c.weather,
            "noise": c.noise,
            **{k: v for k, v in table[m][c.weather][c.key].items() if k != "auroc_note"},
        }
        for m in methods
        for c in conditions
    ]
    outputs = {
        "reliability_csv": write_csv(plots / "reliability.csv", reliability_rows),
        "conditions_csv": write_csv(plots / "conditions.csv", condition_rows),
    }
    weathers = list(dict.fromkeys(c.weather for c in conditions))
    noises = list(dict.fromkeys(c.key for c in conditions))
    for m in methods:
        panels = {
            (c.key, c.weather): {
                **{k: v.numpy() for k, v in reliability[m, c].items()},
                "ece": table[m][c.weather][c.key]["ece"],
            }
            for c in conditions
        }
        fig = reliability_grid(
            panels, noises, weathers, f"{m}: reliability on held-out frames at the {cfg.scenario.name}"
        )
        outputs[f"reliability_{m}"] = save_figure(fig, plots / "figures" / f"reliability_{m}.png")
    lines = {m: {k: [table[m][c.weather][c.key][k] for c in conditions] for k, _ in PLOTTED} for m in methods}
    fig = condition_lines_figure(
        lines,
        [c.label for c in conditions],
        PLOTTED,
        f"Held-out frames at the {cfg.scenario.name}: methods across weather × sensor noise",
    )
    outputs["conditions_png"] = save_figure(fig, plots / "figures" / "conditions.png")
    if REFERENCE in methods:
        agreement = {
            m: {k: [table[m][c.weather][c.key][k] for c in conditions] for k, _ in AGREEMENT_PLOTTED} for m in methods
        }
        fig = condition_lines_figure(
            agreement,
            [c.label for c in conditions],
            AGREEMENT_PLOTTED,
            f"Agreement with HMC on held-out frames at the {cfg.scenario.name} (hmc: two independent draw sets)",
        )
        outputs["agreement_png"] = save_figure(fig, plots / "figures" / f"agreement_{REFERENCE}.png")
    write_json(cfg.evaluate.out, table)
    outputs["metrics"] = Path(cfg.evaluate.out)
    return outputs


def run_evaluate(cfg: DictConfig) -> dict:
    """Evaluate every method of `methods` on the held-out frames of every weather × noise; returns the table,
    the output paths and the MLflow run id of each method."""
    stage = validate(EvaluateStage, cfg)
    settings, bins, methods = stage.evaluate, stage.experiment.bins, list(stage.methods)
    conditions = conditions_from(stage)
    model_paths = check_inputs(cfg, methods, conditions)
    posteriors = {m: load_posterior(path, expected_method=m, expected_classes=bins) for m, path in model_paths.items()}
    folder = Path(cfg.evaluate.heldout_dir)
    frames = {
        c: load_heldout(c.heldout_path(folder, cfg.scenario.name), cfg.scenario.name, c, bins)
        for c in tqdm(conditions, desc="evaluate: load frames", unit="condition", disable=not cfg.progress)
    }

    table: dict = {}
    reliability: dict = {}
    cells = [(m, c) for m in methods for c in conditions]
    predictives = {}
    for m, c in tqdm(cells, desc="evaluate", unit="cell", disable=not cfg.progress):
        probs, eta2, mi = predict(posteriors[m], frames[c], settings, bins.centres, cell_generator(int(cfg.seed), m, c))
        table.setdefault(m, {}).setdefault(c.weather, {})[c.key] = cell_metrics(probs, frames[c].labels, eta2, mi)
        reliability[m, c] = reliability_bins(probs, frames[c].labels)
        predictives[m, c] = probs, mi
    if REFERENCE in methods:
        for m, c in cells:
            probs, mi = predictives[m, c]
            if m == REFERENCE:  # against a second, independent set of HMC draws: the noise floor
                probs, _, mi = predict(
                    posteriors[m], frames[c], settings, bins.centres, cell_generator(int(cfg.seed), f"{m}-repeat", c)
                )
            agreement = agreement_with_reference(probs, mi, *predictives[REFERENCE, c])
            table[m][c.weather][c.key].update({f"{REFERENCE}_{k}": v for k, v in agreement.items()})
    outputs = write_outputs(cfg, table, reliability, methods, conditions)

    shared = [
        outputs[k]
        for k in ("metrics", "conditions_csv", "reliability_csv", "conditions_png", "agreement_png")
        if k in outputs
    ]
    runs = {}
    for m in methods:
        with stage_run(cfg.paths.root, "evaluate", cfg, run_name=f"{m}-{cfg.replicate}") as run:
            mlflow.log_param("method", m)
            mlflow.log_metrics(
                {
                    f"{weather}/{key}/{name}": float(value)
                    for weather, by_noise in table[m].items()
                    for key, cell in by_noise.items()
                    for name, value in cell.items()
                    if isinstance(value, (int, float))
                }
            )
            for path in (outputs[f"reliability_{m}"], *shared):
                mlflow.log_artifact(str(path))
        runs[m] = run.info.run_id
    return {"table": table, "outputs": {k: str(v) for k, v in outputs.items()}, "mlflow_runs": runs}
