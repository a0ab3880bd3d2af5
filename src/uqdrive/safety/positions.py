"""Where an offline-safety cell's rollouts went: every visited position with the road, the route and the safe set's
edges around them (data/safety/<cell>.npz), the input of the per-cell and the summary hexbin figures."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from uqdrive.files import atomic_path
from uqdrive.safety.executors import RolloutJob
from uqdrive.safety.rollout import RolloutResult
from uqdrive.safety.safe_sets import SafeSet, safe_set_for
from uqdrive.sim import ScenarioGeometry
from uqdrive.sim.config import GymWorldConfig

EXTENT_MARGIN = 12.0  # metres around the reference route shown in the figures
ROAD_CELL = 0.25  # metres: the road raster's resolution


@dataclasses.dataclass(frozen=True)
class CellPositions:
    """``rollout``, ``x``, ``y``: every visited position and its rollout index; the reference ``route`` and the safe
    set's ``left``/``right`` edges; ``extent`` (xmin, xmax, ymin, ymax) and the paved ``road`` raster within it."""

    rollout: np.ndarray
    x: np.ndarray
    y: np.ndarray
    route: np.ndarray
    left: np.ndarray
    right: np.ndarray
    extent: np.ndarray
    road: np.ndarray
    eta1: float

    @property
    def edges(self) -> tuple[np.ndarray, np.ndarray] | None:
        return (self.left, self.right) if len(self.left) else None


def road_raster(geometry: ScenarioGeometry, extent: np.ndarray, cell: float = ROAD_CELL) -> np.ndarray:
    """Paved area inside ``extent`` (xmin, xmax, ymin, ymax) as a bool image [rows = y ascending, cols = x]."""
    xs = np.arange(extent[0], extent[1], cell) + cell / 2
    ys = np.arange(extent[2], extent[3], cell) + cell / 2
    gx, gy = np.meshgrid(xs, ys)
    return geometry.is_paved(np.stack([gx.ravel(), gy.ravel()], axis=1)).reshape(gx.shape)


def _visited(results: Sequence[RolloutResult]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every visited position (x, y) and its rollout index."""
    if not results:
        return np.zeros(0, int), np.zeros(0), np.zeros(0)
    rollout = np.concatenate([np.full(len(r.x), i) for i, r in enumerate(results)])
    return rollout, np.concatenate([r.x for r in results]), np.concatenate([r.y for r in results])


def cell_positions(
    results: Sequence[RolloutResult], geometry: ScenarioGeometry, safe_set: SafeSet, eta1: float
) -> CellPositions:
    route = np.stack([safe_set.route_x, safe_set.route_y], axis=1)
    edges = safe_set.boundaries()
    left, right = edges if edges is not None else (np.zeros((0, 2)), np.zeros((0, 2)))
    lo, hi = route.min(0) - EXTENT_MARGIN, route.max(0) + EXTENT_MARGIN
    extent = np.array([lo[0], hi[0], lo[1], hi[1]])
    rollout, x, y = _visited(results)
    return CellPositions(rollout, x, y, route, left, right, extent, road_raster(geometry, extent), eta1)


def world_positions(results: Sequence[RolloutResult], eta1: float) -> CellPositions:
    """The positions of a cell in a world whose road uqdrive does not know (a Gymnasium world: the env draws its own):
    no route, no safe-set edges, an empty road raster, the extent around the visited positions."""
    rollout, x, y = _visited(results)
    points = np.stack([x, y], axis=1) if len(x) else np.zeros((1, 2))
    lo, hi = points.min(0) - EXTENT_MARGIN, points.max(0) + EXTENT_MARGIN
    none = np.zeros((0, 2))
    return CellPositions(
        rollout, x, y, none, none, none, np.array([lo[0], hi[0], lo[1], hi[1]]), np.zeros((0, 0), bool), eta1
    )


@dataclasses.dataclass(frozen=True)
class _PositionsOf:
    """A cell's positions where its rollouts drove (a `uqdrive.sim.world.WorldVisitor`)."""

    job: RolloutJob
    results: Sequence[RolloutResult]
    eta1: float

    def road(self, geometry: ScenarioGeometry) -> CellPositions:
        car = self.job.vehicle
        safe_set = safe_set_for(geometry, car.width, car.length, self.job.half_width)
        return cell_positions(self.results, geometry, safe_set, self.eta1)

    def gym(self, world: GymWorldConfig) -> CellPositions:
        return world_positions(self.results, self.eta1)


def job_positions(job: RolloutJob, results: Sequence[RolloutResult], eta1: float) -> CellPositions:
    """Where a one-condition job's rollouts went, on the road of its location (a Gymnasium world's road is the
    env's: none)."""
    return job.condition(0).visit(_PositionsOf(job, results, eta1))


def write_positions(path: str | Path, positions: CellPositions) -> Path:
    path = Path(path)
    with atomic_path(path) as tmp, tmp.open("wb") as f:
        np.savez_compressed(f, **dataclasses.asdict(positions))
    return path


def read_positions(path: str | Path) -> CellPositions:
    with np.load(path) as data:
        return CellPositions(**{f.name: data[f.name] for f in dataclasses.fields(CellPositions)})
