"""The `avoid_summary` stage: metrics/avoid.json (every method's cells, unknown mixtures and calibration
beside the paper's numbers) and the paths of all methods coloured by uncertainty (the paper's Figure
"coll_avoid_main")."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from uqdrive import paper
from uqdrive.files import write_json
from uqdrive.pipeline.configs import NonEmptyNames, Stage
from uqdrive.plots import avoid_trajectories_figure, save_figure
from uqdrive.schema import Str, schema, validate

SUMMARY_KEYS = (
    "eta1",
    "eta1_low",
    "eta1_high",
    "n",
    "autonomy",
    "full_speed_fraction",
    "collision_rate",
    "off_road_rate",
    "passed_rate",
    "timeout_before_obstacle_rate",
    "handover_distance_min",
    "handover_distance_median",
    "warning0_runs",
    "warning1_runs",
    "warning2_runs",
    "thresholds",
)
COLUMNS = (("known", "on"), ("unknown", "off"), ("unknown", "on"), ("unknown", "calibrated"))


@schema
class AvoidSummarySection:
    results_dir: Str
    data_dir: Str
    out: Str
    figures_dir: Str


@schema(root=True)
class AvoidSummaryStage(Stage):
    methods: NonEmptyNames
    summary: AvoidSummarySection


def run_avoid_summary(cfg: DictConfig) -> dict:
    """Every method's cells and calibration beside the paper's numbers, and one figure of all methods'
    paths (known with warnings on; the unknown conditions off, on and calibrated)."""
    validate(AvoidSummaryStage, cfg)
    results_dir, data_dir = Path(cfg.summary.results_dir), Path(cfg.summary.data_dir)
    table: dict = {"paper": paper.to_dict()}
    panels = {}
    for method in cfg.methods:
        path = results_dir / f"{method}.json"
        if not path.exists():
            raise FileNotFoundError(
                f"{path} is missing; run `python stages/avoid.py model={method}` (or dvc repro) first"
            )
        result = json.loads(path.read_text())
        table[method] = {
            "cells": {
                c: {m: {k: v for k, v in cell.items() if k in SUMMARY_KEYS} for m, cell in modes.items()}
                for c, modes in result["cells"].items()
            },
            "unknown": result["unknown"],
            "calibration": result["calibration"],
            "samples_per_frame": result["samples_per_frame"],
        }
        unknown = result["conditions"][1:]
        for condition, mode in COLUMNS:
            names = ["known"] if condition == "known" else unknown
            panels[(method, f"{condition}, warnings {mode}")] = _panel_from_data(
                [data_dir / method / "traces" / f"{method}-{name}-{mode}.npz" for name in names],
                result["cells"]["known"][mode]["eta1"] if condition == "known" else result["unknown"][mode]["eta1"],
            )
    fig = avoid_trajectories_figure(
        panels,
        list(cfg.methods),
        [f"{c}, warnings {m}" for c, m in COLUMNS],
        "Collision avoidance: paths coloured by mutual information",
    )
    figure = save_figure(fig, Path(cfg.summary.figures_dir) / "coll_avoid_main.png")
    write_json(cfg.summary.out, table)
    return {"table": table, "figures": [str(figure)]}


def _panel_from_data(paths: list[Path], eta1: float) -> dict:
    """The paths of one or more cells' trace files in one panel."""
    runs = []
    for path in paths:
        with np.load(path) as data:
            rollout = data["rollout"]
            runs += [
                {
                    "x": data["x"][rollout == i],
                    "y": data["y"][rollout == i],
                    "mi": data["mi"][rollout == i],
                    "termination": str(t),
                }
                for i, t in enumerate(data["termination"])
            ]
            obstacle, road = data["obstacle"], data["road"]
    return {"paths": runs, "obstacle": obstacle, "road": road, "title": f"η̂1 = {eta1:.2f}"}
