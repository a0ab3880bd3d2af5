"""The `preprocess` stage: raw episodes of every scenario → train/val frames + class histogram."""

from __future__ import annotations

from pathlib import Path

import mlflow
import numpy as np
import pyarrow as pa
from omegaconf import DictConfig
from tqdm import tqdm

from uqdrive.data.binning import SteeringBins
from uqdrive.data.preprocess import Split, class_histogram, preprocess_raw
from uqdrive.data.tables import PROCESSED_SCHEMA, RAW_SCHEMA, read_table, write_table_batches
from uqdrive.files import write_csv, write_json
from uqdrive.plots import class_histogram_figure, save_figure
from uqdrive.tracking import stage_run


def run_preprocess(cfg: DictConfig) -> dict:
    bins = SteeringBins(**cfg.bins)
    split = Split(val_fraction=cfg.preprocess.val_fraction, seed=cfg.preprocess.split_seed)
    raw_dir, out_dir = Path(cfg.paths.raw), Path(cfg.paths.processed)
    if not cfg.scenarios:
        raise ValueError("scenarios=[] is empty: name at least one collected scenario")

    parts: dict[str, list[pa.Table]] = {"train": [], "val": []}
    for scenario in tqdm(list(cfg.scenarios), desc="preprocess", unit="scenario", disable=not cfg.progress):
        train, val = preprocess_raw(read_table(raw_dir / f"{scenario}.parquet", RAW_SCHEMA), bins, split)
        parts["train"].append(train)
        parts["val"].append(val)

    counts: dict[str, np.ndarray] = {}
    for name, tables in parts.items():
        table = pa.concat_tables(tables)
        write_table_batches(out_dir / f"{name}.parquet", PROCESSED_SCHEMA, [table.to_pydict()])
        counts[name] = class_histogram(table.column("label").to_numpy(), bins)

    metrics = {
        "num_classes": bins.num_classes,
        "train_frames": int(counts["train"].sum()),
        "val_frames": int(counts["val"].sum()),
        "majority_class_fraction": float(counts["train"].max() / max(counts["train"].sum(), 1)),
    }
    histogram_csv = write_csv(Path(cfg.paths.plots) / "class_histogram.csv", [
        {"class": k, "steering": f"{centre:+.1f}", "split": name, "frames": int(n)}
        for name, values in counts.items() for k, (centre, n) in enumerate(zip(bins.centres, values))])
    write_json(Path(cfg.paths.metrics) / "preprocess.json", metrics)

    with stage_run(cfg.paths.root, "preprocess", cfg, run_name="preprocess"):
        mlflow.log_metrics(metrics)
        figure = save_figure(class_histogram_figure(bins.centres, counts, "steering classes"),
                             Path(cfg.paths.plots) / "class_histogram.png")
        mlflow.log_artifact(str(figure))
        mlflow.log_artifact(str(histogram_csv))
    return metrics
