"""Paved surfaces: polygons to render triangles, lane markings as thin bands and dashes, and the 5 cm raster of
the paved area that the off-road test and the scenery placement read. Plain numpy and OpenCV."""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

PAVED_RES = 0.05  # raster cell size of the paved-area test, metres
MARK_STEP = 0.75  # marking polylines on curves: fewer triangles render faster


@dataclasses.dataclass(frozen=True)
class PavedArea:
    """Raster of the paved surface (5 cm cells), fillets included; a vectorised point test."""

    origin: tuple[float, float]
    resolution: float
    mask: np.ndarray  # [rows=y, cols=x] bool

    def contains(self, points: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(np.asarray(points, float))
        ix = np.floor((q[:, 0] - self.origin[0]) / self.resolution).astype(np.int64)
        iy = np.floor((q[:, 1] - self.origin[1]) / self.resolution).astype(np.int64)
        h, w = self.mask.shape
        inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
        out = np.zeros(len(q), bool)
        out[inside] = self.mask[iy[inside], ix[inside]]
        return out

    def covers(self, points) -> bool:
        """Whether every (x, y) of a few points is paved: ``contains(points).all()`` in plain Python, for the
        off-road test of every env step (four corners), where numpy's per-call cost is most of the time.

        ``0 <= f < w`` is ``0 <= floor(f) < w`` for a whole w, and False for nan and inf, which numpy's
        int64 cast sends out of range.
        """
        (ox, oy), res = self.origin, self.resolution
        h, w = self.mask.shape
        for x, y in points:
            fx, fy = (float(x) - ox) / res, (float(y) - oy) / res  # float64, as `contains` makes them
            if not (0.0 <= fx < w and 0.0 <= fy < h and self.mask[int(fy), int(fx)]):
                return False
        return True

    def distance_field(self, pad: float, cell: float = 0.5):
        """Distance (m) to the nearest paved cell on a coarse grid padded by ``pad`` metres.

        Returns a lookup function of points; used to keep scenery off the road.
        """
        f = max(1, int(round(cell / self.resolution)))
        h, w = self.mask.shape
        coarse = np.pad(self.mask, ((0, (-h) % f), (0, (-w) % f)))
        coarse = coarse.reshape(coarse.shape[0] // f, f, coarse.shape[1] // f, f).any(axis=(1, 3))
        step = f * self.resolution
        n_pad = int(math.ceil(pad / step))
        coarse = np.pad(coarse, n_pad)
        dist = cv2.distanceTransform((~coarse).astype(np.uint8), cv2.DIST_L2, 5) * step
        ox, oy = self.origin[0] - n_pad * step, self.origin[1] - n_pad * step

        def lookup(points: np.ndarray) -> np.ndarray:
            q = np.atleast_2d(np.asarray(points, float))
            ix = np.clip(((q[:, 0] - ox) / step).astype(int), 0, dist.shape[1] - 1)
            iy = np.clip(((q[:, 1] - oy) / step).astype(int), 0, dist.shape[0] - 1)
            return dist[iy, ix]

        return lookup


def fan(polygon: np.ndarray) -> np.ndarray:
    """Triangle fan from the first vertex (polygon star-shaped from it)."""
    p = np.asarray(polygon, float)
    return np.stack([np.repeat(p[:1], len(p) - 2, axis=0), p[1:-1], p[2:]], axis=1)


def strip(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Triangles of the band between two polylines with matching vertices."""
    a, b, c, d = left[:-1], right[:-1], right[1:], left[1:]
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def band(polyline: np.ndarray, width: float) -> np.ndarray:
    """Triangles of a line of the given width centred on a polyline."""
    p = np.asarray(polyline, float)
    d = np.gradient(p, axis=0)
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.linalg.norm(d, axis=1, keepdims=True)
    return strip(p + n * width / 2, p - n * width / 2)


def dashes(polyline: np.ndarray, dash: float, gap: float, step: float = MARK_STEP) -> list[np.ndarray]:
    if gap <= 0:
        return [polyline]
    seg = np.hypot(*np.diff(polyline, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    out = []
    start = 0.0
    while start < s[-1]:
        end = min(start + dash, s[-1])
        ss = np.linspace(start, end, max(2, int(math.ceil((end - start) / step)) + 1))
        out.append(np.stack([np.interp(ss, s, polyline[:, 0]), np.interp(ss, s, polyline[:, 1])], axis=1))
        start += dash + gap
    return out


def rasterise(polygons_on, polygons_off, bounds) -> PavedArea:
    xmin, ymin, xmax, ymax = bounds
    w = int(math.ceil((xmax - xmin) / PAVED_RES))
    h = int(math.ceil((ymax - ymin) / PAVED_RES))
    mask = np.zeros((h, w), np.uint8)
    shift = 4

    def pix(poly):
        return np.round((np.asarray(poly) - [xmin, ymin]) / PAVED_RES * (1 << shift) - 0.5 * (1 << shift)).astype(
            np.int32
        )

    for poly in polygons_on:
        cv2.fillPoly(mask, [pix(poly)], 1, lineType=cv2.LINE_8, shift=shift)
    for poly in polygons_off:
        cv2.fillPoly(mask, [pix(poly)], 0, lineType=cv2.LINE_8, shift=shift)
    return PavedArea((xmin, ymin), PAVED_RES, mask.astype(bool))


def circle(radius: float, n: int = 360) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([radius * np.cos(a), radius * np.sin(a)], axis=1)
