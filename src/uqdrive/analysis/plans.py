"""The schemas of the stages that turn records into answers: findings (`FindingsStage`), and the safety, avoid and
acquisition summaries (`SafetySummaryStage`, `AvoidSummaryStage`, `AcquireSummaryStage`), each with its section. The
stage functions are `uqdrive.pipeline`'s (`findings_stage`, `safety_summary_stage`, …)."""

from __future__ import annotations

from uqdrive.schema import OpenUnit, Seed, Str, schema
from uqdrive.stage_schemas import NonEmptyNames, NonEmptySeeds, SafetyGrid, Stage


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


@schema
class SafetySummarySection:
    cells_dir: Str
    positions_dir: Str
    out: Str
    figures_dir: Str
    failure_modes: Str  # the failure modes of each method at each weather, for `dvc plots`


@schema(root=True)
class SafetySummaryStage(SafetyGrid):
    summary: SafetySummarySection


@schema
class AvoidSummarySection:
    results_dir: Str
    data_dir: Str
    out: Str
    figures_dir: Str


@schema(root=True)
class AvoidSummaryStage(Stage):
    methods: NonEmptyNames
    replicates: NonEmptySeeds
    summary: AvoidSummarySection


@schema
class AcquireSummarySection:
    experiment: Str  # whose controllers acquired
    alpha: OpenUnit  # family-wise error of the method-level claims
    margin: OpenUnit  # the training cell's non-inferiority margin
    acquire_dir: Str
    out: Str


@schema(root=True)
class AcquireSummaryStage(Stage):
    methods: NonEmptyNames
    replicates: NonEmptySeeds
    summary: AcquireSummarySection
