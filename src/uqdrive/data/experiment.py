"""An experiment's config: the collected scenarios it trains on and its class set (the steering bins)."""

from __future__ import annotations

from uqdrive.data.binning import SteeringBins
from uqdrive.schema import schema
from uqdrive.stage_schemas import NonEmptyNames, Str


@schema
class Experiment:
    """conf/experiment/<name>.yaml: the collected scenarios an experiment trains on, and its class set."""

    name: Str
    scenarios: NonEmptyNames
    bins: SteeringBins
