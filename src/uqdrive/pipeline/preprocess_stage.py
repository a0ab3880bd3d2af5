"""The `preprocess` stage: raw episodes of one experiment's scenarios → its train/val frames + class histogram."""

from __future__ import annotations

from pathlib import Path

import mlflow
import numpy as np
import pyarrow as pa
from omegaconf import DictConfig
from tqdm import tqdm

from uqdrive.data.figure import class_histogram_figure
from uqdrive.data.preprocess import Preprocessed, Split, class_histogram, preprocess_raw
from uqdrive.data.preprocess_plan import PreprocessStage
from uqdrive.data.tables import PROCESSED_SCHEMA, RAW_SCHEMA, read_table, write_table_batches
from uqdrive.figures import save_figure
from uqdrive.files import write_csv
from uqdrive.records import as_dict, write_record
from uqdrive.schema import validate
from uqdrive.tracking import stage_run


def split_frames(stage: PreprocessStage) -> tuple[dict[str, pa.Table], np.ndarray]:
    """Every scenario's raw frames, preprocessed and split into train and val; and every raw steering label."""
    bins = stage.experiment.bins
    split = Split(val_fraction=stage.preprocess.val_fraction, seed=stage.preprocess.split_seed)
    parts: dict[str, list[pa.Table]] = {"train": [], "val": []}
    steering = []
    for scenario in tqdm(stage.experiment.scenarios, desc="preprocess", unit="scenario", disable=not stage.progress):
        raw = read_table(Path(stage.paths.raw) / f"{scenario}.parquet", RAW_SCHEMA)
        steering.append(raw.column("steering").to_numpy())
        train, val = preprocess_raw(raw, bins, split)
        parts["train"].append(train)
        parts["val"].append(val)
    return {name: pa.concat_tables(tables) for name, tables in parts.items()}, np.concatenate(steering)


def run_preprocess(cfg: DictConfig) -> Preprocessed:
    """Split and preprocess, count the classes, plot their histogram, write the frames and the metrics, log."""
    stage = validate(PreprocessStage, cfg)
    bins, plots = stage.experiment.bins, Path(stage.paths.plots)
    tables, steering = split_frames(stage)
    counts = {name: class_histogram(table.column("label").to_numpy(), bins) for name, table in tables.items()}
    metrics = Preprocessed(
        experiment=stage.experiment.name,
        num_classes=bins.num_classes,
        clipped_label_fraction=float(bins.clipped(steering).mean()),
        steering_min=float(steering.min()),
        steering_max=float(steering.max()),
        train_frames=int(counts["train"].sum()),
        val_frames=int(counts["val"].sum()),
        majority_class_fraction=float(counts["train"].max() / max(counts["train"].sum(), 1)),
    )
    figure = class_histogram_figure(bins.centres, counts, "steering classes")
    for name, table in tables.items():
        write_table_batches(Path(stage.paths.processed) / f"{name}.parquet", PROCESSED_SCHEMA, [table.to_pydict()])
    histogram_csv = write_csv(
        plots / "class_histogram.csv",
        [
            {"class": k, "steering": f"{centre:+.1f}", "split": name, "frames": int(n)}
            for name, values in counts.items()
            for k, (centre, n) in enumerate(zip(bins.centres, values))
        ],
    )
    figure_png = save_figure(figure, plots / "class_histogram.png")
    write_record(Path(stage.paths.metrics) / "preprocess.json", metrics)
    with stage_run(stage.paths.root, "preprocess", cfg, run_name=stage.experiment.name):
        mlflow.log_metrics({k: v for k, v in as_dict(metrics).items() if k != "experiment"})
        mlflow.log_artifact(str(figure_png))
        mlflow.log_artifact(str(histogram_csv))
    return metrics
