"""The `preprocess` stage: raw episodes of one experiment's scenarios → its train/val frames + class histogram."""

from __future__ import annotations

from pathlib import Path

import mlflow
import numpy as np
import pyarrow as pa
from omegaconf import DictConfig
from tqdm import tqdm

from uqdrive.data.preprocess import Split, class_histogram, preprocess_raw
from uqdrive.data.tables import PROCESSED_SCHEMA, RAW_SCHEMA, read_table, write_table_batches
from uqdrive.files import write_csv, write_json
from uqdrive.pipeline.configs import Experiment, Stage
from uqdrive.plots import class_histogram_figure, save_figure
from uqdrive.schema import OpenUnit, Seed, schema, validate
from uqdrive.tracking import stage_run


@schema
class PreprocessSection:
    val_fraction: OpenUnit
    split_seed: Seed


@schema(root=True)
class PreprocessStage(Stage):
    experiment: Experiment
    preprocess: PreprocessSection


def run_preprocess(cfg: DictConfig) -> dict:
    stage = validate(PreprocessStage, cfg)
    bins, scenarios = stage.experiment.bins, list(stage.experiment.scenarios)
    split = Split(val_fraction=stage.preprocess.val_fraction, seed=stage.preprocess.split_seed)
    raw_dir, out_dir = Path(cfg.paths.raw), Path(cfg.paths.processed)

    parts: dict[str, list[pa.Table]] = {"train": [], "val": []}
    steering = []
    for scenario in tqdm(scenarios, desc="preprocess", unit="scenario", disable=not cfg.progress):
        raw = read_table(raw_dir / f"{scenario}.parquet", RAW_SCHEMA)
        steering.append(raw.column("steering").to_numpy())
        train, val = preprocess_raw(raw, bins, split)
        parts["train"].append(train)
        parts["val"].append(val)
    steering_all = np.concatenate(steering)

    counts: dict[str, np.ndarray] = {}
    for name, tables in parts.items():
        table = pa.concat_tables(tables)
        write_table_batches(out_dir / f"{name}.parquet", PROCESSED_SCHEMA, [table.to_pydict()])
        counts[name] = class_histogram(table.column("label").to_numpy(), bins)

    metrics = {
        "experiment": cfg.experiment.name,
        "num_classes": bins.num_classes,
        # labels beyond the experiment's end classes by more than half a tenth: the class set should cover them
        "clipped_label_fraction": float(bins.clipped(steering_all).mean()),
        "steering_min": float(steering_all.min()),
        "steering_max": float(steering_all.max()),
        "train_frames": int(counts["train"].sum()),
        "val_frames": int(counts["val"].sum()),
        "majority_class_fraction": float(counts["train"].max() / max(counts["train"].sum(), 1)),
    }
    histogram_csv = write_csv(
        Path(cfg.paths.plots) / "class_histogram.csv",
        [
            {"class": k, "steering": f"{centre:+.1f}", "split": name, "frames": int(n)}
            for name, values in counts.items()
            for k, (centre, n) in enumerate(zip(bins.centres, values))
        ],
    )
    write_json(Path(cfg.paths.metrics) / "preprocess.json", metrics)

    with stage_run(cfg.paths.root, "preprocess", cfg, run_name=cfg.experiment.name):
        mlflow.log_metrics({k: v for k, v in metrics.items() if k != "experiment"})
        figure = save_figure(
            class_histogram_figure(bins.centres, counts, "steering classes"),
            Path(cfg.paths.plots) / "class_histogram.png",
        )
        mlflow.log_artifact(str(figure))
        mlflow.log_artifact(str(histogram_csv))
    return metrics
