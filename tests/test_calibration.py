"""Replaying warning thresholds over recorded warnings-off runs, and choosing them on the paper's joint claim:
the most unknown-condition safety whose known-condition autonomy bound meets the target."""

import dataclasses
import math

import numpy as np
import pytest

from uqdrive.safety.calibration import NEVER_FIRES, Traces, calibrate, candidates, min_known_runs, replay
from uqdrive.safety.warnings import WarningConfig
from uqdrive.uq import clopper_pearson_interval

FAST = WarningConfig(theta=0.3)  # the paper's thresholds and actions
ARGS = {"control_hz": 15.0, "cruise": 8.0, "start_speed": 8.0, "max_accel": 3.0, "max_brake": 6.0, "margin_m": 0.5}


def traces() -> Traces:
    """Three warnings-off runs, frames 1 m apart: a safe one that wavers (η2 0.9 once), one that dips to
    η2 = 0.5 twenty metres before it collides, one that collides with no warning sign at all."""
    s = np.arange(30.0)
    calm, wavers = np.ones(30), np.ones(30)
    wavers[12] = 0.9
    dips = np.ones(30)
    dips[9] = 0.5
    runs = [
        (wavers, np.zeros(30), s, 29.0, True, 0),
        (dips, np.zeros(30), s, 29.0, False, 1),
        (calm, np.zeros(30), s, 29.0, False, 1),
    ]
    return Traces.from_runs(runs)


def test_replay_saves_a_run_only_if_warning_2_fires_a_stopping_distance_before_the_collision():
    t = traces()
    out = replay(t, np.array([0.7, 0.95, 0.7]), np.array([0.6, 0.95, 0.4]), np.array([0.45] * 3), FAST, **ARGS)
    assert out.handover.tolist() == [[False, True, False], [True, True, False], [False, False, False]]
    assert out.safe.tolist() == [[True, True, False], [True, True, False], [True, False, False]]
    # the same dip 3 m before the collision is too late at 8 m/s (5.3 m to stop)
    late = dataclasses.replace(t, end_progress=np.array([29.0, 12.0, 29.0]))
    assert not replay(late, np.array([0.7]), np.array([0.6]), np.array([0.45]), FAST, **ARGS).safe[0, 1]


def random_traces(rng: np.random.Generator, known: int, unknown: int) -> Traces:
    """Known runs that are safe but waver now and then; unknown runs that dip before colliding, or not at all."""
    s = np.arange(40.0)
    runs = []
    for _ in range(known):
        eta2 = np.ones(40)
        eta2[rng.integers(0, 40, 2)] = rng.uniform(0.55, 1.0, 2)
        runs.append((eta2, rng.uniform(0, 0.5, 40), s, 39.0, True, 0))
    for _ in range(unknown):
        eta2 = np.ones(40)
        if rng.random() < 0.7:
            eta2[int(rng.integers(5, 25))] = rng.uniform(0.3, 0.95)
        runs.append((eta2, rng.uniform(0, 0.5, 40), s, 39.0, bool(rng.random() < 0.2), 1))
    return Traces.from_runs(runs)


@pytest.mark.parametrize("target", [0.6, 0.8, 0.85])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_calibration_never_returns_thresholds_below_the_autonomy_target(target, seed):
    t = random_traces(np.random.default_rng(seed), known=30, unknown=40)
    deltas, taus = [0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0], [0.3, 0.45]
    calib = calibrate(t, ["known", "unknown"], FAST, deltas, taus, target=target, gamma=0.05, **ARGS)
    table, chosen = calib.table, calib.chosen
    # the bound is recomputed here from the replayed hand-overs, independently of the table's own column
    handovers = replay(
        t, table["delta1"][[chosen]], table["delta2"][[chosen]], table["tau"][[chosen]], FAST, **ARGS
    ).handover[0, t.group == 0]
    low, _ = clopper_pearson_interval(int((~handovers).sum()), len(handovers), 0.05)
    assert calib.feasible and low >= target
    # and among the candidates that meet the target, no other is safer in the unknown condition
    assert table["eta1_unknown"][chosen] == table["eta1_unknown"][table["feasible"]].max()
    always = np.flatnonzero(table["delta2"] == 1.0)  # hand over at the first frame with any disagreement
    assert not table["feasible"][always].any() and table["autonomy"][always].max() < 0.5


def test_the_never_firing_candidate_is_on_every_grid_and_too_few_known_runs_are_refused():
    d1, d2, t = candidates([0.7], [0.45])
    assert NEVER_FIRES in list(zip(d1, d2, t))
    for target in (0.3, 0.8, 0.95):  # n/n has exact lower bound (γ/2)^(1/n): the fewest n reaching the target
        assert min_known_runs(target, 0.05) == math.ceil(math.log(0.025) / math.log(target))
    with pytest.raises(
        ValueError, match="target=0.8 needs at least 17 known-condition runs at gamma=0.05; there are 1"
    ):
        calibrate(traces(), ["known", "unknown"], FAST, [0.7], [0.45], target=0.8, gamma=0.05, **ARGS)


def test_a_silent_failure_is_never_saved_by_any_threshold():
    calib = calibrate(
        traces(), ["known", "unknown"], FAST, [0.5, 0.6, 0.7, 0.9, 0.95, 1.0], [0.45], target=0.02, gamma=0.05, **ARGS
    )
    # the dipping collision can be saved, the silent one never: unknown η̂1 tops out at 1/2
    assert calib.table["eta1_unknown"].max() == 0.5 and calib.table["eta1_unknown"][calib.chosen] == 0.5
