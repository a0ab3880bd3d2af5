"""One collision-avoidance cell (condition × warnings mode): its rollouts, the warning levels and hand-over places
read off them, distances along the obstacle road, the traces the threshold calibration replays, a figure panel."""

from __future__ import annotations

import dataclasses

import numpy as np

from uqdrive.safety.cell_records import Mode
from uqdrive.safety.replay import Traces
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.warnings import LEVELS, WarningRule
from uqdrive.sim import ScenarioGeometry
from uqdrive.uq import Estimate


@dataclasses.dataclass
class Cell:
    """A finished cell: its estimate, rollouts and the warning rule its warnings are raised or counted with.
    ``reused``: every rollout came from an earlier run's log of the same cell."""

    name: str
    condition: str
    mode: Mode
    rule: WarningRule
    estimate: Estimate
    results: list[RolloutResult]
    seconds: float
    reused: bool
    base_seed: int


def levels(cell: Cell, result: RolloutResult) -> np.ndarray:
    """Warning level per frame: as raised (warnings on) or as the cell's rule would have raised them on the same
    draws (off: read from the recorded η2 counts and MI stages)."""
    if not cell.mode.warnings_off:
        return result.warning
    return cell.rule.levels(result.eta2_counts, result.mi_stages)


def progress_along(geometry: ScenarioGeometry, result: RolloutResult) -> tuple[np.ndarray, float]:
    """Metres along the route at each decision frame, and where the run ended."""
    s, _ = geometry.route.project(np.stack([result.x, result.y], axis=1))
    return s[:-1], float(s[-1])


def obstacle_progress(geometry: ScenarioGeometry) -> float:
    s, _ = geometry.route.project(np.array([[geometry.obstacles[0].x, geometry.obstacles[0].y]]))
    return float(s[0])


def distances(result: RolloutResult, geometry: ScenarioGeometry) -> np.ndarray:
    """Metres to the obstacle along the road at each decision frame."""
    return obstacle_progress(geometry) - progress_along(geometry, result)[0]


def handed_over(cell: Cell) -> list[bool]:
    """Per run, whether the warnings handed control over (always False with warnings off)."""
    if cell.mode.warnings_off:
        return [False] * len(cell.results)
    handover_levels = [lv for lv, a in zip(LEVELS, cell.rule.config.actions) if a.handover]
    return [bool(np.isin(r.warning, handover_levels).any()) for r in cell.results]


def handover_distances(cell: Cell, geometry: ScenarioGeometry) -> list[float]:
    """Distance to the obstacle at the first hand-over frame of each run that handed over (warnings on)."""
    if cell.mode.warnings_off:
        return []
    handover_levels = [lv for lv, a in zip(LEVELS, cell.rule.config.actions) if a.handover]
    out = []
    for r in cell.results:
        fired = np.flatnonzero(np.isin(r.warning, handover_levels))
        if fired.size:
            out.append(float(distances(r, geometry)[fired[0]]))
    return out


def traces_of(cells: list[Cell], geometries: dict[str, ScenarioGeometry], first: int) -> Traces:
    """Rollouts 0 … ``first`` − 1 of the warnings-off ``cells`` as replay input (a number fixed in advance, so
    exact tests on them hold whatever a sequential scheme did next): each frame's recorded η2 counts at the rule's
    looks and MI stages; group g = the g-th cell's condition."""
    runs = []
    for g, cell in enumerate(cells):
        for r in cell.results[:first]:
            s, end = progress_along(geometries[cell.condition], r)
            runs.append((r.eta2_counts, r.mi_stages, s, end, r.safe, g))
    return Traces.from_runs(runs, cells[0].rule.looks)


def obstacle_box(geometry: ScenarioGeometry) -> np.ndarray:
    ob = geometry.obstacles[0]
    return np.array([ob.x, ob.y, ob.size[0], ob.size[1]])


def road_box(geometry: ScenarioGeometry) -> np.ndarray:
    """x range of the road and its lane edges (y), for drawing the straight obstacle road."""
    cfg = geometry.config
    return np.array([0.0, cfg.road_length, -cfg.lane_width, 0.0, cfg.lane_width * (cfg.num_lanes - 1)])


def panel(cell: Cell, geometry: ScenarioGeometry) -> dict:
    """One figure panel: the cell's paths coloured by mutual information on the road."""
    paths = [
        {"x": r.x[:-1], "y": r.y[:-1], "mi": r.mutual_information, "termination": r.termination} for r in cell.results
    ]
    return {
        "paths": paths,
        "obstacle": obstacle_box(geometry),
        "road": road_box(geometry),
        "title": f"η̂1 = {cell.estimate.value:.2f} [{cell.estimate.low:.2f}, {cell.estimate.high:.2f}]",
    }
