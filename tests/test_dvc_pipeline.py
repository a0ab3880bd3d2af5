"""`dvc repro` end to end on the tiny profile, in a copy of the project: the README's main command."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml
from conftest import dvc, project_copy
from rendered_plots import chromium, problems, render
from test_report import markdown_rows

from uqdrive.analysis.acquisition_summary import AcquisitionSummary
from uqdrive.analysis.method_answers import AvoidSummary, SafetySummary
from uqdrive.models.heldout_eval import HeldoutTable
from uqdrive.pipeline.findings_stage import Findings
from uqdrive.records import read_record
from uqdrive.report.document import fmt
from uqdrive.report.findings_text import findings_markdown

ROOT = Path(__file__).resolve().parents[1]


def _git(project: Path, *args: str) -> None:
    subprocess.run(["git", *args], cwd=project, check=True, capture_output=True, timeout=120)


def _metrics_of_experiments(shown: object) -> list[dict]:
    """The `metrics/summary.json` data of every experiment in `dvc exp show --json` (found wherever it nests)."""
    found = []
    if isinstance(shown, dict):
        if "metrics/summary.json" in shown and isinstance(shown["metrics/summary.json"], dict):
            found.append(shown["metrics/summary.json"].get("data", {}))
        for value in shown.values():
            found += _metrics_of_experiments(value)
    elif isinstance(shown, list):
        for value in shown:
            found += _metrics_of_experiments(value)
    return found


@pytest.mark.slow
def test_dvc_repro_builds_every_stage_then_is_up_to_date(tmp_path):
    project = project_copy(
        tmp_path,
        profile="tiny",
        heads=["vi"],  # trained and evaluated, not driven: every trained posterior is evaluated
        methods=["mcd"],  # one driven method: the closed-loop stages' wiring, not method-vs-method (test_findings)
        replicates=[0, 1],
        weathers=["rain"],
        noises=[0.0],
        locations=["roundabout"],
    )
    _git(project, "init", "-q")
    for key, value in (("user.name", "uqdrive test"), ("user.email", "test@localhost")):  # dvc exp commits need one
        _git(project, "config", key, value)
    dvc(project, "init", "-q")
    shutil.copytree(ROOT / ".dvc/plots", project / ".dvc/plots")  # the project's plot templates

    dvc(project, "repro", timeout=1800)
    for scenario in ("obstacle", "roundabout"):
        assert (project / f"data/raw/{scenario}.parquet").exists()
        assert json.loads((project / f"metrics/collect/{scenario}.json").read_text())["frames"] > 0
    for experiment in ("avoid", "offline"):  # one controller per experiment × method, each on its own class set
        metrics = json.loads((project / f"metrics/{experiment}/preprocess.json").read_text())
        classes = yaml.safe_load((project / f"conf/experiment/{experiment}.yaml").read_text())["bins"]
        assert (
            metrics["train_frames"] > 0 and metrics["num_classes"] == round((classes["high"] - classes["low"]) * 10) + 1
        )
        for method in ("mcd", "vi"):
            models = [torch.load(project / f"models/{experiment}/{method}/seed{r}.pt") for r in (0, 1)]
            trained = [
                json.loads((project / f"metrics/{experiment}/train/{method}/seed{r}.json").read_text()) for r in (0, 1)
            ]
            assert [t["seed"] for t in trained] == [0, 1] and trained[0]["val_frames"] == metrics["val_frames"]
            # replicates differ by their seed only: same data, same settings, other weights
            assert models[0]["init_kwargs"] == models[1]["init_kwargs"] and models[0]["arch"] == models[1]["arch"]
            assert not all(torch.equal(models[0]["state"][k], models[1]["state"][k]) for k in models[0]["state"])
    safety = read_record(SafetySummary, project / "metrics/safety.json", "safety_summary")
    answer = safety.answer("mcd", "roundabout", "rain", 0.0)
    cells = [
        json.loads((project / f"metrics/safety/mcd-seed{r}-roundabout-rain-noise0.0.json").read_text()) for r in (0, 1)
    ]
    assert answer.replicates == [0, 1] and answer.estimates == [c["eta1"] for c in cells]
    assert (project / "plots/safety/summary/hexbin_roundabout_noise0.0.png").exists()
    assert (project / "data/heldout/roundabout-rain-noise0.0.parquet").exists()
    evaluated = read_record(HeldoutTable, project / "metrics/evaluate.json", "evaluate")
    assert {m: list(t) for m, t in evaluated.cells.items()} == {"mcd": ["rain"], "vi": ["rain"]}
    assert evaluated.cell("vi", "rain", 0.0).frames > 0
    assert (project / "plots/evaluate/figures/reliability_vi.png").exists()
    avoided = read_record(AvoidSummary, project / "metrics/avoid.json", "avoid_summary")
    findings = read_record(Findings, project / "metrics/findings.json", "findings")
    assert findings.comparisons == len(findings.findings) > 0 and {
        f.finding.replicates == (0, 1) for f in findings.findings
    } == {True}
    acquired = read_record(AcquisitionSummary, project / "metrics/acquisition.json", "acquire_summary")
    assert [(a.method, a.replicate) for a in acquired.controllers] == [("mcd", 0), ("mcd", 1)]
    assert {(c.round, c.cell) for c in acquired.checks} >= {(0, "roundabout-clear_noon-noise0.0")}
    assert acquired.methods == []  # acquire_rounds: 0, the behaviour-cloned controllers checked only
    for method in ("mcd",):  # each driven method's certified map of its first replicate
        envelope = json.loads((project / f"metrics/envelope/{method}-seed0.json").read_text())
        assert envelope["method"] == method and envelope["regions"]
    assert (project / "mlflow.db").exists()

    # the report's tables hold this run's numbers, as the report formats them, the findings first
    report = (project / "reports/report.md").read_text()
    assert findings_markdown(findings) in report
    for row in markdown_rows(report, "method | location | weather"):
        assert row["η̂1"] == fmt(safety.answer(row["method"], row["location"], row["weather"], 0.0).value, 2)
    for row in markdown_rows(report, "method | weather | noise | frames"):
        assert row["accuracy"] == fmt(evaluated.cell(row["method"], row["weather"], 0.0).accuracy)
    for row in markdown_rows(report, "method | condition"):
        assert row["η̂1"] == fmt(avoided.answer(row["method"], row["condition"], row["warnings"]).value, 2)
    assert "No round was run (`acquire_rounds: 0`)" in report
    assert 'src="data:image/png;base64,' in (project / "reports/report.html").read_text()

    assert "Data and pipelines are up to date" in dvc(project, "status")
    # `dvc plots show` draws offline: the page `make install` writes carries Vega, Vega-Lite and Vega-Embed
    subprocess.run(
        [sys.executable, "-m", "uqdrive.tools.cli", "plots-page", "--out", ".dvc/plots_page.html"],
        cwd=project,
        check=True,
        timeout=300,
    )
    dvc(project, "config", "plots.html_template", "plots_page.html")
    dvc(project, "plots", "show")
    page = (project / "dvc_plots/index.html").read_text()
    assert "cdn.jsdelivr" not in page and "vegaEmbed(" in page and '"eta1_unknown"' in page
    if chromium() is not None:  # as a person sees it: every plot draws data under titled axes, every figure loads
        drawn = render(project / "dvc_plots/index.html")
        assert {d.kind for d in drawn} == {"vega", "image"} and not problems(drawn), problems(drawn)
    # bytecode beside every source file (a test run or a benchmark imports what the stages did not): still up to date
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(project / "src")], check=True, timeout=300)
    assert list((project / "src/uqdrive/bench").glob("__pycache__/*.pyc"))
    with (project / "src/uqdrive/bench/__init__.py").open("a") as bench:  # a tool no stage runs (.dvcignore)
        bench.write("# an edit to a benchmark\n")
    assert "Data and pipelines are up to date" in dvc(project, "status")
    stamp = (project / "data/raw/obstacle.parquet").stat().st_mtime_ns
    again = dvc(project, "repro", timeout=1800)
    assert "Running stage" not in again, again
    assert (project / "data/raw/obstacle.parquet").stat().st_mtime_ns == stamp

    # an experiment with a new weather runs its cells (safety, held-out frames) and what aggregates them, nothing
    # upstream; git holds the metrics files, so `dvc exp show` compares the experiment's numbers with the baseline's
    _git(project, "add", "-A")
    _git(project, "commit", "-qm", "tiny run")
    rain_logs = {p.name: p.read_text() for p in (project / "cache/rollouts/safety").glob("*-rain-*.jsonl")}
    ran = sorted(
        line.split("'")[1]
        for line in dvc(project, "exp", "run", "-S", "weathers=[rain,afternoon]", timeout=1800).splitlines()
        if line.startswith("Running stage")
    )
    assert ran == [
        "acquire@mcd-0",  # the controllers' flagged cells are the sweep's: read again
        "acquire@mcd-1",
        "acquire_summary",
        "evaluate",
        "findings",
        "heldout",  # one stage each, over every condition (safety replays the cells it has seen from its rollout log)
        "report",
        "safety",
        "safety_summary",
    ]
    # the safety stage simulated only the new weather's cells: the rain cells' logs are as they were
    assert len(rain_logs) == 2  # 1 method x 2 replicates
    assert {p.name: p.read_text() for p in (project / "cache/rollouts/safety").glob("*-rain-*.jsonl")} == rain_logs
    assert len(list((project / "cache/rollouts/safety").glob("*-afternoon-*.jsonl"))) == 2
    summaries = _metrics_of_experiments(json.loads(dvc(project, "exp", "show", "--json")))
    assert len(summaries) >= 2  # the baseline and the experiment
    assert all(isinstance(m["eta1.sweep.mcd"], float) for m in summaries)  # no clear_noon here
