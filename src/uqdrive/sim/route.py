"""Polylines and the reference route: arcs, lines and joints sampled every 0.2 m, and `Route`, the lane the
autopilot follows and the safety checks measure against. Plain numpy; world frame x east, y north, metres."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

STEP = 0.2  # route / polyline sampling, metres


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

        Vectorised over points x segments, x and y apart (numpy is slow over a last axis of 2,
        and every env step projects the car); past either end the end segment is extended so
        progress and deviation stay meaningful when a car overshoots.
        """
        q = np.atleast_2d(np.asarray(points, float))
        ax, ay, dx, dy, seg_len2, lo, hi = self._segments
        rel_x, rel_y = q[:, :1] - ax, q[:, 1:] - ay
        t = np.clip((rel_x * dx + rel_y * dy) / seg_len2, lo, hi)
        dist2 = (q[:, :1] - (ax + t * dx)) ** 2 + (q[:, 1:] - (ay + t * dy)) ** 2
        k = np.argmin(dist2, axis=1)
        rows = np.arange(len(q))
        seg = np.sqrt(seg_len2[k])
        s = self.s[k] + t[rows, k] * seg
        lateral = (dx[k] * rel_y[rows, k] - dy[k] * rel_x[rows, k]) / seg
        return s, lateral

    @functools.cached_property
    def _segments(self) -> tuple[np.ndarray, ...]:
        """Start x, y, direction x, y, squared length and the clip range of each segment's parameter
        (the end segments extend beyond the route): computed once, `project` runs every step."""
        dx, dy = np.diff(self.x), np.diff(self.y)
        lo, hi = np.zeros_like(dx), np.ones_like(dx)
        lo[0], hi[-1] = -np.inf, np.inf
        return self.x[:-1], self.y[:-1], dx, dy, dx * dx + dy * dy, lo, hi

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
