"""The report's opening and closing facts: what was run (profile, versions, replicates, the sweep, how η1 was
estimated), how many samples each estimation scheme needs, and the headline numbers `dvc exp show` compares."""

from __future__ import annotations

import dataclasses
import platform
import subprocess
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

from uqdrive.analysis.comparisons import Findings
from uqdrive.analysis.method_answers import UNKNOWN
from uqdrive.records import record
from uqdrive.report.document import Report, fmt, table
from uqdrive.report.sections import Run
from uqdrive.safety.cell_records import Mode, SafetyCell
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


@dataclasses.dataclass(frozen=True)
class Scope:
    """What the run covered (params.yaml's knobs, as the report stage validated them)."""

    profile: str
    experiments: tuple[str, ...]
    train_weather: str
    posteriors: tuple[str, ...]  # trained and evaluated
    methods: tuple[str, ...]  # driven in closed loop
    replicates: tuple[int, ...]
    weathers: tuple[str, ...]
    noises: tuple[float, ...]
    locations: tuple[str, ...]


@record
class Headline:
    """metrics/summary.json, the numbers an experiment is compared by (DVC's one metrics file: `dvc exp show` shows
    its keys first, nested keys as dotted columns such as ``offline_safety.vi``), in this order, the run's
    comparison keys first: the loosest (θ, γ) of every closed-loop cell (each η̂1 within θ of η1 with probability at
    least 1 − γ) and how many training replicates each number averages; per driven method, η̂1 over the offline
    sweep's cells and in collision avoidance's unknown conditions (warnings on, off, calibrated); each experiment's
    validation accuracy; how many findings are supported."""

    theta: float
    gamma: float
    n_replicates: int
    offline_safety: dict[str, float]
    avoid_unknown_on: dict[str, float]
    avoid_unknown_off: dict[str, float]
    avoid_unknown_calibrated: dict[str, float]
    val_accuracy: dict[str, dict[str, float]]  # experiment → method
    findings_supported: int


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


def run_section(report: Report, scope: Scope, cells: list[SafetyCell]) -> None:
    schemes = sorted({(c.scheme, c.theta, c.gamma, c.n) for c in cells})
    estimation = "; ".join(f"{s} θ = {t:g}, γ = {g:g} → n = {n} rollouts per cell" for s, t, g, n in schemes)
    built = f"{datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')}, commit {_git_commit(report.root)}"
    noises = ", ".join(f"{x:g}" for x in scope.noises)
    sweep = f"methods {', '.join(scope.methods)} × weathers {', '.join(scope.weathers)} × noise {noises}"
    base_seeds = ", ".join(sorted({str(c.base_seed) for c in cells}))
    report.add(f"""
# uqdrive report

Bayesian end-to-end driving controllers in pybullet and how safe they are, beside *Uncertainty
Quantification with Statistical Guarantees in End-to-End Autonomous Driving Control* (Michelmore et al., ICRA 2020;
CARLA). Built by `dvc repro` from this run's metrics files; every number below is read from them.

| what was run | |
|---|---|
| profile | `{scope.profile}` |
| built | {built}, Python {platform.python_version()} |
| versions | {_versions()} |
| experiments | {", ".join(scope.experiments)}: one controller per experiment × method × replicate, trained on its own \
scenario(s) collected in `{scope.train_weather}` |
| training replicates | seeds {", ".join(map(str, scope.replicates))} (each its own MCD trunk and heads) |
| safety sweep | {sweep} × locations {", ".join(scope.locations)}, every replicate |
| η1 estimation | {estimation or "–"} |
| rollout seeds | {base_seeds} + i for rollout i of a cell: the same in every cell (paired) |
""")


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


def headline_metrics(scope: Scope, run: Run, findings: Findings) -> Headline:
    """The headline numbers (`Headline`): means over the replicates, η̂1 of the unknown mixture per warnings mode."""
    seeds, methods = scope.replicates, scope.methods
    guarantees = [(c.theta, c.gamma) for c in run.cells] + [
        (cell.theta, cell.gamma) for result in run.avoided for modes in result.cells.values() for cell in modes.values()
    ]

    def offline_safety(method: str) -> float:
        answers = [a.value for a in run.safety.answers if a.method == method]
        return sum(answers) / len(answers)

    def avoid_unknown(mode: Mode) -> dict[str, float]:
        return {m: run.avoid.answer(m, UNKNOWN, mode).value for m in methods}

    return Headline(
        theta=max(theta for theta, _ in guarantees),
        gamma=max(gamma for _, gamma in guarantees),
        n_replicates=len(seeds),
        offline_safety={m: offline_safety(m) for m in methods},
        avoid_unknown_on=avoid_unknown(Mode.ON),
        avoid_unknown_off=avoid_unknown(Mode.OFF),
        avoid_unknown_calibrated=avoid_unknown(Mode.CALIBRATED),
        val_accuracy={
            e: {m: sum(run.trained[e, m, r].val_accuracy for r in seeds) / len(seeds) for m in methods}
            for e in scope.experiments
        },
        findings_supported=findings.supported,
    )
