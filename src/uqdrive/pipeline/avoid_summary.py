"""The `avoid_summary` stage: metrics/avoid.json (every method's answer over its replicates per condition × warnings
mode and for the unknown mixture, beside the paper's numbers) and the paths of all methods coloured by uncertainty
(the paper's Figure "coll_avoid_main")."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from uqdrive.pipeline.configs import NonEmptyNames, NonEmptySeeds, Stage
from uqdrive.pipeline.methods import UNKNOWN, summarise_avoid
from uqdrive.pipeline.records import read_avoid_results, write_record
from uqdrive.plots import avoid_trajectories_figure, save_figure
from uqdrive.schema import Str, schema, validate

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
    replicates: NonEmptySeeds
    summary: AvoidSummarySection


def run_avoid_summary(cfg: DictConfig) -> dict:
    """Every method's answers over its replicates beside the paper's numbers, and one figure of all methods'
    paths, every replicate's (known with warnings on; the unknown conditions off, on and calibrated)."""
    stage = validate(AvoidSummaryStage, cfg)
    results = read_avoid_results(cfg.summary.results_dir, list(stage.methods), list(stage.replicates))
    summary = summarise_avoid(results, list(stage.methods))
    data_dir = Path(cfg.summary.data_dir)
    panels = {}
    for method in stage.methods:
        for condition, mode in COLUMNS:
            paths = [
                data_dir
                / f"{r.method}-seed{r.replicate}"
                / "traces"
                / f"{r.method}-seed{r.replicate}-{name}-{mode}.npz"
                for r in results
                if r.method == method
                for name in (["known"] if condition == "known" else r.conditions[1:])
            ]
            answer = summary.answer(method, "known" if condition == "known" else UNKNOWN, mode)
            panels[(method, f"{condition}, warnings {mode}")] = _panel_from_data(paths, answer.value)
    fig = avoid_trajectories_figure(
        panels,
        list(stage.methods),
        [f"{c}, warnings {m}" for c, m in COLUMNS],
        "Collision avoidance: paths coloured by mutual information, every replicate",
    )
    figure = save_figure(fig, Path(cfg.summary.figures_dir) / "coll_avoid_main.png")
    write_record(cfg.summary.out, summary)
    return {"summary": summary, "figures": [str(figure)]}


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
