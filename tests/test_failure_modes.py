"""Failures grouped into modes: constructed failures of known causes, places and warnings come back as the expected
modes, shares and sentence, per cell, per method at a weather and per method."""

from __future__ import annotations

import dataclasses

from uqdrive.analysis.failure_modes import by_group, failure_modes, mode_sentence, modes_table
from uqdrive.safety.cell_records import SafetyCell
from uqdrive.safety.failures import RolloutFailure
from uqdrive.uq.estimators import Estimate

FAILURE = RolloutFailure(
    index=0, seed=100, condition="", termination="off_road", cause="off road", step=5, steps=9, x=0.0, y=0.0,
    progress=3.0, segment="ring", margin=-1.0, warning=-1, warned=False, eta2=None, mutual_information=0.1,
    path_sha256="0" * 64,
)  # fmt: skip


def cell(method: str, weather: str, failures: list[tuple[str, str, bool, float]], replicate: int = 0) -> SafetyCell:
    """A cell of 10 rollouts whose failures are (cause, segment, warned, margin), the first ones; the rest are safe."""
    rollouts = 10
    records = [
        dataclasses.replace(FAILURE, index=i, seed=100 + i, cause=c, segment=s, warned=w, margin=m)
        for i, (c, s, w, m) in enumerate(failures)
    ]
    numbers = dict.fromkeys(("noise", "seconds", "collision_rate", "off_road_rate"), 0.0)
    numbers |= dict.fromkeys(("left_corridor_rate", "reached_goal_rate", "max_corridor_use", "mean_corridor_use"), 0.0)
    numbers |= dict.fromkeys(("mean_lateral_deviation", "mean_eta2", "mean_mutual_information"), 0.0)
    return SafetyCell(
        method=method, replicate=replicate, experiment="offline", location="roundabout", weather=weather,
        estimate=Estimate(0.0, 0.0, 0.0, rollouts, 0.0, 0.0, "chernoff", True),
        base_seed=100, family_size=1, fixed_rollouts=rollouts, rollouts=rollouts, steps=0,
        outcomes="0" * len(failures) + "1" * (rollouts - len(failures)), config_hash="x", failures=records, **numbers,
    )  # fmt: skip


LATE_EXIT = ("left lane", "exit arm", False)
RAIN = [
    (*LATE_EXIT, -0.5),
    (*LATE_EXIT, -0.2),
    ("collision", "ring", True, -2.0),
    (*LATE_EXIT, -0.9),
    (*LATE_EXIT, -0.1),
]


def test_grouping_constructed_failures_returns_their_modes_most_common_first():
    cells = [
        cell("mcd", "rain", RAIN[:3]),
        cell("mcd", "rain", RAIN[3:], replicate=1),
        cell("vi", "rain", []),
        cell("mcd", "fog", []),
    ]
    per_weather = by_group(failure_modes(cells, "method_weather"))
    assert list(per_weather) == [("mcd", "rain")]  # groups without failures have no modes
    late, crash = per_weather[("mcd", "rain")]
    assert (late.cause, late.segment, late.warned, late.count, late.failures, late.rollouts) == (*LATE_EXIT, 4, 5, 20)
    assert late.share == 0.8 and late.worst.margin == -0.9 and late.worst.seed == 100  # the second cell's first
    assert (crash.cause, crash.segment, crash.warned, crash.count, crash.share) == ("collision", "ring", True, 1, 0.2)
    assert mode_sentence(per_weather[("mcd", "rain")]) == (
        "mcd's rain failures (5 of 20 rollouts) are 80 % left lane on the exit arm, no warning first; "
        "20 % collision on the ring, a warning first."
    )
    per_cell = by_group(failure_modes(cells, "cell"))
    assert [m.count for m in per_cell[(cells[0].name,)]] == [2, 1] and [
        m.count for m in per_cell[(cells[1].name,)]
    ] == [2]
    assert [(m.count, m.failures) for m in failure_modes(cells, "method")] == [(4, 5), (1, 5)]
    rows = modes_table(failure_modes(cells, "method_weather"))
    assert rows[0]["group"] == "mcd rain" and rows[0]["share"] == 0.8 and rows[0]["worst_seed"] == 100


def test_equal_counts_rank_by_the_worst_margin():
    modes = failure_modes([cell("vi", "rain", [("off road", "ring", False, -0.1), ("collision", "ring", False, -3.0)])])
    assert [m.cause for m in modes] == ["collision", "off road"]
    assert mode_sentence([]) == ""
