"""The report's section on the certified operating envelopes (stage `envelope@<method>`): per method, how much of the
condition box is certified safe, unsafe or left undecided, what it cost beside a grid of per-cell intervals, and the
map. Reads only the stage's typed records (`EnvelopeResult`) and figures."""

from __future__ import annotations

from pathlib import Path

from uqdrive.envelope.certify import RegionVerdict
from uqdrive.envelope.map_records import EnvelopeResult
from uqdrive.records import read_record
from uqdrive.report.document import Report, fmt, table


def read_envelopes(metrics_dir: Path, methods: list[str], replicate: int) -> list[EnvelopeResult]:
    """Each driven method's map of replicate ``replicate`` (the stage certifies the first training seed)."""
    return [
        read_record(EnvelopeResult, metrics_dir / "envelope" / f"{m}-seed{replicate}.json", f"envelope@{m}")
        for m in methods
    ]


def _axis(result: EnvelopeResult, index: int) -> str:
    axis = result.axes[index]
    name = f"{axis.key} ({result.blend['from']} → {result.blend['to']})" if axis.key == "weather.blend" else axis.key
    return f"{name} ∈ [{axis.range[0]:g}, {axis.range[1]:g}]"


def envelope_section(report: Report, envelopes: list[EnvelopeResult]) -> None:
    """One row per method (regions and their share of the box by verdict, rollouts against the grid's), then each
    method's map."""
    first = envelopes[0]
    axes = " × ".join(_axis(first, i) for i in range(len(first.axes)))
    report.add(f"""
## Certified operating envelope

Each `offline` controller (replicate seed{first.replicate}) over the continuous conditions {axes} at
{first.location}: phase one searches for the boundary η1 = {first.threshold:g} with {first.search.rollouts}
rollouts; their outcomes alone choose a partition, finer along that boundary; phase two certifies each region's η1
with the sequential threshold test at its share of γ. **A verdict is about the region's average**: its η1 is the
probability that a rollout at a condition drawn uniformly in the region, on a fresh seed, stays in the safe set. A
region ends safe (its average η1 ≥ τ certified), unsafe (its average < τ certified) or undecided (its budget
spent); a safe region may hold points below τ (nothing here assumes safety falls monotonically with noise or
rain). **Guarantee: family-wise, of region averages.** With probability ≥ 1 − {first.gamma:g}, every verdict of a
map holds at once. `grid`: the rollouts a grid of the finest regions would need with a per-cell exact interval of
half-width {first.grid.theta:g}, family-wise at the same γ (each cell's interval, too, is of a region average).
`rollouts`: search + the tests' + run ahead of a test and never read (a region's
rollouts are simulated a full lockstep batch at a time; a test reads only what it asks for, in order).""")
    rows = [
        [
            e.method,
            *(f"{e.verdicts[v]} ({e.volume[v]:.0%})" for v in RegionVerdict),
            str(e.search.failures),
            f"{e.rollouts['search']} + {e.rollouts['certify']} + {e.rollouts['unread']} = {e.rollouts['total']}",
            str(e.grid.rollouts),
            fmt(e.seconds, 0),
        ]
        for e in envelopes
    ]
    headers = [
        "method",
        "safe on average (box)",
        "unsafe on average",
        "undecided",
        "failures found",
        "rollouts",
        "grid",
    ]
    headers += ["seconds"]
    report.add(table(headers, rows))
    for e in envelopes:
        report.figure(
            report.root / "plots" / "envelope" / f"{e.method}-seed{e.replicate}" / "map.png",
            f"{e.method}: regions coloured by verdict, phase one's rollouts as points (failures as crosses); each "
            "region labelled with its safe / total certification rollouts",
        )
