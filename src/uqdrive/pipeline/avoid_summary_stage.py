"""The `avoid_summary` stage: metrics/avoid.json (every method's answer over its replicates per condition × warnings
mode and for the unknown mixture, beside the paper's numbers) and the paths of all methods coloured by uncertainty
(the paper's Figure "coll_avoid_main")."""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
from omegaconf import DictConfig

from uqdrive.analysis.method_answers import UNKNOWN, AvoidSummary, summarise_avoid
from uqdrive.analysis.plans import AvoidSummaryStage
from uqdrive.avoid.figure import avoid_trajectories_figure
from uqdrive.avoid.outputs import read_trace_panel
from uqdrive.avoid.plan import KNOWN
from uqdrive.avoid.results import AvoidResult, Mode, read_avoid_results
from uqdrive.figures import save_figure
from uqdrive.records import write_record
from uqdrive.schema import validate

COLUMNS = ((KNOWN, Mode.ON), ("unknown", Mode.OFF), ("unknown", Mode.ON), ("unknown", Mode.CALIBRATED))


def paths_figure(stage: AvoidSummaryStage, results: list[AvoidResult], summary: AvoidSummary) -> plt.Figure:
    """All methods' paths, every replicate's, coloured by mutual information: known with warnings on; the unknown
    conditions off, on and calibrated."""
    data_dir, panels = Path(stage.summary.data_dir), {}
    for method in stage.methods:
        for condition, mode in COLUMNS:
            paths = [
                data_dir
                / f"{r.method}-seed{r.replicate}"
                / "traces"
                / f"{r.method}-seed{r.replicate}-{name}-{mode}.npz"
                for r in results
                if r.method == method
                for name in ([KNOWN] if condition == KNOWN else r.conditions[1:])
            ]
            answer = summary.answer(method, KNOWN if condition == KNOWN else UNKNOWN, mode)
            panels[(method, f"{condition}, warnings {mode}")] = read_trace_panel(paths, answer.value)
    return avoid_trajectories_figure(
        panels,
        list(stage.methods),
        [f"{c}, warnings {m}" for c, m in COLUMNS],
        "Collision avoidance: paths coloured by mutual information, every replicate",
    )


def run_avoid_summary(cfg: DictConfig) -> AvoidSummary:
    """Every method's answers over its replicates beside the paper's numbers, and the paths figure."""
    stage = validate(AvoidSummaryStage, cfg)
    results = read_avoid_results(stage.summary.results_dir, list(stage.methods), list(stage.replicates))
    summary = summarise_avoid(results, list(stage.methods))
    save_figure(paths_figure(stage, results, summary), Path(stage.summary.figures_dir) / "coll_avoid_main.png")
    write_record(stage.summary.out, summary)
    return summary
