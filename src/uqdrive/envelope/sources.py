"""Where an envelope cell's rollouts drive: condition sources over its condition space for the one rollout job
(`uqdrive.safety.executors.RolloutJob`), rollout i at the source's i-th condition with seed ``base_seed + i``.

Two sources: the conditions phase one chose (`Listed`), and uniform draws in a region (`UniformIn`), where
condition i comes from rollout i's seed alone, so rollout i has the same world and outcome in any process, in
any order, and when a rerun replays it from the cell's log.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from uqdrive.envelope.space import ConditionSpace
from uqdrive.sim.condition import Condition

CONDITION_STREAM = 0xE17E  # the condition's own random stream of a rollout seed, apart from the episode's


@dataclasses.dataclass(frozen=True)
class Listed:
    """Rollout i at the i-th of these points of the space's unit cube."""

    space: ConditionSpace
    points: tuple[tuple[float, ...], ...]

    @property
    def title(self) -> str:
        return f"{len(self.points)} listed conditions"

    @property
    def base(self) -> Condition:
        """The world the axes vary (what a cell's identity reads beyond the points)."""
        return self.space.base

    def point(self, index: int, seed: int) -> np.ndarray:
        return np.asarray(self.points[index], dtype=float)

    def condition(self, index: int, seed: int) -> Condition:
        return self.space.condition(self.point(index, seed))


@dataclasses.dataclass(frozen=True)
class UniformIn:
    """Rollout i at a condition drawn uniformly in the box [low, high) of the space's unit cube, from its seed."""

    space: ConditionSpace
    low: tuple[float, ...]
    high: tuple[float, ...]

    @property
    def title(self) -> str:
        return f"uniform in {self.low}–{self.high}"

    @property
    def base(self) -> Condition:
        """The world the axes vary (what a cell's identity reads beyond the box)."""
        return self.space.base

    def point(self, index: int, seed: int) -> np.ndarray:
        u = np.random.default_rng([CONDITION_STREAM, seed]).random(len(self.low))
        return np.asarray(self.low) + u * (np.asarray(self.high) - np.asarray(self.low))

    def condition(self, index: int, seed: int) -> Condition:
        return self.space.condition(self.point(index, seed))
