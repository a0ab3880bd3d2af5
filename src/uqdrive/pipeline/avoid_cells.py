"""One collision-avoidance cell (condition × warnings mode) and what is measured on it: η̂1 with its
interval, autonomy, passed and timeout rates, where hand-overs happened, warning counts; the
replay traces, and the per-cell tables and figures data the avoid stage writes.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from pathlib import Path

import numpy as np

from uqdrive.files import atomic_path, write_csv
from uqdrive.pipeline.records import WARNINGS_OFF, AvoidCell
from uqdrive.safety.calibration import Calibration, Traces
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.warnings import LEVELS, WarningConfig, classify
from uqdrive.sim import ScenarioGeometry
from uqdrive.uq import Estimate


@dataclasses.dataclass
class Cell:
    """A finished cell: its estimate, rollouts and the thresholds its warnings are counted with.
    ``reused``: every rollout came from an earlier run's log of the same cell."""

    name: str
    condition: str
    mode: str
    warning: WarningConfig
    estimate: Estimate
    results: list[RolloutResult]
    seconds: float
    reused: bool
    base_seed: int


def levels(cell: Cell, result: RolloutResult) -> np.ndarray:
    """Warning level per frame: as raised (warnings on) or as the cell's thresholds would have raised them (off)."""
    if cell.mode not in WARNINGS_OFF:
        return result.warning
    w = cell.warning
    return classify(result.eta2, result.mutual_information, w.delta1, w.delta2, w.tau)


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


def handover_distances(cell: Cell, geometry: ScenarioGeometry) -> list[float]:
    """Distance to the obstacle at the first hand-over frame of each run that handed over (warnings on)."""
    if cell.mode in WARNINGS_OFF:
        return []
    handover_levels = [lv for lv, a in zip(LEVELS, cell.warning.actions) if a.handover]
    out = []
    for r in cell.results:
        fired = np.flatnonzero(np.isin(r.warning, handover_levels))
        if fired.size:
            out.append(float(distances(r, geometry)[fired[0]]))
    return out


def cell_metrics(
    cell: Cell, cruise: float, geometry: ScenarioGeometry, fixed_rollouts: int, family_size: int
) -> AvoidCell:
    """η̂1 with its interval, autonomy, passed and timeout rates, hand-over distances, warning counts, and each
    run's verdict in rollout order (``fixed_rollouts``: how many every cell runs whatever the outcomes)."""
    results, est = cell.results, cell.estimate
    handover_levels = [lv for lv, a in zip(LEVELS, cell.warning.actions) if a.handover]
    per_run = [levels(cell, r) for r in results]
    handed = [cell.mode not in WARNINGS_OFF and bool(np.isin(lv, handover_levels).any()) for lv in per_run]
    steps = sum(r.steps for r in results)
    full = sum(int(np.sum(r.command_speed >= cruise - 1e-9)) for r in results)
    where = handover_distances(cell, geometry)
    metrics = {
        "eta1": est.value,
        "eta1_low": est.low,
        "eta1_high": est.high,
        "n": est.n,
        "handover_rate": float(np.mean(handed)),
        "autonomy": 1 - float(np.mean(handed)),
        "full_speed_fraction": full / max(steps, 1),
        "collision_rate": float(np.mean([r.collision for r in results])),
        "off_road_rate": float(np.mean([r.off_road for r in results])),
        "passed_rate": float(np.mean([r.reached_goal for r in results])),
        # ran out of time before passing the obstacle without having stopped: no answer, never safe
        "timeout_before_obstacle_rate": float(
            np.mean([r.termination == "timeout" and not r.reached_goal for r in results])
        ),
        "handover_distance_min": min(where, default=None),  # None (JSON null): no hand-over
        "handover_distance_median": float(np.median(where)) if where else None,
        "handover_distances": [round(d, 2) for d in where],
        "mean_steps": steps / len(results),
        "seconds": cell.seconds,
        "reused": cell.reused,
    }
    for level in LEVELS:
        metrics[f"warning{level}_frames"] = int(sum(int(np.sum(lv == level)) for lv in per_run))
        metrics[f"warning{level}_runs"] = int(sum(bool(np.any(lv == level)) for lv in per_run))
    return AvoidCell(
        **metrics,
        terminations=dict(sorted(Counter(r.termination for r in results).items())),
        guaranteed=est.guaranteed,
        scheme=est.scheme,
        theta=est.theta,
        gamma=est.gamma,
        family_size=family_size,
        fixed_rollouts=fixed_rollouts,
        thresholds={"delta1": cell.warning.delta1, "delta2": cell.warning.delta2, "tau": cell.warning.tau},
        base_seed=cell.base_seed,
        outcomes="".join("1" if r.safe else "0" for r in results),
    )


def traces_of(cells: list[Cell], geometries: dict[str, ScenarioGeometry], first: int) -> Traces:
    """Rollouts 0 … ``first`` − 1 of the warnings-off ``cells`` as replay input (a number fixed in advance, so
    exact tests on them hold whatever a sequential scheme did next); group g = the g-th cell's condition."""
    runs = []
    for g, cell in enumerate(cells):
        for r in cell.results[:first]:
            s, end = progress_along(geometries[cell.condition], r)
            runs.append((r.eta2, r.mutual_information, s, end, r.safe, g))
    return Traces.from_runs(runs)


def write_cell_table(path: Path, cell: Cell) -> Path:
    """Per-rollout rows: outcome, steps, time at full speed, min η2, max MI, frames per warning level."""
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
    return write_csv(path, rows)


def obstacle_box(geometry: ScenarioGeometry) -> np.ndarray:
    ob = geometry.obstacles[0]
    return np.array([ob.x, ob.y, ob.size[0], ob.size[1]])


def road_box(geometry: ScenarioGeometry) -> np.ndarray:
    """x range of the road and its lane edges (y), for drawing the straight obstacle road."""
    cfg = geometry.config
    return np.array([0.0, cfg.road_length, -cfg.lane_width, 0.0, cfg.lane_width * (cfg.num_lanes - 1)])


def write_cell_data(path: Path, cell: Cell, geometry: ScenarioGeometry) -> Path:
    """Per-frame traces of a cell (npz) for the summary figure: positions, distance to the obstacle, η2, MI, level."""
    frames: dict[str, list[np.ndarray]] = {k: [] for k in ("rollout", "x", "y", "distance", "eta2", "mi", "level")}
    for i, r in enumerate(cell.results):
        for key, value in (
            ("rollout", np.full(r.steps, i)),
            ("x", r.x[:-1]),
            ("y", r.y[:-1]),
            ("distance", distances(r, geometry)),
            ("eta2", r.eta2),
            ("mi", r.mutual_information),
            ("level", levels(cell, r)),
        ):
            frames[key].append(value)
    with atomic_path(path) as tmp, tmp.open("wb") as f:
        np.savez_compressed(
            f,
            **{k: np.concatenate(v) if v else np.zeros(0) for k, v in frames.items()},
            termination=np.array([r.termination for r in cell.results]),
            safe=np.array([r.safe for r in cell.results]),
            eta1=cell.estimate.value,
            obstacle=obstacle_box(geometry),
            road=road_box(geometry),
        )
    return path


def write_signals(path: Path, cells: list[Cell], geometries: dict[str, ScenarioGeometry]) -> Path:
    """η2 and MI per frame against the distance to the obstacle (a DVC plot)."""
    return write_csv(
        path,
        [
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
            for d, e, m in zip(distances(r, geometries[cell.condition]), r.eta2, r.mutual_information)
        ],
    )


def write_tradeoff(path: Path, calib: Calibration) -> Path:
    return write_csv(path, [{k: _fmt(v[i]) for k, v in calib.table.items()} for i in range(len(calib.table["delta1"]))])


def _fmt(value: object) -> str:
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value)).lower()
    return f"{float(value):.6g}"


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
