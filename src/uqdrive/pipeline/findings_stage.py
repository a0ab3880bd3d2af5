"""The `findings` stage: the family of paired comparisons over the offline-safety cells and the avoid results, each
decided by its exact test and the family's correction (`uqdrive.analysis.comparisons`), written to
metrics/findings.json. The same over a Gymnasium world's safety sweep and avoid results (conf/gym_findings.yaml),
without the paper's claims (they are about its roundabout)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from omegaconf import DictConfig

from uqdrive.analysis.comparisons import Findings, avoid_comparisons, decide, safety_comparisons
from uqdrive.analysis.method_claims import check_replicates, method_claims
from uqdrive.analysis.plans import FindingsStage
from uqdrive.avoid.results import read_avoid_results
from uqdrive.records import write_record
from uqdrive.safety.cell_records import read_safety_cells
from uqdrive.schema import validate


def run_findings(cfg: DictConfig) -> Findings:
    """Read the records, decide the controller-level family and the method-level claims, write them."""
    stage = validate(FindingsStage, cfg)
    methods, settings = list(stage.methods), stage.findings
    training = (stage.locations[0], stage.train_weather, 0.0)
    cells = read_safety_cells(settings.cells_dir, stage)
    results = read_avoid_results(settings.results_dir, methods, list(stage.replicates))
    check_replicates(cells, results, methods)
    family = [*safety_comparisons(cells, methods, training, settings.experiment), *avoid_comparisons(results, methods)]
    paper = settings.experiment == "offline"
    claims = method_claims(
        cells, results, methods, training, settings.alpha, settings.margin, paper, settings.runs_needed_sims
    )
    findings = dataclasses.replace(decide(family, settings.alpha), margin=settings.margin, claims=claims)
    write_record(Path(settings.out), findings)
    return findings
