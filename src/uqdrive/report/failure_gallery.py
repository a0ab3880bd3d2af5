"""The report's failures section: what each method's failures share (modes, in a sentence and a table, from
`uqdrive.analysis.failure_modes`) and a gallery per condition of the clips the safety stage drew, worst first, each
with the command that re-drives it.

The clips are shown as GIFs made from the stage's MP4s beside the report (reports/failures/), images every browser
plays; the MP4 is linked. A failure whose clip the safety stage did not draw (past `safety.clips` of its cell) is
counted in the modes, not shown.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Sequence
from pathlib import Path

from uqdrive.analysis.failure_modes import by_group, failure_modes, mode_sentence
from uqdrive.replay.video import gif_of
from uqdrive.report.document import Report, fmt, table
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.safety.failures import RolloutFailure

GALLERY_CLIPS = 3  # clips per condition: the worst few say what a condition's failures look like


def failures_section(
    report: Report, cells: Sequence[SafetyCell], clips_dir: Path, record_dir: Path, conditions: Sequence[tuple]
) -> int:
    """Modes per method and weather, then the gallery per condition (``clips_dir``: the safety stage's clips;
    ``record_dir``: where the cells' records lie, for the replay commands). Returns the clips shown, whose replay
    commands reports/failures/replays.txt lists (empty: none shown)."""
    folder = report.out_dir / "failures"
    shutil.rmtree(folder, ignore_errors=True)  # a clip of an earlier run is not this run's
    folder.mkdir(parents=True)
    commands: list[str] = []
    modes = failure_modes(cells, "method_weather")
    report.add(
        "## Failures: modes and a gallery\n\n"
        "Every failing rollout of every cell is recorded (`metrics/safety/<cell>.json`, `failures`, worst margin "
        "first) and grouped into modes by how it ended, where on the route and whether a warning fired first."
    )
    if not modes:
        report.add("No cell of this run has a failing rollout.")
        (folder / "replays.txt").write_text("")
        return 0
    report.add("\n".join(f"- {mode_sentence(group)}" for group in by_group(modes).values()))
    rows = [[" ".join(m.group), m.label, str(m.count), fmt(m.share, 2), f"seed {m.worst.seed}"] for m in modes]
    report.add(table(["method weather", "mode", "failures", "share", "worst"], rows))
    for condition in conditions:
        commands += _gallery(report, [c for c in cells if c.condition == tuple(condition)], clips_dir, record_dir)
    (folder / "replays.txt").write_text("".join(f"{command}\n" for command in commands))
    return len(commands)


def _gallery(report: Report, cells: Sequence[SafetyCell], clips_dir: Path, record_dir: Path) -> list[str]:
    """One condition's worst clips, each with its replay command (returned)."""
    drawn = [
        (f, cell) for cell in cells for f in cell.failures if (clips_dir / f"{cell.name}-seed{f.seed}.mp4").exists()
    ]
    drawn.sort(key=lambda item: (item[0].margin is None, item[0].margin or 0.0))
    if not drawn:
        return []
    location, weather, noise = cells[0].condition
    report.add(f"### Failure gallery: {location}, {weather}, noise {noise:g}")
    commands = []
    for failure, cell in drawn[:GALLERY_CLIPS]:
        name = f"{cell.name}-seed{failure.seed}"
        gif_of(clips_dir / f"{name}.mp4", report.out_dir / "failures" / f"{name}.gif")
        video = Path(os.path.relpath(clips_dir / f"{name}.mp4", report.out_dir)).as_posix()
        record = Path(os.path.relpath(record_dir / f"{cell.name}.json", report.root)).as_posix()
        commands.append(f"uqdrive replay {record} --seed {failure.seed}")
        report.add(
            f"![{_caption(cell, failure)}](failures/{name}.gif)\n\n*{_caption(cell, failure)}* "
            f"([MP4]({video})) — replay: `{commands[-1]}`"
        )
    return commands


def _caption(cell: SafetyCell, failure: RolloutFailure) -> str:
    return (
        f"{cell.method} seed{cell.replicate}, rollout seed {failure.seed}: {failure.cause} on the {failure.segment} "
        f"at step {failure.step} of {failure.steps}, margin {fmt(failure.margin, 2)}"
        f"{', after a warning' if failure.warned else ''}"
    )
