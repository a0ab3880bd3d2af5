"""The registry of per-rollout metrics: each cell summary over the rollouts that measured it, None where none did."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.rollout_metrics import METRICS, summarise
from uqdrive.safety.safe_sets import PathVerdict


def run(collision: bool, corridor_use: float, eta2: float) -> RolloutResult:
    verdict = PathVerdict(not collision, collision, False, corridor_use > 1, True, corridor_use)
    return RolloutResult(0, "timeout", verdict, 0.1, eta2, 0.2, 10, np.zeros(11), np.zeros(11))


def test_a_summary_leaves_out_the_runs_that_measured_nothing_and_is_none_where_none_did():
    runs = [run(True, 0.5, math.nan), run(False, 1.5, math.nan), run(False, math.nan, math.nan)]
    got = summarise(runs)
    assert got["collision_rate"] == pytest.approx(1 / 3) and got["left_corridor_rate"] == pytest.approx(1 / 3)
    assert got["max_corridor_use"] == 1.5 and got["mean_corridor_use"] == pytest.approx(1.0)  # the NaN run left out
    assert got["mean_eta2"] is None  # no run drew an η2 set
    assert set(got) == {m.name for m in METRICS} and summarise(runs, ("off_road_rate",)) == {"off_road_rate": 0.0}
