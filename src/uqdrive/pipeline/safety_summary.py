"""The `safety_summary` stage: each method's answer over its training replicates at every condition of the
offline-safety sweep (metrics/safety.json), and the paper's offline-safety figure per location and noise level."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from uqdrive.pipeline.configs import SafetyGrid
from uqdrive.pipeline.methods import summarise_methods
from uqdrive.pipeline.records import SafetyCell, read_safety_cells, write_record
from uqdrive.plots import safety_hexbin_grid, save_figure
from uqdrive.resolvers import noise_label
from uqdrive.schema import Str, schema, validate


@schema
class SafetySummarySection:
    cells_dir: Str
    positions_dir: Str
    out: Str
    figures_dir: Str


@schema(root=True)
class SafetySummaryStage(SafetyGrid):
    summary: SafetySummarySection


def run_safety_summary(cfg: DictConfig) -> dict:
    """Per method × condition, its answer over the replicates (metrics/safety.json: `SafetySummary`), and one
    method × weather grid of every replicate's paths per location and noise."""
    stage = validate(SafetySummaryStage, cfg)
    cells = read_safety_cells(cfg.summary.cells_dir, stage)
    summary = summarise_methods(cells, stage.methods)
    figures = []
    for location in stage.locations:
        for noise in stage.noises:
            panels = {}
            for method in stage.methods:
                for weather in stage.weathers:
                    members = [c for c in cells if (c.method, c.condition) == (method, (location, weather, noise))]
                    panels[(method, weather)] = _pooled_positions(Path(cfg.summary.positions_dir), members)
                    panels[(method, weather)]["eta1"] = summary.answer(method, location, weather, noise).value
            fig = safety_hexbin_grid(
                panels,
                list(stage.methods),
                list(stage.weathers),
                f"Closed-loop paths at {location}, sensor noise {noise:g}, every replicate",
            )
            figures.append(
                save_figure(fig, Path(cfg.summary.figures_dir) / f"hexbin_{location}_noise{noise_label(noise)}.png")
            )
    write_record(cfg.summary.out, summary)
    return {"summary": summary, "figures": [str(f) for f in figures]}


def _pooled_positions(folder: Path, cells: list[SafetyCell]) -> dict[str, np.ndarray]:
    """The visited positions of every replicate's cell at one condition, with the road of the first."""
    parts = []
    for cell in cells:
        with np.load(folder / f"{cell.name}.npz") as data:
            parts.append({k: data[k] for k in data.files})
    panel = dict(parts[0])
    panel["x"] = np.concatenate([p["x"] for p in parts])
    panel["y"] = np.concatenate([p["y"] for p in parts])
    return panel
