"""The `report` stage: the findings first, then every table and figure of this run beside the paper's numbers.

Reads only the stages' records and figures (the DVC outputs), so the report is a pure function of what this run
produced and `dvc repro` rebuilds it whenever any of them changes. Writes `reports/report.md` (figures linked), a
self-contained `reports/report.html` (figures embedded) and metrics/summary.json, and logs the report to MLflow.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mlflow
from omegaconf import DictConfig

from uqdrive.files import atomic_path
from uqdrive.records import write_record
from uqdrive.report.assemble import build_report, read_records
from uqdrive.report.overview import Headline, Scope, headline_metrics
from uqdrive.schema import Str, schema, validate
from uqdrive.stage_schemas import NonEmptyNames, SafetyGrid
from uqdrive.tracking import stage_run


@schema
class ReportSection:
    out_dir: Str
    summary: Str


@schema(root=True)
class ReportStage(SafetyGrid):
    profile_name: Str
    experiments: NonEmptyNames
    train_weather: Str
    posteriors: NonEmptyNames
    report: ReportSection


@dataclasses.dataclass(frozen=True)
class ReportFiles:
    """The report's files and how many figures it embeds; ``headline``: metrics/summary.json."""

    markdown: Path
    html: Path
    figures: int
    headline: Headline


def run_report(cfg: DictConfig) -> ReportFiles:
    """Read the records, build the report and the headline numbers, write them, log the report."""
    stage = validate(ReportStage, cfg)
    scope = Scope(
        stage.profile_name,
        tuple(stage.experiments),
        stage.train_weather,
        tuple(stage.posteriors),
        tuple(stage.methods),
        tuple(stage.replicates),
        tuple(stage.weathers),
        tuple(stage.noises),
        tuple(stage.locations),
    )
    records = read_records(Path(stage.paths.metrics), scope)
    out_dir = Path(stage.report.out_dir)
    report = build_report(Path(stage.paths.root), out_dir, scope, records)
    headline = headline_metrics(scope, records.run, records.findings)
    md_path, html_path = out_dir / "report.md", out_dir / "report.html"
    with atomic_path(md_path) as tmp:
        tmp.write_text(report.markdown)
    with atomic_path(html_path) as tmp:
        tmp.write_text(report.html())
    write_record(stage.report.summary, headline, sort_keys=False)  # the comparison keys first in `dvc exp show`
    with stage_run(stage.paths.root, "report", cfg, run_name="report"):
        mlflow.log_artifact(str(md_path))
        mlflow.log_artifact(str(html_path))
    return ReportFiles(md_path, html_path, len(report.figures), headline)
