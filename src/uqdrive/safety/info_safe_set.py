"""The safe set of a Gymnasium world (`uqdrive.sim.gym_world`): a predicate over every step's info.

A path is safe when every recorded step (the reset's included) has each ``safe_if`` key at its required value
(e.g. HighwayEnv: ``crashed: false, on_road: true``), no step is ``unsafe`` by the env's own signals (the world's
``unsafe_if`` keys, ``safe_when`` predicate, a termination that is a failure: `uqdrive.sim.gym_world`) and the
episode did not end in a collision or off the road.
There is no goal beyond staying safe to the horizon, so ``reached_goal`` says the run was safe and drove to its end
(the horizon, or the env ended it otherwise), not stopped by a hand-over; there is no corridor: ``left_corridor``
says the predicate failed at some step, ``corridor_use`` is NaN.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from uqdrive.safety.safe_sets import PathVerdict, SafeSet, safe_set_for
from uqdrive.sim.config import GymWorldConfig
from uqdrive.sim.geometry import ScenarioGeometry
from uqdrive.sim.gym_world import DrivenPath


@dataclass(frozen=True)
class InfoSafeSet:
    """``safe_if``: info key → the value it must have at every step."""

    safe_if: Mapping[str, bool] = field(default_factory=lambda: {"collision": False, "off_road": False})
    kind: str = "info"

    @classmethod
    def of(cls, config: GymWorldConfig) -> InfoSafeSet:
        return cls(dict(config.safe_if))

    def judge(self, lane: DrivenPath, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, termination: str) -> PathVerdict:
        """The verdict on the episode ``lane`` records (a Gymnasium world's lane); the poses are not needed."""
        infos = lane.infos
        held = all(bool(info[key]) == value for info in infos for key, value in self.safe_if.items())
        held = held and not any(info.get("unsafe", False) for info in infos)  # the env's own signals (gym_world)
        collision = termination == "collision" or any(info["collision"] for info in infos)
        off_road = termination == "off_road" or any(info["off_road"] for info in infos)
        safe = held and not (collision or off_road)
        reached = safe and termination in ("timeout", "terminated")
        return PathVerdict(safe, collision, off_road, not held, reached, math.nan)

    def time_to_boundary(self, lane: DrivenPath, x: np.ndarray, y: np.ndarray, yaw: np.ndarray, speed) -> float:
        """NaN: a Gymnasium world's safe set is a predicate on its info (HighwayEnv's holds a crash flag and the
        speed, no distance to an edge or another car), so no time to a boundary is measured."""
        return math.nan

    def boundaries(self) -> None:
        """No corridor to draw."""
        return None


AnySafeSet = SafeSet | InfoSafeSet  # what judges a rollout: a road's lane rule, or a Gymnasium world's predicate


@dataclass(frozen=True)
class SafeSetOf:
    """The safe set where a world drives (a `uqdrive.sim.world.WorldVisitor`): a road's, for a car of ``car_size``
    (length, width) with ``half_width`` (m; None: the lane's), or a Gymnasium world's predicate."""

    car_size: tuple[float, float]
    half_width: float | None

    def road(self, geometry: ScenarioGeometry) -> SafeSet:
        length, width = self.car_size
        return safe_set_for(geometry, width, length, self.half_width)

    def gym(self, world: GymWorldConfig) -> InfoSafeSet:
        return InfoSafeSet.of(world)
