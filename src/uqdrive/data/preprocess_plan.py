"""The preprocess stage's schema (`PreprocessStage`, its `PreprocessSection`). The stage function is
`uqdrive.pipeline.preprocess_stage`'s."""

from __future__ import annotations

from uqdrive.data.experiment import Experiment
from uqdrive.schema import OpenUnit, Seed, schema
from uqdrive.stage_schemas import Stage


@schema
class PreprocessSection:
    val_fraction: OpenUnit
    split_seed: Seed


@schema(root=True)
class PreprocessStage(Stage):
    experiment: Experiment
    preprocess: PreprocessSection
