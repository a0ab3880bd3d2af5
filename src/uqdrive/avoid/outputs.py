"""The files an avoid stage writes per cell and for its calibration: per-rollout tables and the trade-off (CSV, DVC
plot data), per-frame traces (npz, for the summary figure) and η2 / MI against the distance to the obstacle (in a
Gymnasium world: the metres before the run ended, `uqdrive.avoid.cells.distances`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from uqdrive.avoid.calibration import Calibration
from uqdrive.avoid.cells import Cell, Course, distances, levels
from uqdrive.files import atomic_path, write_csv
from uqdrive.policy.warnings import LEVELS


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


def write_cell_data(path: Path, cell: Cell, course: Course) -> Path:
    """Per-frame traces of a cell (npz) for the summary figure: positions, distance (`distances`), η2, MI, level;
    the obstacle and road boxes (empty in a Gymnasium world)."""
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
    with atomic_path(path) as tmp, tmp.open("wb") as f:
        np.savez_compressed(
            f,
            **{k: np.concatenate(v) if v else np.zeros(0) for k, v in frames.items()},
            termination=np.array([r.termination for r in cell.results]),
            safe=np.array([r.safe for r in cell.results]),
            eta1=cell.estimate.value,
            obstacle=course.obstacle_box(),
            road=course.road_box(),
        )
    return path


def write_signals(path: Path, cells: list[Cell], courses: dict[str, Course]) -> Path:
    """η2 and MI per frame against the distance (`distances`; a DVC plot)."""
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
            for d, e, m in zip(distances(r, courses[cell.condition]), r.eta2, r.mutual_information)
        ],
    )


def write_tradeoff(path: Path, calib: Calibration) -> Path:
    return write_csv(path, [{k: _fmt(v[i]) for k, v in calib.table.items()} for i in range(len(calib.table["delta1"]))])


def _fmt(value: object) -> str:
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value)).lower()
    return f"{float(value):.6g}"


def read_trace_panel(paths: list[Path], eta1: float) -> dict:
    """The paths of one or more cells' trace files (`write_cell_data`) in one figure panel."""
    runs = []
    for path in paths:
        with np.load(path) as data:
            rollout = data["rollout"]
            runs += [
                {
                    "x": data["x"][rollout == i],
                    "y": data["y"][rollout == i],
                    "mi": data["mi"][rollout == i],
                    "termination": str(t),
                }
                for i, t in enumerate(data["termination"])
            ]
            obstacle, road = data["obstacle"], data["road"]
    return {"paths": runs, "obstacle": obstacle, "road": road, "title": f"η̂1 = {eta1:.2f}"}
