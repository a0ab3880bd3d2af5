"""The unknown conditions as one cell: rollout i drives the variant its seed draws, uniformly among them.

The paper reports collision avoidance "in unknown conditions" as one number. One cell per variant gives each its own
interval but costs a full sample each; one cell whose rollouts draw their variant makes every outcome an
independent Bernoulli draw of rate η1 = the variants' mean, so any estimator of `uqdrive.uq` (the sequential
scheme included) gives the mixture's η1 with its own guarantee in one sample. The variant comes from rollout
i's seed alone, on a stream apart from the episode's, so a cell on the same seeds (warnings off and on, the
known condition) drives rollout i in the same variant, rollout i is the same in any process, batch or order,
and it is exactly rollout i of that variant's own cell (the same job less the draw).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from uqdrive.envelope.rollouts import ConditionWorker
from uqdrive.envelope.space import World
from uqdrive.safety.executors import PolicySpec
from uqdrive.sim import CameraConfig, VehicleConfig

VARIANT_STREAM = 0xA401D  # the variant's own random stream of a rollout seed


def variant_of(seed: int, count: int) -> int:
    """The variant (0 … count − 1) rollout seed ``seed`` drives: uniform, independent across seeds."""
    return int(np.random.default_rng([VARIANT_STREAM, seed]).integers(count))


@dataclasses.dataclass(frozen=True)
class MixtureJob:
    """Rollout i of a mixture cell: seed ``base_seed + i`` in variant `variant_of` of ``variants``."""

    policy: PolicySpec
    variants: tuple[World, ...]
    base_seed: int
    camera: CameraConfig = dataclasses.field(default_factory=CameraConfig)
    vehicle: VehicleConfig = dataclasses.field(default_factory=VehicleConfig)
    control_hz: float = 15.0
    horizon_s: float = 40.0
    half_width: float | None = None

    def variant(self, index: int) -> int:
        return variant_of(self.base_seed + index, len(self.variants))

    def world(self, index: int) -> World:
        return self.variants[self.variant(index)]

    def worker(self, width: int = 1) -> ConditionWorker:
        return ConditionWorker(self, width)
