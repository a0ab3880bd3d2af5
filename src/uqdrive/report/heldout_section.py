"""The report's section on held-out uncertainty (stage `evaluate`): every posterior on held-out frames of each
weather × noise, and each against HMC's predictive. Reads only the stage's record (`HeldoutTable`) and figures."""

from __future__ import annotations

from collections.abc import Sequence

from uqdrive.models.heldout_eval import HeldoutCell, HeldoutTable
from uqdrive.report.document import Report, fmt, table

COLUMNS = (
    ("accuracy", "accuracy"),
    ("nll", "NLL"),
    ("ece", "ECE"),
    ("brier", "Brier"),
    ("mean_mutual_information", "mean MI"),
    ("mean_eta2", "mean η2"),
    ("auroc_mi", "AUROC MI"),
    ("auroc_one_minus_eta2", "AUROC 1 − η2"),
)


def heldout_section(
    report: Report,
    evaluated: HeldoutTable,
    methods: Sequence[str],
    weathers: Sequence[str],
    noises: Sequence[float],
    replicate: int,
) -> None:
    report.add(f"""
## Held-out uncertainty

Frames the autopilot recorded at the roundabout in each weather × noise level, on episodes never used
for training, predicted by the first replicate's controllers (seed{replicate}). AUROC: how well an
uncertainty score ranks frames with a wrong class above right ones
(0.5 = chance); '–' where a condition has no mistakes or no right frames. The paper reports no such table.""")
    rows = [
        [m, w, f"{x:g}", str(c.frames), *(fmt(getattr(c, key)) for key, _ in COLUMNS)]
        for m in methods
        for w in weathers
        for x in noises
        for c in [evaluated.cell(m, w, x)]
    ]
    report.add(table(["method", "weather", "noise", "frames", *(name for _, name in COLUMNS)], rows))
    figures = report.root / "plots" / "evaluate" / "figures"
    report.figure(figures / "conditions.png", "Held-out metrics across conditions, one line per method")
    for method in methods:
        report.figure(figures / f"reliability_{method}.png", f"{method}: reliability diagrams per condition")
    cells = {m: [evaluated.cell(m, w, x) for w in weathers for x in noises] for m in methods}
    if all(c.hmc_tv_distance is not None for by_method in cells.values() for c in by_method):
        agreement_table(report, cells)


def _mean(values: list[float | None]) -> str:
    return fmt(sum(values) / len(values)) if all(v is not None for v in values) else "–"


def agreement_table(report: Report, cells: dict[str, list[HeldoutCell]]) -> None:
    """Each method against HMC's predictive on the same held-out frames."""
    report.add("""
### Agreement with HMC

HMC is the reference the other posteriors approximate. Per method, over the held-out frames of every condition:
mean total-variation distance between its predictive and HMC's (worst condition beside it), share of frames with
the same decision (argmax), Spearman correlation of per-frame mutual information with HMC's. The hmc row compares
two independent sets of HMC draws: the Monte-Carlo noise floor.""")
    rows = [
        [
            m,
            _mean([c.hmc_tv_distance for c in cs]),
            fmt(max(c.hmc_tv_distance for c in cs)),
            _mean([c.hmc_argmax_agreement for c in cs]),
            _mean([c.hmc_mi_spearman for c in cs]),
        ]
        for m, cs in cells.items()
    ]
    report.add(table(["method", "mean TV to HMC", "worst condition TV", "argmax agreement", "MI Spearman ρ"], rows))
    report.figure(
        report.root / "plots" / "evaluate" / "figures" / "agreement_hmc.png",
        "Agreement with HMC across conditions, one line per method",
    )
