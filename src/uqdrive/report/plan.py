"""The report stage's schema (`ReportStage`, its `ReportSection`) and what a run returns (`ReportFiles`). The stage
function is `uqdrive.pipeline.report_stage`'s."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from uqdrive.report.headline import Headline
from uqdrive.schema import Str, schema
from uqdrive.stage_schemas import NonEmptyNames, SafetyGrid


@schema
class ReportSection:
    out_dir: Str
    summary: Str


@schema(root=True)
class ReportStage(SafetyGrid):
    profile_name: Str
    profile_note: str = ""  # the report's first line: what the profile's sizes can and cannot show
    experiments: NonEmptyNames
    train_weather: Str
    posteriors: NonEmptyNames
    report: ReportSection


@dataclasses.dataclass(frozen=True)
class ReportFiles:
    """The report's files and how many figures it embeds; ``headline``: metrics/summary.json."""

    markdown: Path
    html: Path
    figures: int
    headline: Headline
