"""Scenario layouts, one builder per `ScenarioConfig.kind` (`LAYOUTS`): the road's route, start pose, paved area,
asphalt and marking triangles, obstacles and roundabout island. A new kind is a builder here and its entry in
`LAYOUTS`; `uqdrive.safety.safe_sets` holds its safe-set rule."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from uqdrive.schema import ConfigError

from .config import ScenarioConfig
from .paving import MARK_STEP, PavedArea, band, circle, dashes, fan, rasterise, strip
from .route import STEP, Route, arc, join, line, rotate


@dataclasses.dataclass(frozen=True)
class Prop:
    """A stationary body of the scene: an obstacle's car (``kind`` 'car', size = length, width, height) or the
    scenery around the road ('tree', size = trunk radius, crown radius, height; or 'building'); centre (x, y),
    heading, size and colour."""

    kind: str
    x: float
    y: float
    yaw: float
    size: tuple[float, float, float]
    color: tuple[float, float, float]


@dataclasses.dataclass(frozen=True)
class Layout:
    """What a scenario kind's builder lays out (scenery is placed around it by `build_geometry`)."""

    route: Route
    start: tuple[float, float, float]  # x, y, yaw of the nominal start (body centre)
    paved: PavedArea
    asphalt: list[np.ndarray]  # triangles [n, 3, 2] per patch
    markings: np.ndarray  # triangles [n, 3, 2]
    obstacles: list[Prop]  # cars
    island: tuple[float, float, float] | None  # centre x, y and radius of a roundabout island


def straight(cfg: ScenarioConfig) -> Layout:
    """A straight road of `num_lanes` lanes; kind `obstacle` adds a stationary car and a lane change around it."""
    L, lw, n = cfg.road_length, cfg.lane_width, cfg.num_lanes
    half = n * lw / 2
    right = -half + lw / 2
    road = np.array([[0, -half], [L, -half], [L, half], [0, half]], float)
    mw = cfg.marking_width
    edge = 0.15 + mw / 2
    marks = [
        band(line([0, -half + edge], [L, -half + edge], L), mw),
        band(line([0, half - edge], [L, half - edge], L), mw),
    ]
    for k in range(1, n):
        for dash in dashes(line([0, -half + k * lw], [L, -half + k * lw]), cfg.dash_length, cfg.dash_gap, L):
            marks.append(band(dash, mw))
    x = np.arange(0.0, L + STEP / 2, STEP)
    y = np.full_like(x, right)
    obstacles = []
    if cfg.kind == "obstacle":
        ox = cfg.start_distance + cfg.obstacle_distance
        obstacles.append(Prop("car", ox, right, 0.0, cfg.obstacle_size, cfg.obstacle_color))
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
    paved = rasterise([road], [], bounds)
    return Layout(route, start, paved, [fan(road)], np.concatenate(marks), obstacles, None)


def _roundabout_route(cfg: ScenarioConfig, a: float, reach: float) -> Route:
    """South arm's right lane (centre offset ``a``) -> fillet (right turn) -> ring (ccw) -> mirrored to the east arm."""
    rc, rf = cfg.ring_radius, cfg.route_fillet
    c1 = np.array([a + rf, -math.sqrt((rc + rf) ** 2 - (a + rf) ** 2)])
    theta_in = math.atan2(c1[1], c1[0])
    if theta_in >= -math.pi / 4:
        raise ConfigError(
            f"scenario.route_fillet={rf} is too large for ring_radius={rc}: the entry and exit curves overlap"
        )
    half_route = join(
        line([a, -reach], [a, c1[1]]),
        arc(c1, rf, math.pi, math.atan2(-c1[1], -c1[0])),
        arc(np.zeros(2), rc, theta_in, -math.pi / 4),
    )
    mirrored = np.stack([-half_route[:, 1], -half_route[:, 0]], axis=1)[::-1]
    return Route.from_points(join(half_route, mirrored))


def roundabout(cfg: ScenarioConfig) -> Layout:
    """A four-arm roundabout; the route enters from the south arm and leaves by the first exit (east)."""
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

    asphalt = [strip(circle(r_out, 240)[np.r_[0:240, 0]], circle(r_in, 240)[np.r_[0:240, 0]])]
    on, marks = [circle(r_out)], []
    # fillet between the arm edge (local v = side * h) and the ring's outer circle
    fu = math.sqrt((r_out + fj) ** 2 - (h + fj) ** 2)
    corner_u = math.sqrt(r_out**2 - h**2)
    openings = []
    for k in range(4):
        phi = -math.pi / 2 + k * math.pi / 2  # arms: south, east, north, west
        arm = np.array([[rc, -h], [reach, -h], [reach, h], [rc, h]])
        on.append(rotate(arm, phi))
        asphalt.append(fan(rotate(np.array([[corner_u - 0.5, -h], [reach, -h], [reach, h], [corner_u - 0.5, h]]), phi)))
        for side in (-1.0, 1.0):
            f = np.array([fu, side * (h + fj)])
            t2 = f * r_out / (r_out + fj)
            a1 = -math.pi / 2 if side > 0 else math.pi / 2
            a2 = math.atan2(-f[1], -f[0])
            fillet = arc(f, fj, a1, a2)  # from the arm edge (T1) to the ring (T2)
            poly = np.concatenate([[[corner_u, side * h]], fillet])
            on.append(rotate(poly, phi))
            asphalt.append(fan(rotate(poly, phi)))
            edge_arc = arc(f, fj + edge, a1, a2, MARK_STEP)
            marks.append(band(rotate(edge_arc, phi), mw))
            marks.append(band(rotate(line([fu, side * (h - edge)], [reach, side * (h - edge)], reach), phi), mw))
            openings.append(phi + math.atan2(t2[1], t2[0]))
        for k_lane in range(1, n):
            v = -h + k_lane * lw
            for dash in dashes(line([r_out, v], [reach, v]), cfg.dash_length, cfg.dash_gap, reach):
                marks.append(band(rotate(dash, phi), mw))
    n_mark = int(2 * math.pi * r_in / MARK_STEP)
    marks.append(band(circle(r_in + edge, n_mark)[np.r_[0:n_mark, 0]], mw))
    for k in range(4):  # outer ring edge between neighbouring arms
        a0 = openings[2 * k + 1]
        a1 = openings[(2 * k + 2) % 8] + (2 * math.pi if k == 3 else 0.0)
        marks.append(band(arc(np.zeros(2), r_out - edge, a0, a1, MARK_STEP), mw))
    paved = rasterise(on, [circle(r_in)], (-reach - 1, -reach - 1, reach + 1, reach + 1))

    route = _roundabout_route(cfg, a, reach)
    start = (a, -(r_out + cfg.start_distance), math.pi / 2)
    island = (0.0, 0.0, r_in - 0.3)
    return Layout(route, start, paved, asphalt, np.concatenate(marks), [], island)


LAYOUTS: dict[str, Callable[[ScenarioConfig], Layout]] = {
    "straight": straight,
    "obstacle": straight,
    "roundabout": roundabout,
}
