"""The offline-safety cell's record (metrics/safety/<cell>.json): its outcomes in rollout order, so cells on the same
seeds pair."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np

from uqdrive.records import flattened, read_record, record
from uqdrive.resolvers import condition_label
from uqdrive.safety.failures import RolloutFailure
from uqdrive.uq.estimators import Estimate

ESTIMATE_KEYS = {"value": "eta1", "low": "eta1_low", "high": "eta1_high"}  # a cell's `Estimate` as its file names it


def safety_cell_name(method: str, replicate: int, location: str, weather: str, noise: float) -> str:
    """A cell's name in file names and runs, as conf/safety.yaml's `safety.cell` spells it."""
    return f"{method}-seed{replicate}-{condition_label(location, weather, noise)}"


@record
class SafetyCell:
    """One offline-safety cell: η̂1 of one controller (method × replicate) at one condition, how its runs failed,
    and ``outcomes``: each rollout's verdict in index order ("1" safe), which pairs it with every other cell."""

    method: str
    replicate: int
    experiment: str
    location: str
    weather: str
    noise: float
    estimate: Estimate = flattened(ESTIMATE_KEYS, left=("condition",))  # η̂1, its interval, θ, γ, scheme, n
    base_seed: int
    family_size: int  # cells γ was spread over (1: the guarantee holds per cell)
    fixed_rollouts: int  # rollouts the scheme runs whatever the outcomes: the prefix exact tests may use
    rollouts: int
    steps: int
    seconds: float
    collision_rate: float
    off_road_rate: float
    left_corridor_rate: float
    reached_goal_rate: float
    max_corridor_use: float | None
    mean_corridor_use: float | None
    mean_lateral_deviation: float
    mean_eta2: float | None  # None: the controller drew no η2 set (sequential draws acting on no warning)
    mean_mutual_information: float
    outcomes: str
    config_hash: str
    median_time_to_boundary: float | None = None  # s, over the runs of each run's least time to its lane's edge
    unread: int = 0  # rollouts run ahead of a sequential estimator that it never read: time spent, not error
    margins: list[float | None] = dataclasses.field(default_factory=list)  # each run's `PathVerdict.margin`, in order
    failures: list[RolloutFailure] = dataclasses.field(default_factory=list)  # the failing runs, worst margin first
    overrides: list[str] = dataclasses.field(default_factory=list)  # the Hydra overrides composing the cell (replay)

    @property
    def condition(self) -> tuple[str, str, float]:
        return self.location, self.weather, self.noise

    @property
    def name(self) -> str:
        return safety_cell_name(self.method, self.replicate, self.location, self.weather, self.noise)

    @property
    def safe(self) -> np.ndarray:
        return np.frombuffer(self.outcomes.encode(), np.uint8) == ord("1")

    @property
    def margin(self) -> np.ndarray:
        """Each run's margin in rollout order (NaN: none recorded)."""
        return np.array([math.nan if m is None else m for m in self.margins], float)


def read_safety_cells(folder: str | Path, grid: Any) -> list[SafetyCell]:
    """Every cell of the ``grid`` (its methods × replicates × locations × weathers × noises), as written."""
    return [
        read_record(SafetyCell, Path(folder) / f"{safety_cell_name(m, r, loc, w, x)}.json", "safety")
        for m in grid.methods
        for r in grid.replicates
        for loc in grid.locations
        for w in grid.weathers
        for x in grid.noises
    ]
