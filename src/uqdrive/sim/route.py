"""Polylines and the reference route: arcs, lines and joints sampled every 0.2 m, and `Route`, the lane the
autopilot follows and the safety checks measure against. Plain numpy; world frame x east, y north, metres."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

STEP = 0.2  # route / polyline sampling, metres
_CELL = 0.25  # grid cell of `Route.project_point`'s candidate segments, metres
_GRID_MARGIN = 10.0  # how far around the route the grid reaches, metres
_CELL_SLACK = 1e-3  # metres; float rounding of the distances is ~1e-13
_MAX_CANDIDATES = 64  # more, and numpy over every segment is quicker


def arc(center: np.ndarray, radius: float, a0: float, a1: float, step: float = STEP) -> np.ndarray:
    n = max(2, int(math.ceil(abs(a1 - a0) * radius / step)) + 1)
    a = np.linspace(a0, a1, n)
    return np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)], axis=1)


def line(p0, p1, step: float = STEP) -> np.ndarray:
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    n = max(2, int(math.ceil(np.linalg.norm(p1 - p0) / step)) + 1)
    return p0 + np.linspace(0.0, 1.0, n)[:, None] * (p1 - p0)


def join(*parts: np.ndarray) -> np.ndarray:
    """Concatenate polylines, dropping duplicated joint points."""
    out = [parts[0]]
    for part in parts[1:]:
        out.append(part[1:] if np.allclose(part[0], out[-1][-1], atol=1e-6) else part)
    return np.concatenate(out)


def rotate(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return points @ np.array([[c, s], [-s, c]])


@dataclasses.dataclass
class _Grid:
    """`Route.project_point`'s grid: origin, size in cells, segments as plain floats, candidates per visited cell."""

    x0: float
    y0: float
    nx: int
    ny: int
    rows: list[tuple[float, ...]]
    candidates: dict[tuple[int, int], tuple[int, ...] | None]


@dataclasses.dataclass(frozen=True)
class Route:
    """Reference path as a dense polyline with heading and arc length (the autopilot's lane)."""

    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    s: np.ndarray

    @classmethod
    def from_points(cls, points: np.ndarray) -> Route:
        pts = np.asarray(points, float)
        d = np.diff(pts, axis=0)
        seg = np.hypot(d[:, 0], d[:, 1])
        keep = np.concatenate([[True], seg > 1e-9])
        pts = pts[keep]
        d = np.diff(pts, axis=0)
        s = np.concatenate([[0.0], np.cumsum(np.hypot(d[:, 0], d[:, 1]))])
        seg_heading = np.arctan2(d[:, 1], d[:, 0])
        heading = np.concatenate([seg_heading, seg_heading[-1:]])
        return cls(pts[:, 0].copy(), pts[:, 1].copy(), heading, s)

    @property
    def length(self) -> float:
        return float(self.s[-1])

    @property
    def points(self) -> np.ndarray:
        return np.stack([self.x, self.y], axis=1)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Arc length of the closest route point and signed lateral offset (+ = left of route).

        Vectorised over points x segments, x and y apart (numpy is slow over a last axis of 2);
        past either end the end segment is extended so progress and deviation stay meaningful
        when a car overshoots. `project_point` gives one point's result, bit for bit, at a step's cost.
        """
        return self._project_all(np.atleast_2d(np.asarray(points, float)))

    def project_point(self, x: float, y: float) -> tuple[float, float]:
        """`project` of one point, bit for bit, in plain Python over the few segments that can be closest.

        Every env step and autopilot step projects the car, and numpy's per-call cost over all
        segments made that the dearest check of a step. The candidates of a `_CELL` grid cell are
        worked out on its first visit (`_cell_candidates`) and kept; a point off the grid takes the
        full computation.
        """
        grid, x, y = self._grid, float(x), float(y)  # float64, as `project` makes them
        fx, fy = (x - grid.x0) / _CELL, (y - grid.y0) / _CELL
        candidates = None
        if 0.0 <= fx < grid.nx and 0.0 <= fy < grid.ny:  # False for nan and inf too
            key = (int(fx), int(fy))
            if key not in grid.candidates:
                grid.candidates[key] = self._cell_candidates(*key)
            candidates = grid.candidates[key]
        if candidates is None:
            s, lateral = self._project_all(np.array([[x, y]], float))
            return float(s[0]), float(lateral[0])
        best = math.inf
        for k in candidates:  # the same float operations, in the same order, as `_project_all`
            ax, ay, dx, dy, seg_len2, lo, hi = grid.rows[k]
            rel_x, rel_y = x - ax, y - ay
            t = (rel_x * dx + rel_y * dy) / seg_len2
            t = t if t > lo else lo  # np.clip
            t = t if t < hi else hi
            ex, ey = x - (ax + t * dx), y - (ay + t * dy)
            dist2 = ex * ex + ey * ey
            if dist2 < best:  # strictly: the first of equals wins, as np.argmin's
                best, found = dist2, (k, t, rel_x, rel_y)
        k, t, rel_x, rel_y = found
        ax, ay, dx, dy, seg_len2, lo, hi = grid.rows[k]
        seg = math.sqrt(seg_len2)
        return float(self.s[k] + t * seg), float((dx * rel_y - dy * rel_x) / seg)

    def _to_segments(self, q: np.ndarray) -> tuple[np.ndarray, ...]:
        """From each point of q [N, 2] to every segment [N, S]: offsets from its start, the clipped
        parameter of the closest point on it, and the squared distance to that point."""
        ax, ay, dx, dy, seg_len2, lo, hi = self._segments
        rel_x, rel_y = q[:, :1] - ax, q[:, 1:] - ay
        t = np.clip((rel_x * dx + rel_y * dy) / seg_len2, lo, hi)
        dist2 = (q[:, :1] - (ax + t * dx)) ** 2 + (q[:, 1:] - (ay + t * dy)) ** 2
        return rel_x, rel_y, t, dist2

    def _project_all(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        _, _, dx, dy, seg_len2, _, _ = self._segments
        rel_x, rel_y, t, dist2 = self._to_segments(q)
        k = np.argmin(dist2, axis=1)
        rows = np.arange(len(q))
        seg = np.sqrt(seg_len2[k])
        s = self.s[k] + t[rows, k] * seg
        lateral = (dx[k] * rel_y[rows, k] - dy[k] * rel_x[rows, k]) / seg
        return s, lateral

    def _cell_candidates(self, ix: int, iy: int) -> tuple[int, ...] | None:
        """Segments that can be the closest, or tie for it, from some point of grid cell (ix, iy), in index
        order; None where there are too many for plain Python to pay.

        Distance to a segment is 1-Lipschitz in the point: from a point q of the cell, within h (half
        the diagonal) of its centre c, segment j is at least d_j(c) - h away and the closest at most
        min d(c) + h, so a segment with d_j(c) > min d(c) + 2h is farther than the closest from every
        q, never tied with it (`_CELL_SLACK` dwarfs the rounding of these distances).
        """
        grid = self._grid
        centre = np.array([[grid.x0 + (ix + 0.5) * _CELL, grid.y0 + (iy + 0.5) * _CELL]])
        d = np.sqrt(self._to_segments(centre)[3][0])
        near = np.flatnonzero(d <= d.min() + _CELL * math.sqrt(2) + _CELL_SLACK)
        return tuple(near.tolist()) if len(near) <= _MAX_CANDIDATES else None

    @functools.cached_property
    def _segments(self) -> tuple[np.ndarray, ...]:
        """Start x, y, direction x, y, squared length and the clip range of each segment's parameter
        (the end segments extend beyond the route): computed once, `project` runs every step."""
        dx, dy = np.diff(self.x), np.diff(self.y)
        lo, hi = np.zeros_like(dx), np.ones_like(dx)
        lo[0], hi[-1] = -np.inf, np.inf
        return self.x[:-1], self.y[:-1], dx, dy, dx * dx + dy * dy, lo, hi

    @functools.cached_property
    def _grid(self) -> _Grid:
        """The cells `project_point` covers (the route's bounding box and `_GRID_MARGIN` around it), each segment
        as plain floats, and the cells' candidates so far."""
        ax, ay, dx, dy, seg_len2, lo, hi = self._segments
        x0, y0 = float(self.x.min()) - _GRID_MARGIN, float(self.y.min()) - _GRID_MARGIN
        nx = math.ceil((float(self.x.max()) + _GRID_MARGIN - x0) / _CELL)
        ny = math.ceil((float(self.y.max()) + _GRID_MARGIN - y0) / _CELL)
        if not (np.all(seg_len2 > 0) and np.isfinite(seg_len2).all()):
            nx = ny = 0  # a degenerate segment gives nan, which np.argmin picks: leave those routes to numpy
        rows = list(zip(*(a.tolist() for a in (ax, ay, dx, dy, seg_len2, lo, hi))))
        return _Grid(x0, y0, nx, ny, rows, {})

    def sample(self, s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, heading) at arc length s, extrapolated straight beyond the ends."""
        s = np.asarray(s, float)
        sc = np.clip(s, 0.0, self.length)
        x = np.interp(sc, self.s, self.x)
        y = np.interp(sc, self.s, self.y)
        k = np.clip(np.searchsorted(self.s, sc, side="right") - 1, 0, len(self.s) - 2)
        h = np.arctan2(self.y[k + 1] - self.y[k], self.x[k + 1] - self.x[k])
        extra = s - sc
        return x + extra * np.cos(h), y + extra * np.sin(h), h

    def curvature(self) -> np.ndarray:
        """Signed curvature per route point (+ = turning left)."""
        dh = np.diff(np.unwrap(self.heading[:-1]))
        ds = np.diff(self.s[:-1])
        k = np.concatenate([[0.0], dh / np.maximum(ds, 1e-9), [0.0]])
        return np.convolve(k, np.ones(5) / 5, mode="same")
