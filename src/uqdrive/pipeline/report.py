"""The `report` stage: the findings first, then every table and figure of this run beside the paper's numbers.

Reads only the stages' metrics files (as typed records, `uqdrive.pipeline.records`) and figures (the DVC outputs),
so the report is a pure function of what this run produced and `dvc repro` rebuilds it whenever any of them
changes.
Writes `reports/report.md` (figures linked) and a self-contained `reports/report.html`
(figures embedded as data URIs), and logs both to MLflow.
"""

from __future__ import annotations

import platform
import subprocess
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

import mlflow
from omegaconf import DictConfig

from uqdrive.files import atomic_path, write_json
from uqdrive.pipeline.configs import NonEmptyNames, SafetyGrid
from uqdrive.pipeline.findings import Findings
from uqdrive.pipeline.methods import UNKNOWN, AvoidSummary, SafetySummary
from uqdrive.pipeline.records import SafetyCell, read_avoid_results, read_record, read_safety_cells
from uqdrive.pipeline.report_document import Report, fmt, read_json, table
from uqdrive.pipeline.report_experiments import (
    Run,
    avoid_section,
    conditions_of,
    fidelity_section,
    read_train_metrics,
    safety_section,
    training_section,
)
from uqdrive.pipeline.report_findings import findings_markdown
from uqdrive.schema import Str, schema, validate
from uqdrive.tracking import stage_run
from uqdrive.uq import chernoff_n, clopper_pearson_n, sequential_scheme

PACKAGES = (
    "uqdrive",
    "torch",
    "pybullet",
    "opencv-python-headless",
    "hydra-core",
    "dvc",
    "mlflow",
    "pyarrow",
    "numpy",
    "scipy",
)


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


def _git_commit(root: Path) -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True, timeout=10
        )
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"
    return out.stdout.strip() if out.returncode == 0 else "unknown (not a git checkout)"


def _versions() -> str:
    found = []
    for name in PACKAGES:
        try:
            found.append(f"{name} {metadata.version(name)}")
        except metadata.PackageNotFoundError:
            continue
    return ", ".join(found)


def run_section(report: Report, stage: ReportStage, run: Run) -> None:
    schemes = sorted({(c.scheme, c.theta, c.gamma, c.n) for c in run.cells})
    estimation = "; ".join(f"{s} θ = {t:g}, γ = {g:g} → n = {n} rollouts per cell" for s, t, g, n in schemes)
    built = f"{datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')}, commit {_git_commit(report.root)}"
    noises = ", ".join(f"{x:g}" for x in stage.noises)
    sweep = f"methods {', '.join(stage.methods)} × weathers {', '.join(stage.weathers)} × noise {noises}"
    base_seeds = ", ".join(sorted({str(c.base_seed) for c in run.cells}))
    report.add(f"""
# uqdrive report

Bayesian end-to-end driving controllers in pybullet and how safe they are, beside *Uncertainty
Quantification with Statistical Guarantees in End-to-End Autonomous Driving Control* (Michelmore et al., ICRA 2020;
CARLA). Built by `dvc repro` from this run's metrics files; every number below is read from them.

| what was run | |
|---|---|
| profile | `{stage.profile_name}` |
| built | {built}, Python {platform.python_version()} |
| versions | {_versions()} |
| experiments | {", ".join(stage.experiments)}: one controller per experiment × method × replicate, trained on its own \
scenario(s) collected in `{stage.train_weather}` |
| training replicates | seeds {", ".join(map(str, stage.replicates))} (each its own MCD trunk and heads) |
| safety sweep | {sweep} × locations {", ".join(stage.locations)}, every replicate |
| η1 estimation | {estimation or "–"} |
| rollout seeds | {base_seeds} + i for rollout i of a cell: the same in every cell (paired) |
""")


def evaluate_section(report: Report, cfg: ReportStage, evaluated: dict) -> None:
    report.add(f"""
## Held-out uncertainty

Frames the autopilot recorded at the roundabout in each weather × noise level, on episodes never used
for training, predicted by the first replicate's controllers (seed{cfg.replicates[0]}). AUROC: how well an
uncertainty score ranks frames with a wrong class above right ones
(0.5 = chance); '–' where a condition has no mistakes or no right frames. The paper reports no such table.""")
    rows = []
    for method in cfg.posteriors:
        for weather in cfg.weathers:
            for noise in cfg.noises:
                c = evaluated[method][weather][f"noise{noise}"]
                rows.append(
                    [
                        method,
                        weather,
                        f"{noise:g}",
                        str(c["frames"]),
                        fmt(c["accuracy"]),
                        fmt(c["nll"]),
                        fmt(c["ece"]),
                        fmt(c["brier"]),
                        fmt(c["mean_mutual_information"]),
                        fmt(c["mean_eta2"]),
                        fmt(c["auroc_mi"]),
                        fmt(c["auroc_one_minus_eta2"]),
                    ]
                )
    report.add(
        table(
            [
                "method",
                "weather",
                "noise",
                "frames",
                "accuracy",
                "NLL",
                "ECE",
                "Brier",
                "mean MI",
                "mean η2",
                "AUROC MI",
                "AUROC 1 − η2",
            ],
            rows,
        )
    )
    figures = report.root / "plots" / "evaluate" / "figures"
    report.figure(figures / "conditions.png", "Held-out metrics across conditions, one line per method")
    for method in cfg.posteriors:
        report.figure(figures / f"reliability_{method}.png", f"{method}: reliability diagrams per condition")
    agreement_table(report, cfg, evaluated)


def agreement_table(report: Report, cfg: ReportStage, evaluated: dict) -> None:
    """Each method against HMC's predictive on the same held-out frames (when HMC was evaluated)."""
    cells = {m: [evaluated[m][w][f"noise{x}"] for w in cfg.weathers for x in cfg.noises] for m in cfg.posteriors}
    if not all("hmc_tv_distance" in c for by_method in cells.values() for c in by_method):
        return
    mean = lambda key, cs: fmt(sum(c[key] for c in cs) / len(cs)) if all(c[key] is not None for c in cs) else "–"  # noqa: E731
    report.add("""
### Agreement with HMC

HMC is the reference the other posteriors approximate. Per method, over the held-out frames of every condition:
mean total-variation distance between its predictive and HMC's (worst condition beside it), share of frames with
the same decision (argmax), Spearman correlation of per-frame mutual information with HMC's. The hmc row compares
two independent sets of HMC draws: the Monte-Carlo noise floor.""")
    report.add(
        table(
            ["method", "mean TV to HMC", "worst condition TV", "argmax agreement", "MI Spearman ρ"],
            [
                [
                    m,
                    mean("hmc_tv_distance", cs),
                    fmt(max(c["hmc_tv_distance"] for c in cs)),
                    mean("hmc_argmax_agreement", cs),
                    mean("hmc_mi_spearman", cs),
                ]
                for m, cs in cells.items()
            ],
        )
    )
    report.figure(
        report.root / "plots" / "evaluate" / "figures" / "agreement_hmc.png",
        "Agreement with HMC across conditions, one line per method",
    )


def sample_counts_section(report: Report, cells: list[SafetyCell], look_size: int = 4) -> None:
    """What each scheme needs for this run's (θ, γ) and the paper's: why `sequential` exists."""
    settings = sorted({(c.theta, c.gamma) for c in cells} | {(0.05, 0.05)})
    rows = []
    for theta, gamma in settings:
        scheme = sequential_scheme(theta, gamma, look_size)
        mid, high = scheme.operating_characteristics([0.5, 0.99])[0]
        rows.append(
            [
                f"{theta:g}",
                f"{gamma:g}",
                str(chernoff_n(theta, gamma)),
                str(clopper_pearson_n(theta, gamma)),
                str(scheme.max_n),
                fmt(mid, 1),
                fmt(high, 1),
            ]
        )
    report.add(
        "## Samples per estimation scheme\n\nRollouts (or weight samples) for P(|η̂ − η| > θ) ≤ γ: Chernoff "
        "(the paper, planned), exact Clopper–Pearson (planned) and the sequential scheme, whose stopping levels are "
        f"calibrated by exact computation, with a look every {look_size} rollouts (expected count at η = 0.5 and "
        "0.99, exact by dynamic programming over the stopping rule). `uqdrive bound` prints more."
    )
    report.add(
        table(
            ["θ", "γ", "chernoff", "clopper_pearson", "sequential at most", "sequential E[n] at η=0.5", "at η=0.99"],
            rows,
        )
    )


def headline_metrics(stage: ReportStage, run: Run, findings: Findings) -> dict[str, float]:
    """metrics/summary.json, the numbers an experiment is compared by (DVC's one metrics file: `dvc exp show`),
    flat and short-named so they fit a terminal: per driven method, the mean validation accuracy of each
    experiment's replicates (`acc_<experiment>_<method>`), the offline η̂1 over every cell of the sweep
    (`safety_<method>`), the unknown-mixture η̂1 in collision avoidance with warnings off, on and calibrated
    (`avoid_off_<method>`, …), and how many findings are supported."""
    seeds = stage.replicates
    headline: dict[str, float] = {}
    for m in stage.methods:
        for e in stage.experiments:
            headline[f"acc_{e}_{m}"] = sum(run.trained[e, m, r].val_accuracy for r in seeds) / len(seeds)
        answers = [a.value for a in run.safety.answers if a.method == m]
        headline[f"safety_{m}"] = sum(answers) / len(answers)
        for mode, short in (("off", "off"), ("on", "on"), ("calibrated", "cal")):
            headline[f"avoid_{short}_{m}"] = run.avoid.answer(m, UNKNOWN, mode).value
    return {**headline, "findings": findings.supported}


def run_report(cfg: DictConfig) -> dict:
    stage = validate(ReportStage, cfg)
    root, metrics_dir, out_dir = Path(cfg.paths.root), Path(cfg.paths.metrics), Path(cfg.report.out_dir)
    seeds = list(stage.replicates)
    run = Run(
        trained=read_train_metrics(metrics_dir, list(stage.experiments), list(stage.posteriors), seeds),
        classes={e: read_json(metrics_dir / e / "preprocess.json")["num_classes"] for e in stage.experiments},
        cells=read_safety_cells(metrics_dir / "safety", stage),
        safety=read_record(SafetySummary, metrics_dir / "safety.json", "safety_summary"),
        avoided=read_avoid_results(metrics_dir / "avoid", list(stage.methods), seeds),
        avoid=read_record(AvoidSummary, metrics_dir / "avoid.json", "avoid_summary"),
    )
    findings = read_record(Findings, metrics_dir / "findings.json", "findings")
    evaluated = read_json(metrics_dir / "evaluate.json")
    report = Report(root, out_dir)
    run_section(report, stage, run)
    report.add("## What the run found\n\n" + findings_markdown(findings))
    fidelity_section(report, run, list(stage.methods), list(stage.weathers), stage.locations[0])
    training_section(report, run, list(stage.experiments), list(stage.posteriors), seeds)
    safety_section(report, run, list(stage.methods), conditions_of(stage.locations, stage.weathers, stage.noises))
    avoid_section(report, run, list(stage.methods))
    evaluate_section(report, stage, evaluated)
    sample_counts_section(report, run.cells)
    write_json(Path(cfg.report.summary), headline_metrics(stage, run, findings))
    md_path, html_path = out_dir / "report.md", out_dir / "report.html"
    with atomic_path(md_path) as tmp:
        tmp.write_text(report.markdown)
    with atomic_path(html_path) as tmp:
        tmp.write_text(report.html())
    with stage_run(root, "report", cfg, run_name="report"):
        mlflow.log_artifact(str(md_path))
        mlflow.log_artifact(str(html_path))
    return {"markdown": str(md_path), "html": str(html_path), "figures": len(report.figures)}
