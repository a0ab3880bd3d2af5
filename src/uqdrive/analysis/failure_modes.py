"""Failures grouped into modes: what a cell's (or a method's) failing rollouts share — how they ended, where on the
route, under which condition, whether a warning fired first — so that many failures read as a few things to fix.

A mode is one (cause, segment, warned) combination within a group of cells (a cell; a method at a condition; a
method); its share is of the group's failures, and the group's failures are also counted against its rollouts. The
sentence a finding or the report states is generated from the modes, never written by hand.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Callable, Sequence

from uqdrive.safety.cell_records import SafetyCell
from uqdrive.safety.failures import RolloutFailure

GROUPINGS: dict[str, Callable[[SafetyCell], tuple[str, ...]]] = {
    "cell": lambda c: (c.name,),
    "method_weather": lambda c: (c.method, c.weather),
    "method": lambda c: (c.method,),
}
"""How cells pool into a group: each cell alone, a method at a weather (over replicates, locations, noises), a
method over everything."""


@dataclasses.dataclass(frozen=True)
class FailureMode:
    """``count`` of the group's ``failures`` (of ``rollouts``) ended by ``cause`` in ``segment``, ``warned`` or
    not; ``worst``: the record of its worst failure (for a replay command)."""

    group: tuple[str, ...]
    cause: str
    segment: str
    warned: bool
    count: int
    failures: int
    rollouts: int
    worst: RolloutFailure
    worst_cell: str

    @property
    def share(self) -> float:
        return self.count / self.failures

    @property
    def label(self) -> str:
        """The mode in words: 'off road on the approach, no warning first'."""
        return f"{self.cause} on the {self.segment}, {'a warning first' if self.warned else 'no warning first'}"


def failure_modes(cells: Sequence[SafetyCell], grouping: str = "cell") -> list[FailureMode]:
    """Every group's modes (`GROUPINGS`), groups in the cells' order, each group's modes most common first (ties:
    the worst margin first)."""
    key_of = GROUPINGS[grouping]
    groups: dict[tuple[str, ...], list[SafetyCell]] = {}
    for cell in cells:
        groups.setdefault(key_of(cell), []).append(cell)
    modes = []
    for group, members in groups.items():
        failures = [(f, cell.name) for cell in members for f in cell.failures]
        rollouts = sum(len(cell.outcomes) for cell in members)
        counts = Counter((f.cause, f.segment, f.warned) for f, _ in failures)
        for (cause, segment, warned), count in counts.items():
            ranked = sorted(
                ((f, name) for f, name in failures if (f.cause, f.segment, f.warned) == (cause, segment, warned)),
                key=lambda item: (item[0].margin is None, item[0].margin or 0.0),
            )
            worst, worst_cell = ranked[0]
            modes.append(FailureMode(group, cause, segment, warned, count, len(failures), rollouts, worst, worst_cell))
    order = {group: i for i, group in enumerate(groups)}
    return sorted(modes, key=lambda m: (order[m.group], -m.count, m.worst.margin is None, m.worst.margin or 0.0))


def mode_sentence(modes: Sequence[FailureMode]) -> str:
    """One group's failures in a sentence, e.g. "mcd's rain failures (5 of 20 rollouts) are 80 % off road on the
    ring, no warning first; 20 % left lane on the exit arm, a warning first." (modes: one group's)."""
    if not modes:
        return ""
    first = modes[0]
    who = " ".join(first.group[:1]) + "'s" + "".join(f" {part}" for part in first.group[1:])
    parts = [f"{round(100 * m.share)} % {m.label}" for m in modes]
    return f"{who} failures ({first.failures} of {first.rollouts} rollouts) are {'; '.join(parts)}."


def modes_table(modes: Sequence[FailureMode]) -> list[dict[str, object]]:
    """The modes as rows (a CSV for `dvc plots`, a table in the report); ``label``: group and mode, one bar each."""
    return [
        {
            "label": f"{' '.join(m.group)}: {m.label}",
            "group": " ".join(m.group),
            "mode": m.label,
            "cause": m.cause,
            "segment": m.segment,
            "warned": m.warned,
            "count": m.count,
            "share": round(m.share, 4),
            "failures": m.failures,
            "rollouts": m.rollouts,
            "worst_cell": m.worst_cell,
            "worst_seed": m.worst.seed,
        }
        for m in modes
    ]


def by_group(modes: Sequence[FailureMode]) -> dict[tuple[str, ...], list[FailureMode]]:
    """The modes of each group, in order."""
    groups: dict[tuple[str, ...], list[FailureMode]] = {}
    for mode in modes:
        groups.setdefault(mode.group, []).append(mode)
    return groups
