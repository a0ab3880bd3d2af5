"""The report from the run's records: read every stage's record, then the sections in order — the answer first,
then every table and figure of the paper with ours beside it."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from uqdrive.analysis.acquisition_summary import AcquisitionSummary
from uqdrive.analysis.comparisons import Findings
from uqdrive.analysis.method_answers import AvoidSummary, SafetySummary
from uqdrive.avoid.results import read_avoid_results
from uqdrive.data.preprocess import Preprocessed
from uqdrive.envelope.map_records import EnvelopeResult
from uqdrive.models.heldout_eval import HeldoutTable
from uqdrive.records import read_record
from uqdrive.report.acquisition_section import acquisition_section
from uqdrive.report.answer import answer_markdown
from uqdrive.report.document import Report
from uqdrive.report.envelope_section import envelope_section, read_envelopes
from uqdrive.report.failure_gallery import failures_section
from uqdrive.report.findings_text import findings_markdown
from uqdrive.report.headline import Headline, headline_table
from uqdrive.report.heldout_section import heldout_section
from uqdrive.report.overview import Scope, run_section, sample_counts_section, title_section
from uqdrive.report.sections import (
    Run,
    avoid_section,
    conditions_of,
    fidelity_section,
    learning_curves_section,
    read_train_metrics,
    safety_section,
    training_section,
)
from uqdrive.resolvers import condition_label
from uqdrive.safety.cell_records import read_safety_cells


@dataclasses.dataclass(frozen=True)
class Records:
    """Everything the report reads: the run's closed-loop and training records, the findings, the held-out table,
    the envelopes, the acquisition."""

    run: Run
    findings: Findings
    evaluated: HeldoutTable
    envelopes: list[EnvelopeResult]
    acquisition: AcquisitionSummary


def read_records(metrics_dir: Path, scope: Scope) -> Records:
    seeds = list(scope.grid.replicates)
    classes = {
        e: read_record(Preprocessed, metrics_dir / e / "preprocess.json", f"preprocess@{e}").num_classes
        for e in scope.experiments
    }
    run = Run(
        trained=read_train_metrics(metrics_dir, list(scope.experiments), list(scope.posteriors), seeds),
        classes=classes,
        cells=read_safety_cells(metrics_dir / "safety", scope.grid),
        safety=read_record(SafetySummary, metrics_dir / "safety.json", "safety_summary"),
        avoided=read_avoid_results(metrics_dir / "avoid", list(scope.grid.methods), seeds),
        avoid=read_record(AvoidSummary, metrics_dir / "avoid.json", "avoid_summary"),
    )
    return Records(
        run,
        read_record(Findings, metrics_dir / "findings.json", "findings"),
        read_record(HeldoutTable, metrics_dir / "evaluate.json", "evaluate"),
        read_envelopes(metrics_dir, list(scope.grid.methods), seeds[0]),
        read_record(AcquisitionSummary, metrics_dir / "acquisition.json", "acquire_summary"),
    )


def build_report(root: Path, out_dir: Path, scope: Scope, records: Records, headline: Headline, chart: Path) -> Report:
    """The answer first (generated), the contents, the paper's claims and the findings, the paper's numbers beside
    ours, every experiment's tables and figures, what was run; learning curves last. ``chart``: η̂1 per condition."""
    grid = scope.grid
    run, methods, training = records.run, list(grid.methods), (grid.locations[0], scope.train_weather, 0.0)
    report = Report(root, out_dir)
    title_section(report, scope.note)
    report.add(
        "## The answer\n\n"
        + answer_markdown(headline, run.safety, records.findings, methods, condition_label(*training))
    )
    sweep = dict(
        locations=grid.locations, train_weather=scope.train_weather, weathers=grid.weathers, noises=grid.noises
    )
    report.add(headline_table(headline, sweep))
    report.figure(chart, "η̂1 per condition, each method's mean over its replicates with the interval for the method")
    report.add_contents()
    report.add("## The paper's claims and what the run found\n\n" + findings_markdown(records.findings))
    fidelity_section(report, run, methods, list(grid.weathers), grid.locations[0])
    conditions = conditions_of(grid.locations, grid.weathers, grid.noises)
    safety_section(report, run, methods, conditions)
    failures_section(report, run.cells, root / "data" / "safety" / "clips", root / "metrics" / "safety", conditions)
    acquisition_section(report, records.acquisition)
    avoid_section(report, run, methods)
    envelope_section(report, records.envelopes)
    heldout_section(report, records.evaluated, scope.posteriors, grid.weathers, grid.noises, grid.replicates[0])
    training_section(report, run, list(scope.experiments), list(scope.posteriors), list(grid.replicates))
    run_section(report, scope, run.cells)
    sample_counts_section(report, run.cells)
    learning_curves_section(report, list(scope.experiments), list(scope.posteriors), list(grid.replicates))
    return report
