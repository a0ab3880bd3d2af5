"""The `report` stage: every table and figure of this run beside the paper's numbers.

Reads only the stages' metrics JSON and figures (the DVC outputs), so the report is a pure
function of what this run produced and `dvc repro` rebuilds it whenever any of them changes.
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
from uqdrive.pipeline.configs import NonEmptyNames, NonEmptyNoises, Stage
from uqdrive.pipeline.report_document import Report, fmt, read_json, table
from uqdrive.pipeline.report_experiments import (
    avoid_section,
    fidelity_section,
    pooled_cells,
    safety_section,
    training_section,
)
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
class ReportStage(Stage):
    profile_name: Str
    experiments: NonEmptyNames
    train_weather: Str
    posteriors: NonEmptyNames
    methods: NonEmptyNames
    weathers: NonEmptyNames
    noises: NonEmptyNoises
    locations: NonEmptyNames
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


def run_section(report: Report, cfg: DictConfig, safety_cells: list[dict], seeds: dict[str, list[int]]) -> None:
    thetas = sorted({(c["scheme"], c["theta"], c["gamma"], c["n"]) for c in safety_cells})
    estimation = "; ".join(f"{s} θ = {t:g}, γ = {g:g} → n = {n} rollouts per cell" for s, t, g, n in thetas)
    built = f"{datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')}, commit {_git_commit(report.root)}"
    noises = ", ".join(f"{x:g}" for x in cfg.noises)
    sweep = f"methods {', '.join(cfg.methods)} × weathers {', '.join(cfg.weathers)} × noise {noises}"
    train_seeds = ", ".join(sorted({str(s) for s in seeds["train"]}))
    safety_seeds = ", ".join(sorted({str(s) for s in seeds["safety"]}))
    report.add(f"""
# uqdrive report

Bayesian end-to-end driving controllers in pybullet and how safe they are, beside *Uncertainty
Quantification with Statistical Guarantees in End-to-End Autonomous Driving Control* (CARLA).
Built by `dvc repro` from this run's metrics files; every number below is read from them.

| what was run | |
|---|---|
| profile | `{cfg.profile_name}` |
| built | {built}, Python {platform.python_version()} |
| versions | {_versions()} |
| experiments | {", ".join(cfg.experiments)}: one controller per experiment × method, trained on its own \
scenario(s) collected in `{cfg.train_weather}` |
| safety sweep | {sweep} × locations {", ".join(cfg.locations)} |
| η1 estimation | {estimation or "–"} |
| seeds | training {train_seeds}; safety rollouts {safety_seeds} + i for rollout i of a cell |
""")


def evaluate_section(report: Report, cfg: DictConfig, evaluated: dict) -> None:
    report.add("""
## Held-out uncertainty

Frames the autopilot recorded at the roundabout in each weather × noise level, on episodes never used
for training. AUROC: how well an uncertainty score ranks frames with a wrong class above right ones
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


def agreement_table(report: Report, cfg: DictConfig, evaluated: dict) -> None:
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


def sample_counts_section(report: Report, cells: list[dict], look_size: int = 4) -> None:
    """What each scheme needs for this run's (θ, γ) and the paper's: why `sequential` exists."""
    settings = sorted({(c["theta"], c["gamma"]) for c in cells} | {(0.05, 0.05)})
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
        "(the paper, planned), exact Clopper–Pearson (planned) and the exactly calibrated sequential "
        f"Clopper–Pearson scheme with a look every {look_size} rollouts (expected count at η = 0.5 and 0.99, "
        "exact by dynamic programming). `uqdrive bound` prints more."
    )
    report.add(
        table(
            ["θ", "γ", "chernoff", "clopper_pearson", "sequential at most", "sequential E[n] at η=0.5", "at η=0.99"],
            rows,
        )
    )


def headline_metrics(cfg: DictConfig, metrics_dir: Path, summary: dict, avoided: dict, gamma: float) -> dict:
    """metrics/summary.json: the few numbers an experiment is compared by (DVC's one metrics file), read from
    the stages' own files: validation accuracy per controller, η̂1 pooled over every offline-safety cell
    and its worst cell per method, and the avoid experiment's unknown mixture and known autonomy."""
    controllers = {
        e: {m: read_json(metrics_dir / e / "train" / f"{m}.json")["val_accuracy"] for m in cfg.posteriors}
        for e in cfg.experiments
    }
    offline = {}
    for method, locations in summary.items():
        cells = [c for loc in locations.values() for w in loc.values() for c in w.values()]
        offline[method] = {
            "eta1_pooled": pooled_cells(cells, gamma).value,
            "eta1_worst_cell": min(c["eta1"] for c in cells),
        }
    avoid = {
        m: {
            "unknown_off_eta1": r["unknown"]["off"]["eta1"],
            "unknown_on_eta1": r["unknown"]["on"]["eta1"],
            "unknown_calibrated_eta1": r["unknown"]["calibrated"]["eta1"],
            "known_calibrated_autonomy": r["cells"]["known"]["calibrated"]["autonomy"],
        }
        for m, r in avoided.items()
        if m in cfg.methods
    }
    return {"val_accuracy": controllers, "offline_safety": offline, "avoid": avoid}


def run_report(cfg: DictConfig) -> dict:
    validate(ReportStage, cfg)
    root = Path(cfg.paths.root)
    metrics_dir = Path(cfg.paths.metrics)
    out_dir = Path(cfg.report.out_dir)
    summary = read_json(metrics_dir / "safety.json")
    cells = [c for m in summary.values() for loc in m.values() for w in loc.values() for c in w.values()]
    gamma = max(c["gamma"] for c in cells)
    report = Report(root, out_dir)
    seeds = {
        "train": [
            read_json(metrics_dir / e / "train" / f"{m}.json")["seed"] for e in cfg.experiments for m in cfg.posteriors
        ],
        "safety": [c["base_seed"] for c in cells],
    }
    avoided = read_json(metrics_dir / "avoid.json")
    evaluated = read_json(metrics_dir / "evaluate.json")
    run_section(report, cfg, cells, seeds)
    fidelity_section(report, cfg, summary, avoided, evaluated, gamma)
    training_section(report, cfg, metrics_dir)
    safety_section(report, cfg, summary, gamma)
    avoid_section(report, cfg, avoided)
    evaluate_section(report, cfg, evaluated)
    sample_counts_section(report, cells)
    write_json(Path(cfg.report.summary), headline_metrics(cfg, metrics_dir, summary, avoided, gamma))
    md_path, html_path = out_dir / "report.md", out_dir / "report.html"
    with atomic_path(md_path) as tmp:
        tmp.write_text(report.markdown)
    with atomic_path(html_path) as tmp:
        tmp.write_text(report.html())
    with stage_run(root, "report", cfg, run_name="report"):
        mlflow.log_artifact(str(md_path))
        mlflow.log_artifact(str(html_path))
    return {"markdown": str(md_path), "html": str(html_path), "figures": len(report.figures)}
