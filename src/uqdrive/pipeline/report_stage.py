"""The `report` stage: the answer first, then every table and figure of this run beside the paper's numbers.

Reads only the stages' records and figures (the DVC outputs), so the report is a pure function of what this run
produced and `dvc repro` rebuilds it whenever any of them changes. Writes `reports/report.md` (figures linked), a
self-contained `reports/report.html` (figures embedded), metrics/summary.json and the plot data under
plots/report/ (η̂1 per condition, learning curves, envelope maps), and logs the report to MLflow.
"""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import mlflow
from omegaconf import DictConfig

from uqdrive.analysis.method_answers import SafetySummary
from uqdrive.figures import save_figure
from uqdrive.files import atomic_path, write_csv, write_json
from uqdrive.report.assemble import build_report, read_records
from uqdrive.report.figure import eta1_intervals_figure
from uqdrive.report.headline import headline_metrics, summary_keys
from uqdrive.report.overview import Scope
from uqdrive.report.plan import ReportFiles, ReportStage
from uqdrive.schema import validate
from uqdrive.stage_schemas import training_stage
from uqdrive.tracking import stage_run


def write_eta1_chart(plots: Path, safety: SafetySummary, methods: list[str]) -> Path:
    """plots/report/eta1.csv (`dvc plots`) and eta1.png (the report): each method's η̂1 per condition, with its
    interval."""
    rows = [
        {"method": a.method, "condition": a.condition, "eta1": a.value, "eta1_low": a.low, "eta1_high": a.high}
        for a in safety.answers
        if a.method in methods
    ]
    write_csv(plots / "eta1.csv", rows)
    return save_figure(eta1_intervals_figure(rows, methods), plots / "eta1.png")


def write_learning_curves(root: Path, plots: Path, scope: Scope) -> Path:
    """plots/report/learning_curves.csv: every trained controller's validation accuracy per step, a panel per
    experiment · method and a line per replicate, so `dvc plots` shows each curve once, titled (not a plot per file
    named by its path, and its PNG again)."""
    rows = []
    for experiment in scope.experiments:
        for method in scope.posteriors:
            for replicate in scope.grid.replicates:
                path = root / "plots" / experiment / "train" / method / f"seed{replicate}_curve.csv"
                if not path.exists():
                    stage = training_stage(experiment, method)
                    raise FileNotFoundError(f"{path} is missing; run the stage that writes it first: dvc repro {stage}")
                with path.open() as f:
                    rows += [
                        {
                            "panel": f"{experiment} · {method}",
                            "replicate": f"seed{replicate}",
                            "step": int(float(row["step"])),
                            "val_accuracy": float(row["val_accuracy"]),
                        }
                        for row in csv.DictReader(f)
                    ]
    return write_csv(plots / "learning_curves.csv", rows)


def copy_envelope_maps(root: Path, plots: Path, methods: tuple[str, ...], seed: int) -> Path:
    """plots/report/envelope/<method>-seed<r>.png: the envelope maps where `dvc plots` shows images (the envelope
    stage's folder also holds its tables); a map the run lacks is named missing in the report."""
    folder = plots / "envelope"
    folder.mkdir(parents=True, exist_ok=True)
    for method in methods:
        found = root / "plots" / "envelope" / f"{method}-seed{seed}" / "map.png"
        if found.exists():
            shutil.copyfile(found, folder / f"{method}-seed{seed}.png")
    return folder


def run_report(cfg: DictConfig) -> ReportFiles:
    """Read the records, build the report and the headline numbers, write them, log the report."""
    stage = validate(ReportStage, cfg)
    scope = Scope(
        stage.profile_name,
        tuple(stage.experiments),
        stage.train_weather,
        tuple(stage.posteriors),
        stage,
        stage.profile_note,
    )
    records = read_records(Path(stage.paths.metrics), scope)
    out_dir = Path(stage.report.out_dir)
    headline = headline_metrics(scope, records.run, records.findings)
    root, plots = Path(stage.paths.root), Path(stage.paths.plots) / "report"
    chart = write_eta1_chart(plots, records.run.safety, list(scope.grid.methods))
    write_learning_curves(root, plots, scope)
    copy_envelope_maps(root, plots, scope.grid.methods, scope.grid.replicates[0])
    report = build_report(root, out_dir, scope, records, headline, chart)
    md_path, html_path = out_dir / "report.md", out_dir / "report.html"
    with atomic_path(md_path) as tmp:
        tmp.write_text(report.markdown)
    with atomic_path(html_path) as tmp:
        tmp.write_text(report.html())
    write_json(stage.report.summary, summary_keys(headline), sort_keys=False)  # the answer first in `dvc exp show`
    with stage_run(stage.paths.root, "report", cfg, run_name="report"):
        mlflow.log_artifact(str(md_path))
        mlflow.log_artifact(str(html_path))
    return ReportFiles(md_path, html_path, len(report.figures), headline)
