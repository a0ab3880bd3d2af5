"""The report's opening and closing facts: what was run (profile, versions, replicates, the sweep, how η1 was
estimated) and how many samples each estimation scheme needs."""

from __future__ import annotations

import dataclasses
import platform
import subprocess
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path

from uqdrive.report.document import Report, fmt, table
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.stage_schemas import SafetyGrid
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
    """What the run covered (params.yaml's knobs, as the report stage validated them; ``grid``: its safety grid)."""

    profile: str
    experiments: tuple[str, ...]
    train_weather: str
    posteriors: tuple[str, ...]  # trained and evaluated
    grid: SafetyGrid  # the offline-safety sweep: methods driven in closed loop × replicates × conditions
    note: str = ""  # what the profile's sizes can and cannot show (conf/profile/<name>.yaml: profile_note)


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


def title_section(report: Report, note: str = "") -> None:
    """The title, then what the run's profile can and cannot show (its sizes), then what the report is."""
    report.add("# uqdrive report" + (f"\n\n**{note}**" if note else ""))
    report.add("""
Bayesian end-to-end driving controllers in pybullet and how safe they are, beside *Uncertainty Quantification with
Statistical Guarantees in End-to-End Autonomous Driving Control* (Michelmore et al., ICRA 2020; CARLA). Every
number and sentence below is generated from this run's metrics files.""")


def run_section(report: Report, scope: Scope, cells: list[SafetyCell]) -> None:
    schemes = sorted({(c.estimate.scheme, c.estimate.theta, c.estimate.gamma, c.estimate.n) for c in cells})
    estimation = "; ".join(f"{s} θ = {t:g}, γ = {g:g} → n = {n} rollouts per cell" for s, t, g, n in schemes)
    built = f"{datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')}, commit {_git_commit(report.root)}"
    noises = ", ".join(f"{x:g}" for x in scope.grid.noises)
    sweep = f"methods {', '.join(scope.grid.methods)} × weathers {', '.join(scope.grid.weathers)} × noise {noises}"
    base_seeds = ", ".join(sorted({str(c.base_seed) for c in cells}))
    report.add(f"""
## What was run

Built by `dvc repro` from this run's metrics files; every number in this report is read from them.

| what was run | |
|---|---|
| profile | `{scope.profile}` |
| built | {built}, Python {platform.python_version()} |
| versions | {_versions()} |
| experiments | {", ".join(scope.experiments)}: one controller per experiment × method × replicate, trained on its own \
scenario(s) collected in `{scope.train_weather}` |
| training replicates | seeds {", ".join(map(str, scope.grid.replicates))} (each its own MCD trunk and heads) |
| safety sweep | {sweep} × locations {", ".join(scope.grid.locations)}, every replicate |
| η1 estimation | {estimation or "–"} |
| rollout seeds | {base_seeds} + i for rollout i of a cell: the same in every cell (paired) |
""")


def sample_counts_section(report: Report, cells: list[SafetyCell], look_size: int = 4) -> None:
    """What each scheme needs for this run's (θ, γ) and the paper's: why `sequential` exists."""
    settings = sorted({(c.estimate.theta, c.estimate.gamma) for c in cells} | {(0.05, 0.05)})
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
