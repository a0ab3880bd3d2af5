"""The `findings` stage: the family of paired comparisons over the offline-safety cells and the avoid results, each
decided by its exact test and the family's correction (`uqdrive.analysis.comparisons`), written to
metrics/findings.json."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from uqdrive.analysis.comparisons import Findings, avoid_comparisons, decide, safety_comparisons
from uqdrive.records import write_record
from uqdrive.safety.cell_records import read_avoid_results, read_safety_cells
from uqdrive.schema import OpenUnit, Str, schema, validate
from uqdrive.stage_schemas import SafetyGrid


@schema
class FindingsSection:
    alpha: OpenUnit  # family-wise error over the whole family of comparisons
    cells_dir: Str
    results_dir: Str
    out: Str


@schema(root=True)
class FindingsStage(SafetyGrid):
    """The offline-safety grid, the training weather, and where the cells and the avoid results are."""

    train_weather: Str
    findings: FindingsSection


def run_findings(cfg: DictConfig) -> Findings:
    stage = validate(FindingsStage, cfg)
    methods = list(stage.methods)
    training = (stage.locations[0], stage.train_weather, 0.0)
    family = [
        *safety_comparisons(read_safety_cells(stage.findings.cells_dir, stage), methods, training),
        *avoid_comparisons(read_avoid_results(stage.findings.results_dir, methods, list(stage.replicates)), methods),
    ]
    findings = decide(family, stage.findings.alpha)
    write_record(Path(stage.findings.out), findings)
    return findings
