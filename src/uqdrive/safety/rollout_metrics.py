"""The one registry of what each rollout records beside its verdict, and how a cell summarises it: the failure rates,
the corridor use, the tracking error, the policy's confidence. A cell record's summaries (`SafetyCell`, `AvoidCell`,
`CertifyRecord`) and the report's table of them are computed here, once, with one handling of missing values: a
rollout that did not measure a quantity (NaN: no lane rule in a Gymnasium world, no η2 set drawn) is left out, and a
summary over no measured rollout is None (null in the file)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from uqdrive.safety.rollout import RolloutResult


@dataclass(frozen=True)
class RolloutMetric:
    """One per-rollout quantity (``of_run``: a rollout's value, NaN where it measured none) summarised over a cell's
    rollouts by ``summary`` into the cell's key ``name``; ``label``: its words in the report (a table header: no
    ``|``)."""

    name: str
    label: str
    of_run: Callable[[RolloutResult], float]
    summary: Callable[[np.ndarray], float] = np.mean


METRICS = (
    RolloutMetric("collision_rate", "collisions", lambda r: r.verdict.collision),
    RolloutMetric("off_road_rate", "off road", lambda r: r.verdict.off_road),
    RolloutMetric("left_corridor_rate", "left lane", lambda r: r.verdict.left_corridor),
    RolloutMetric("reached_goal_rate", "reached goal", lambda r: r.verdict.reached_goal),
    RolloutMetric("max_corridor_use", "worst corridor use", lambda r: r.verdict.corridor_use, np.max),
    RolloutMetric("mean_corridor_use", "mean corridor use", lambda r: r.verdict.corridor_use),
    RolloutMetric("mean_lateral_deviation", "mean lateral deviation (m)", lambda r: r.mean_abs_lateral_deviation),
    RolloutMetric("mean_eta2", "mean η2", lambda r: r.mean_eta2),
    RolloutMetric("mean_mutual_information", "mean mutual information", lambda r: r.mean_mutual_information),
    RolloutMetric(
        "median_time_to_boundary", "median time to lane edge (s)", lambda r: r.min_time_to_boundary, np.median
    ),
)
BY_NAME = {m.name: m for m in METRICS}


def summarise(results: Sequence[RolloutResult], names: Sequence[str] | None = None) -> dict[str, float | None]:
    """Each metric of ``names`` (all: None) over ``results``: its summary over the rollouts that measured it, None
    where none did."""
    return {name: summary_of(BY_NAME[name], results) for name in (names or BY_NAME)}


def summary_of(metric: RolloutMetric, results: Sequence[RolloutResult]) -> float | None:
    values = [float(metric.of_run(r)) for r in results]
    finite = [v for v in values if not math.isnan(v)]
    return float(metric.summary(np.array(finite))) if finite else None
