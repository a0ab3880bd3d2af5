"""The files an avoid stage writes beside its record: per-frame traces of each cell (npz, for the summary figure;
`uqdrive.avoid.cells.cell_arrays` computes them) and the calibration's trade-off (CSV, DVC plot data); and the
summary's reading of the traces back. Writers only write: the rows and arrays are computed in `uqdrive.avoid.cells`
and the stage's other tables go through `uqdrive.files.write_csv` as they are."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from uqdrive.files import atomic_path, write_csv


def write_cell_data(path: Path, arrays: dict[str, np.ndarray | float]) -> Path:
    """A cell's per-frame traces (`uqdrive.avoid.cells.cell_arrays`) as npz, for the summary figure."""
    with atomic_path(path) as tmp, tmp.open("wb") as f:
        np.savez_compressed(f, **arrays)
    return path


def write_tradeoff(path: Path, table: dict[str, np.ndarray]) -> Path:
    """Every candidate's row of the calibration's table (`uqdrive.avoid.calibration.Calibration`)."""
    return write_csv(path, [{k: _fmt(v[i]) for k, v in table.items()} for i in range(len(table["delta1"]))])


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
