"""A stage that fits or drives a posterior: the experiment it belongs to and the posterior's settings, checked."""

from __future__ import annotations

from typing import Any

from uqdrive.data.experiment import Experiment
from uqdrive.schema import schema
from uqdrive.stage_schemas import Stage


@schema(root=True)
class ModelStage(Stage):
    """A stage that fits or drives a posterior: `model` (conf/model/<method>.yaml) is that class's settings."""

    experiment: Experiment
    model: dict[str, Any]

    def __post_init__(self) -> None:
        from uqdrive.models.posterior import posterior_settings  # here: a collect worker imports no torch

        posterior_settings(self.model)
