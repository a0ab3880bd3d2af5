"""The `acquire_summary` stage: every controller's acquisition record of one experiment, summed up per method
(`uqdrive.analysis.acquisition_summary`), written to metrics/acquisition.json."""

from __future__ import annotations

from omegaconf import DictConfig

from uqdrive.analysis.acquisition_summary import AcquisitionSummary, read_acquisitions, summarise_acquisition
from uqdrive.analysis.plans import AcquireSummaryStage
from uqdrive.records import write_record
from uqdrive.schema import validate


def run_acquire_summary(cfg: DictConfig) -> AcquisitionSummary:
    stage = validate(AcquireSummaryStage, cfg)
    s = stage.summary
    controllers = read_acquisitions(s.acquire_dir, list(stage.methods), list(stage.replicates))
    summary = summarise_acquisition(s.experiment, controllers, s.alpha, s.margin)
    write_record(s.out, summary)
    return summary


def describe(summary: AcquisitionSummary, out: str) -> str:
    """One line per method and check cell, then where the file went."""
    lines = [
        f"acquire {g.method} round {g.round} at {g.cell}: {g.behaviour_cloned:.2f} -> {g.acquired:.2f} "
        f"(expert {g.expert:.2f}), {g.claim.verdict}{f', {g.non_inferior}' if g.non_inferior else ''}"
        for g in summary.methods
    ]
    rounds = max((s.round for a in summary.controllers for s in a.rounds), default=0)
    lines.append(f"acquisition: {len(summary.controllers)} controllers, up to round {rounds} -> {out}")
    return "\n".join(lines)
