"""Centre-line geometry of the scenarios: reference route, paved area, markings, scenery.

All of it is plain numpy, independent of pybullet, so safety boundaries and analyses can use
the same geometry the world was built from. World frame: x east, y north, z up, metres.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import cv2
import numpy as np

from uqdrive.checks import ConfigError

from .config import ScenarioConfig

_STEP = 0.2  # route / polyline sampling, metres
_PAVED_RES = 0.05  # raster cell size of the paved-area test, metres
_MARK_STEP = 0.75  # marking polylines on curves: fewer triangles render faster


def _arc(center: np.ndarray, radius: float, a0: float, a1: float, step: float = _STEP) -> np.ndarray:
    n = max(2, int(math.ceil(abs(a1 - a0) * radius / step)) + 1)
    a = np.linspace(a0, a1, n)
    return np.stack([center[0] + radius * np.cos(a), center[1] + radius * np.sin(a)], axis=1)


def _line(p0, p1, step: float = _STEP) -> np.ndarray:
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    n = max(2, int(math.ceil(np.linalg.norm(p1 - p0) / step)) + 1)
    return p0 + np.linspace(0.0, 1.0, n)[:, None] * (p1 - p0)


def _join(*parts: np.ndarray) -> np.ndarray:
    """Concatenate polylines, dropping duplicated joint points."""
    out = [parts[0]]
    for part in parts[1:]:
        out.append(part[1:] if np.allclose(part[0], out[-1][-1], atol=1e-6) else part)
    return np.concatenate(out)


def _rot(points: np.ndarray, angle: float) -> np.ndarray:
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


@dataclasses.dataclass(frozen=True)
class Obstacle:
    """A stationary car: centre (x, y), heading and size (length, width, height)."""

    x: float
    y: float
    yaw: float
    size: tuple[float, float, float]
    color: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class Scenery:
    """Off-road props. kind is 'tree' (size = trunk radius, crown radius, height) or 'building'."""

    kind: str
    x: float
    y: float
    yaw: float
    size: tuple[float, float, float]
    color: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class ScenarioGeometry:
    """Everything the world and the safety checks need to know about one scenario."""

    config: ScenarioConfig
    route: Route
    start: tuple[float, float, float]  # x, y, yaw of the nominal start (body centre)
    paved: PavedArea
    asphalt: list[np.ndarray]  # triangles [n, 3, 2] per patch
    markings: np.ndarray  # triangles [n, 3, 2]
    obstacles: list[Obstacle]
    scenery: list[Scenery]
    island: tuple[float, float, float] | None  # centre x, y and radius of a roundabout island
    bounds: tuple[float, float, float, float]  # xmin, ymin, xmax, ymax of the paved area

    def is_paved(self, points: np.ndarray) -> np.ndarray:
        return self.paved.contains(points)

    def lateral_deviation(self, points: np.ndarray) -> np.ndarray:
        return self.route.project(points)[1]


# -- polygons -> triangles / markings ------------------------------------------------------


def _fan(polygon: np.ndarray) -> np.ndarray:
    """Triangle fan from the first vertex (polygon star-shaped from it)."""
    p = np.asarray(polygon, float)
    return np.stack([np.repeat(p[:1], len(p) - 2, axis=0), p[1:-1], p[2:]], axis=1)


def _strip(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Triangles of the band between two polylines with matching vertices."""
    a, b, c, d = left[:-1], right[:-1], right[1:], left[1:]
    return np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def _band(polyline: np.ndarray, width: float) -> np.ndarray:
    """Triangles of a line of the given width centred on a polyline."""
    p = np.asarray(polyline, float)
    d = np.gradient(p, axis=0)
    n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.linalg.norm(d, axis=1, keepdims=True)
    return _strip(p + n * width / 2, p - n * width / 2)


def _dashes(polyline: np.ndarray, dash: float, gap: float, step: float = _MARK_STEP) -> list[np.ndarray]:
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


def _rasterise(polygons_on, polygons_off, bounds) -> PavedArea:
    xmin, ymin, xmax, ymax = bounds
    w = int(math.ceil((xmax - xmin) / _PAVED_RES))
    h = int(math.ceil((ymax - ymin) / _PAVED_RES))
    mask = np.zeros((h, w), np.uint8)
    shift = 4

    def pix(poly):
        return np.round((np.asarray(poly) - [xmin, ymin]) / _PAVED_RES * (1 << shift) - 0.5 * (1 << shift)).astype(
            np.int32
        )

    for poly in polygons_on:
        cv2.fillPoly(mask, [pix(poly)], 1, lineType=cv2.LINE_8, shift=shift)
    for poly in polygons_off:
        cv2.fillPoly(mask, [pix(poly)], 0, lineType=cv2.LINE_8, shift=shift)
    return PavedArea((xmin, ymin), _PAVED_RES, mask.astype(bool))


# -- scenarios --------------------------------------------------------------------------------


def _straight(cfg: ScenarioConfig):
    L, lw, n = cfg.road_length, cfg.lane_width, cfg.num_lanes
    half = n * lw / 2
    right = -half + lw / 2
    road = np.array([[0, -half], [L, -half], [L, half], [0, half]], float)
    mw = cfg.marking_width
    edge = 0.15 + mw / 2
    marks = [
        _band(_line([0, -half + edge], [L, -half + edge], L), mw),
        _band(_line([0, half - edge], [L, half - edge], L), mw),
    ]
    for k in range(1, n):
        for dash in _dashes(_line([0, -half + k * lw], [L, -half + k * lw]), cfg.dash_length, cfg.dash_gap, L):
            marks.append(_band(dash, mw))
    x = np.arange(0.0, L + _STEP / 2, _STEP)
    y = np.full_like(x, right)
    obstacles = []
    if cfg.kind == "obstacle":
        ox = cfg.start_distance + cfg.obstacle_distance
        obstacles.append(Obstacle(ox, right, 0.0, cfg.obstacle_size, cfg.obstacle_color))
        half_len = cfg.obstacle_size[0] / 2
        x0 = ox - half_len - cfg.lane_change_gap - cfg.lane_change_length
        x1 = ox + half_len + cfg.lane_change_gap
        t_out = np.clip((x - x0) / cfg.lane_change_length, 0, 1)
        t_back = np.clip((x - x1) / cfg.lane_change_length, 0, 1)
        y = y + lw * (0.5 - 0.5 * np.cos(np.pi * t_out)) - lw * (0.5 - 0.5 * np.cos(np.pi * t_back))
        if x0 < cfg.start_distance or x1 + cfg.lane_change_length > L - cfg.finish_margin:
            raise ConfigError(
                f"scenario.obstacle_distance={cfg.obstacle_distance} leaves no room to change lanes "
                f"on a road of length {L} starting at {cfg.start_distance}"
            )
    route = Route.from_points(np.stack([x, y], axis=1))
    start = (cfg.start_distance, right, 0.0)
    bounds = (-1.0, -half - 1.0, L + 1.0, half + 1.0)
    paved = _rasterise([road], [], bounds)
    return route, start, paved, [_fan(road)], np.concatenate(marks), obstacles, None


def _circle(radius: float, n: int = 360) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([radius * np.cos(a), radius * np.sin(a)], axis=1)


def _roundabout(cfg: ScenarioConfig):
    lw, n = cfg.lane_width, cfg.num_lanes
    h = n * lw / 2  # arm half width
    a = h - lw / 2  # right-lane centre offset
    rc, r_in, r_out = cfg.ring_radius, cfg.ring_radius - cfg.ring_width / 2, cfg.ring_radius + cfg.ring_width / 2
    reach = r_out + cfg.arm_length
    fj = cfg.junction_fillet
    if h >= r_out * math.sin(math.pi / 4) - fj:
        raise ConfigError(f"scenario.ring_radius={rc} is too small for {n} lanes of {lw} m with fillets of {fj} m")
    mw = cfg.marking_width
    edge = 0.15 + mw / 2

    asphalt = [_strip(_circle(r_out, 240)[np.r_[0:240, 0]], _circle(r_in, 240)[np.r_[0:240, 0]])]
    on, marks = [_circle(r_out)], []
    # fillet between the arm edge (local v = side * h) and the ring's outer circle
    fu = math.sqrt((r_out + fj) ** 2 - (h + fj) ** 2)
    corner_u = math.sqrt(r_out**2 - h**2)
    openings = []
    for k in range(4):
        phi = -math.pi / 2 + k * math.pi / 2  # arms: south, east, north, west
        arm = np.array([[rc, -h], [reach, -h], [reach, h], [rc, h]])
        on.append(_rot(arm, phi))
        asphalt.append(_fan(_rot(np.array([[corner_u - 0.5, -h], [reach, -h], [reach, h], [corner_u - 0.5, h]]), phi)))
        for side in (-1.0, 1.0):
            f = np.array([fu, side * (h + fj)])
            t2 = f * r_out / (r_out + fj)
            a1 = -math.pi / 2 if side > 0 else math.pi / 2
            a2 = math.atan2(-f[1], -f[0])
            arc = _arc(f, fj, a1, a2)  # from the arm edge (T1) to the ring (T2)
            poly = np.concatenate([[[corner_u, side * h]], arc])
            on.append(_rot(poly, phi))
            asphalt.append(_fan(_rot(poly, phi)))
            edge_arc = _arc(f, fj + edge, a1, a2, _MARK_STEP)
            marks.append(_band(_rot(edge_arc, phi), mw))
            marks.append(_band(_rot(_line([fu, side * (h - edge)], [reach, side * (h - edge)], reach), phi), mw))
            openings.append(phi + math.atan2(t2[1], t2[0]))
        for k_lane in range(1, n):
            v = -h + k_lane * lw
            for dash in _dashes(_line([r_out, v], [reach, v]), cfg.dash_length, cfg.dash_gap, reach):
                marks.append(_band(_rot(dash, phi), mw))
    n_mark = int(2 * math.pi * r_in / _MARK_STEP)
    marks.append(_band(_circle(r_in + edge, n_mark)[np.r_[0:n_mark, 0]], mw))
    for k in range(4):  # outer ring edge between neighbouring arms
        a0 = openings[2 * k + 1]
        a1 = openings[(2 * k + 2) % 8] + (2 * math.pi if k == 3 else 0.0)
        marks.append(_band(_arc(np.zeros(2), r_out - edge, a0, a1, _MARK_STEP), mw))
    paved = _rasterise(on, [_circle(r_in)], (-reach - 1, -reach - 1, reach + 1, reach + 1))

    # route: south arm right lane -> fillet (right turn) -> ring (ccw) -> mirrored to the east arm
    rf = cfg.route_fillet
    c1 = np.array([a + rf, -math.sqrt((rc + rf) ** 2 - (a + rf) ** 2)])
    theta_in = math.atan2(c1[1], c1[0])
    if theta_in >= -math.pi / 4:
        raise ConfigError(
            f"scenario.route_fillet={rf} is too large for ring_radius={rc}: the entry and exit curves overlap"
        )
    half_route = _join(
        _line([a, -reach], [a, c1[1]]),
        _arc(c1, rf, math.pi, math.atan2(-c1[1], -c1[0])),
        _arc(np.zeros(2), rc, theta_in, -math.pi / 4),
    )
    mirrored = np.stack([-half_route[:, 1], -half_route[:, 0]], axis=1)[::-1]
    route = Route.from_points(_join(half_route, mirrored))
    start = (a, -(r_out + cfg.start_distance), math.pi / 2)
    island = (0.0, 0.0, r_in - 0.3)
    return route, start, paved, asphalt, np.concatenate(marks), [], island


def _place_scenery(cfg: ScenarioConfig, paved: PavedArea, bounds, island) -> list[Scenery]:
    rng = np.random.default_rng(cfg.scenery_seed)
    xmin, ymin, xmax, ymax = bounds
    ext = cfg.scenery_extent
    distance = paved.distance_field(ext + 1.0)
    items: list[Scenery] = []
    tries = 0
    while len(items) < cfg.scenery_count and tries < 200 * max(cfg.scenery_count, 1):
        tries += 1
        x = rng.uniform(xmin - ext, xmax + ext)
        y = rng.uniform(ymin - ext, ymax + ext)
        tree = rng.random() < cfg.tree_fraction
        if tree:
            crown = rng.uniform(1.2, 2.2)
            size = (rng.uniform(0.15, 0.3), crown, rng.uniform(4.0, 7.0))
            radius = crown
            color = cfg.crown_colors[rng.integers(len(cfg.crown_colors))]
        else:
            size = (rng.uniform(6.0, 14.0), rng.uniform(6.0, 12.0), rng.uniform(5.0, 14.0))
            radius = 0.5 * math.hypot(size[0], size[1])
            color = cfg.building_colors[rng.integers(len(cfg.building_colors))]
        yaw = rng.uniform(-math.pi, math.pi)
        if distance(np.array([[x, y]]))[0] < radius + cfg.scenery_margin:
            continue
        if island is not None and math.hypot(x - island[0], y - island[1]) < island[2] + radius + cfg.ring_width:
            continue
        if any(
            math.hypot(x - o.x, y - o.y)
            < radius + 1.0 + (o.size[1] if o.kind == "tree" else 0.5 * math.hypot(*o.size[:2]))
            for o in items
        ):
            continue
        items.append(Scenery("tree" if tree else "building", x, y, yaw, size, color))
    return items


def build_geometry(cfg: ScenarioConfig) -> ScenarioGeometry:
    """Centre-line geometry of a scenario (deterministic in the config, scenery in scenery_seed)."""
    if cfg.kind == "roundabout":
        route, start, paved, asphalt, marks, obstacles, island = _roundabout(cfg)
    else:
        route, start, paved, asphalt, marks, obstacles, island = _straight(cfg)
    xs = np.concatenate([t.reshape(-1, 2) for t in asphalt])
    bounds = (float(xs[:, 0].min()), float(xs[:, 1].min()), float(xs[:, 0].max()), float(xs[:, 1].max()))
    scenery = _place_scenery(cfg, paved, bounds, island)
    return ScenarioGeometry(cfg, route, start, paved, asphalt, marks, obstacles, scenery, island, bounds)
