"""The `safety_summary` stage: each method's answer over its training replicates at every condition of the
offline-safety sweep (metrics/safety.json), and the paper's offline-safety figure per location and noise level."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from omegaconf import DictConfig

from uqdrive.analysis.failure_modes import failure_modes, modes_table
from uqdrive.analysis.method_answers import SafetySummary, summarise_methods
from uqdrive.analysis.plans import SafetySummaryStage
from uqdrive.figures import save_figure
from uqdrive.files import write_csv
from uqdrive.records import write_record
from uqdrive.resolvers import noise_label
from uqdrive.safety.cell_records import SafetyCell, read_safety_cells
from uqdrive.safety.figure import safety_hexbin_grid
from uqdrive.safety.positions import read_positions
from uqdrive.schema import validate


def pooled_positions(folder: Path, cells: list[SafetyCell], eta1: float) -> dict[str, np.ndarray]:
    """The visited positions of every replicate's cell at one condition on the road of the first: a figure panel."""
    parts = [read_positions(folder / f"{cell.name}.npz") for cell in cells]
    panel = dataclasses.asdict(parts[0])
    panel["x"] = np.concatenate([p.x for p in parts])
    panel["y"] = np.concatenate([p.y for p in parts])
    panel["eta1"] = eta1
    return panel


def hexbin_figures(stage: SafetySummaryStage, cells: list[SafetyCell], summary: SafetySummary) -> dict[str, plt.Figure]:
    """Per location and noise level, a method × weather grid of every replicate's paths (the paper's figure)."""
    folder, figures = Path(stage.summary.positions_dir), {}
    for location in stage.locations:
        for noise in stage.noises:
            panels = {
                (method, weather): pooled_positions(
                    folder,
                    [c for c in cells if (c.method, c.condition) == (method, (location, weather, noise))],
                    summary.answer(method, location, weather, noise).value,
                )
                for method in stage.methods
                for weather in stage.weathers
            }
            title = f"Closed-loop paths at {location}, sensor noise {noise:g}, every replicate"
            fig = safety_hexbin_grid(panels, list(stage.methods), list(stage.weathers), title)
            figures[f"hexbin_{location}_noise{noise_label(noise)}"] = fig
    return figures


def run_safety_summary(cfg: DictConfig) -> SafetySummary:
    """Per method × condition, its answer over the replicates (metrics/safety.json), and the hexbin figures."""
    stage = validate(SafetySummaryStage, cfg)
    cells = read_safety_cells(stage.summary.cells_dir, stage)
    summary = summarise_methods(cells, stage.methods)
    for name, fig in hexbin_figures(stage, cells, summary).items():
        save_figure(fig, Path(stage.summary.figures_dir) / f"{name}.png")
    write_failure_modes(Path(stage.summary.failure_modes), cells)
    write_record(stage.summary.out, summary)
    return summary


def write_failure_modes(path: Path, cells: list[SafetyCell]) -> Path:
    """Each method's failure modes at each weather as a CSV (`dvc plots`: a bar per mode); a sweep with no failure
    writes one row that says so, so the plot still shows the answer."""
    rows = modes_table(failure_modes(cells, "method_weather"))
    none = {"label": "no failing rollout in any cell", "group": "", "mode": "", "cause": "", "segment": ""}
    none |= {"warned": False, "count": 0, "share": 0.0, "failures": 0, "rollouts": sum(len(c.outcomes) for c in cells)}
    return write_csv(path, rows or [none | {"worst_cell": "", "worst_seed": ""}])
