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
from uqdrive.avoid.results import read_avoid_results
from uqdrive.records import write_record
from uqdrive.safety.cell_records import read_safety_cells
from uqdrive.schema import OpenUnit, Seed, Str, schema, validate
from uqdrive.stage_schemas import SafetyGrid


@schema
class FindingsSection:
    alpha: OpenUnit  # family-wise error of each family (the controller-level one; each method-level one)
    margin: OpenUnit  # δ: two methods within ±δ of each other are equivalent (a method-level verdict)
    experiment: Str  # whose controllers drove the cells: offline (the paper's), or a Gymnasium world's experiment
    cells_dir: Str
    results_dir: Str  # the avoid results
    runs_needed_sims: Seed  # simulated studies per run count for the paper claims' runs needed (0: not computed)
    out: Str


@schema(root=True)
class FindingsStage(SafetyGrid):
    """The offline-safety grid, the training weather, and where the cells and the avoid results are."""

    train_weather: Str
    findings: FindingsSection


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
