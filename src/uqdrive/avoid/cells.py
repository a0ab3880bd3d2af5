"""One collision-avoidance cell (condition × warnings mode): its rollouts, the warning levels and hand-over places
read off them, distances along the obstacle road, the traces the threshold calibration replays, a figure panel, the
rows and arrays its files hold; and the stage's run of them all (`AvoidRun`).

A Gymnasium world (`OwnPath`) has no road of ours and no fixed hazard: progress is metres driven along the run's
own path, a frame's distance is the metres left before the run ended (where an unsafe run crashed or left the
road), and no hand-over has a distance to an obstacle."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from uqdrive.avoid.calibration import Calibration
from uqdrive.avoid.course import Course, distances, progress_along
from uqdrive.avoid.plan import AvoidSettings
from uqdrive.avoid.results import FreshSeedCheck, Mode
from uqdrive.avoid.trace_replay import Traces
from uqdrive.policy.warnings import LEVELS, WarningRule
from uqdrive.safety.failures import RolloutFailure
from uqdrive.safety.rollout import RolloutResult
from uqdrive.uq import Estimate


@dataclasses.dataclass
class Cell:
    """A finished cell: its estimate, rollouts and the warning rule its warnings are raised or counted with.
    ``reused``: every rollout came from an earlier run's log of the same cell. ``failures``: its failing runs
    (`uqdrive.safety.failures.job_failures`)."""

    name: str
    condition: str
    mode: Mode
    rule: WarningRule
    estimate: Estimate
    results: list[RolloutResult]
    seconds: float
    reused: bool
    base_seed: int
    failures: list[RolloutFailure]


@dataclasses.dataclass(frozen=True)
class AvoidRun:
    """One avoid stage's work, each part computed once by its drive: the settings it ran, the condition names (the
    known one first) and their road geometries, every cell by condition and mode, the calibration, the replay at the
    configured thresholds against closed loop (`calibration.replay_check`) and the fresh-seed check of the deployed
    rule. Its answers, figures, files and logging read it."""

    settings: AvoidSettings
    names: list[str]
    geometries: dict[str, Course]
    cells: dict[tuple[str, Mode], Cell]
    calibration: Calibration
    replay_check: dict[str, dict[str, float]]
    fresh_check: FreshSeedCheck
    seconds: float


def levels(cell: Cell, result: RolloutResult) -> np.ndarray:
    """Warning level per frame: as raised (warnings on) or as the cell's rule would have raised them on the same
    draws (off: read from the recorded η2 counts and MI stages)."""
    if not cell.mode.warnings_off:
        return result.warning
    return cell.rule.levels(result.eta2_counts, result.mi_stages)


def handed_over(cell: Cell) -> list[bool]:
    """Per run, whether the warnings handed control over (always False with warnings off)."""
    if cell.mode.warnings_off:
        return [False] * len(cell.results)
    handover_levels = [lv for lv, a in zip(LEVELS, cell.rule.config.actions) if a.handover]
    return [bool(np.isin(r.warning, handover_levels).any()) for r in cell.results]


def handover_distances(cell: Cell, course: Course) -> list[float]:
    """Distance to the obstacle at the first hand-over frame of each run that handed over (warnings on; none in a
    Gymnasium world: it has no obstacle)."""
    if cell.mode.warnings_off or not course.fixed_hazard:
        return []
    handover_levels = [lv for lv, a in zip(LEVELS, cell.rule.config.actions) if a.handover]
    out = []
    for r in cell.results:
        fired = np.flatnonzero(np.isin(r.warning, handover_levels))
        if fired.size:
            out.append(float(distances(r, course)[fired[0]]))
    return out


def traces_of(cells: list[Cell], geometries: dict[str, Course], first: int) -> Traces:
    """Rollouts 0 … ``first`` − 1 of the warnings-off ``cells`` as replay input (a number fixed in advance, so
    exact tests on them hold whatever a sequential scheme did next): each frame's recorded η2 counts at the rule's
    looks and MI stages; group g = the g-th cell's condition."""
    runs = []
    for g, cell in enumerate(cells):
        for r in cell.results[:first]:
            s, end = progress_along(geometries[cell.condition], r)
            runs.append((r.eta2_counts, r.mi_stages, s, end, r.verdict.safe, g))
    return Traces.from_runs(runs, cells[0].rule.looks)


def panel(cell: Cell, course: Course) -> dict:
    """One figure panel: the cell's paths coloured by mutual information on the road."""
    paths = [
        {"x": r.x[:-1], "y": r.y[:-1], "mi": r.mutual_information, "termination": r.termination} for r in cell.results
    ]
    return {
        "paths": paths,
        "obstacle": course.obstacle_box(),
        "road": course.road_box(),
        "title": f"η̂1 = {cell.estimate.value:.2f} [{cell.estimate.low:.2f}, {cell.estimate.high:.2f}]",
    }


def rollout_rows(cell: Cell) -> list[dict]:
    """Per-rollout rows of a cell's table: outcome, steps, time at full speed, min η2, max MI, frames per warning
    level."""
    rows = []
    for r in cell.results:
        lv = levels(cell, r)
        rows.append(
            {
                **r.summary(),
                "min_eta2": float(np.min(r.eta2)) if r.steps else math.nan,
                "max_mutual_information": float(np.max(r.mutual_information)) if r.steps else math.nan,
                **{f"warning{level}_frames": int(np.sum(lv == level)) for level in LEVELS},
            }
        )
    return rows


def cell_arrays(cell: Cell, course: Course) -> dict[str, np.ndarray | float]:
    """Per-frame traces of a cell for the summary figure: positions, distance (`distances`), η2, MI, level; each
    run's termination and outcome, η̂1, the obstacle and road boxes (empty in a Gymnasium world)."""
    frames: dict[str, list[np.ndarray]] = {k: [] for k in ("rollout", "x", "y", "distance", "eta2", "mi", "level")}
    for i, r in enumerate(cell.results):
        for key, value in (
            ("rollout", np.full(r.steps, i)),
            ("x", r.x[:-1]),
            ("y", r.y[:-1]),
            ("distance", distances(r, course)),
            ("eta2", r.eta2),
            ("mi", r.mutual_information),
            ("level", levels(cell, r)),
        ):
            frames[key].append(value)
    return {
        **{k: np.concatenate(v) if v else np.zeros(0) for k, v in frames.items()},
        "termination": np.array([r.termination for r in cell.results]),
        "safe": np.array([r.verdict.safe for r in cell.results]),
        "eta1": cell.estimate.value,
        "obstacle": course.obstacle_box(),
        "road": course.road_box(),
    }


def signal_rows(cells: list[Cell], courses: dict[str, Course]) -> list[dict]:
    """η2 and MI per frame against the distance (`distances`): the rows of a DVC plot."""
    return [
        {
            "condition": cell.condition,
            "rollout": i,
            "distance": f"{d:.3f}",
            "eta2": f"{e:.4f}",
            "mutual_information": f"{m:.4f}",
            "outcome": r.termination,
        }
        for cell in cells
        for i, r in enumerate(cell.results)
        for d, e, m in zip(distances(r, courses[cell.condition]), r.eta2, r.mutual_information)
    ]
