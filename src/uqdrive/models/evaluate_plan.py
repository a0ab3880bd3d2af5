"""The evaluate stage's schema (`EvaluateStage`, its `EvaluateSection`) and what a run returns (`Evaluation`). The
stage function is `uqdrive.pipeline.evaluate_stage`'s."""

from __future__ import annotations

import dataclasses

import torch

from uqdrive.data.experiment import Experiment
from uqdrive.models.heldout_eval import HeldoutTable
from uqdrive.schema import Count, Positive, Str, schema
from uqdrive.stage_schemas import Named, NonEmptyMethodNames, NonEmptyNames, NonEmptyNoises, Stage


@schema
class EvaluateSection:
    heldout_dir: Str
    samples: Count  # posterior draws per frame
    eps: Positive  # η2's ball, steering units
    batch_size: Count
    out: Str
    plots_dir: Str


@schema(root=True)
class EvaluateStage(Stage):
    experiment: Experiment
    scenario: Named  # where the held-out frames were collected
    methods: NonEmptyMethodNames
    weathers: NonEmptyNames
    noises: NonEmptyNoises
    evaluate: EvaluateSection


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """The held-out table and each cell's reliability bins (for the plots)."""

    table: HeldoutTable
    reliability: dict[MethodCondition, dict[str, torch.Tensor]]


MethodCondition = tuple[str, str, float]  # method, weather, noise
