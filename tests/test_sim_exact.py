"""The shortcuts of an env step give the full computations' results bit for bit: `Route.project_point`,
`PavedArea.covers`, the ego placed in pybullet only when a query needs it, and the camera's rain and 8-bit
conversion."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from uqdrive.sim import DrivingEnv, Route, ScenarioConfig, WeatherConfig, build_geometry
from uqdrive.sim.camera import _rain_cover, add_noise
from uqdrive.sim.condition import Condition

CONF = Path(__file__).resolve().parents[1] / "conf"


def same(a, b) -> bool:
    """Equal as bits (nan included), which == is not for nan."""
    return np.array_equal(np.asarray(a, float).view(np.int64), np.asarray(b, float).view(np.int64))


def check_points(route: Route, points: np.ndarray) -> None:
    with np.errstate(all="ignore"):  # nan and inf points
        s, lateral = route._project_all(points)
        many = route.project(points)  # many points: the full computation itself
        for k, (x, y) in enumerate(points.tolist()):
            assert same(route.project_point(x, y), (s[k], lateral[k])), (x, y)
            assert all(same(a, b[k : k + 1]) for a, b in zip(route.project(points[k]), (s, lateral)))
    assert same(many[0], s) and same(many[1], lateral)


@pytest.mark.parametrize("kind", ["roundabout", "obstacle", "straight"])
def test_point_projection_is_the_full_computation(kind):
    route = build_geometry(ScenarioConfig.from_yaml(CONF / "scenario" / f"{kind}.yaml")).route
    rng = np.random.default_rng(0)
    lo, hi = route.points.min(axis=0), route.points.max(axis=0)
    vertices = route.points[::7]
    heading = np.stack([np.cos(route.heading[::7]), np.sin(route.heading[::7])], axis=1)
    check_points(
        route,
        np.concatenate(
            [
                rng.uniform(lo - 12, hi + 12, size=(3000, 2)),  # around the route, and off the grid
                vertices,  # on joints, where neighbouring segments tie
                vertices + rng.normal(0, 1e-9, size=vertices.shape),
                vertices + 0.7 * heading[:, ::-1] * [-1, 1],  # beside joints
                route.points[[0, -1]] + [[-30.0, 0.4], [30.0, -0.4]],  # past either end
                [[1e6, -1e6], [np.nan, 0.0], [0.0, np.inf]],  # far away, not a number
            ]
        ),
    )
    assert route._grid.nx > 0 and any(c is not None for c in route._grid.candidates.values())


def test_point_projection_keeps_the_first_of_tied_segments():
    """On a staircase of unit segments, (3, -1) is exactly sqrt(5) from the joints (1, 0) and (2, 1), so four
    segments tie, each with its own lateral offset: np.argmin takes the first."""
    route = Route.from_points(np.array([[k // 2 + k % 2, k // 2] for k in range(12)], float))
    assert route.project_point(3.0, -1.0) == (1.0, -1.0)
    grid = np.stack(np.meshgrid(np.arange(-3, 10, 0.5), np.arange(-3, 10, 0.5)), axis=-1).reshape(-1, 2)
    check_points(route, grid)


def test_point_projection_of_a_route_with_a_repeated_point():
    """A zero-length segment gives nan, which np.argmin picks: such a route takes the full computation."""
    x, y = np.array([0.0, 1.0, 1.0, 2.0]), np.array([0.0, 0.0, 0.0, 0.5])
    route = Route(x, y, np.zeros(4), np.array([0.0, 1.0, 1.0, 2.1]))
    check_points(route, np.random.default_rng(1).uniform(-2, 4, size=(200, 2)))
    assert route._grid.nx == 0


def test_covers_is_contains_all():
    paved = build_geometry(ScenarioConfig.from_yaml(CONF / "scenario" / "roundabout.yaml")).paved
    rng = np.random.default_rng(2)
    h, w = paved.mask.shape
    (ox, oy), res = paved.origin, paved.resolution
    rows, cols = np.nonzero(paved.mask[:, 1:] != paved.mask[:, :-1])  # the road's edges, cell by cell
    pick = rng.choice(len(rows), 300)
    x, y = ox + (cols[pick] + 1) * res, oy + (rows[pick] + 0.5) * res
    edges = np.concatenate(
        [np.stack([np.nextafter(x, d), y], axis=1) for d in (-np.inf, np.inf)] + [np.stack([x, y], 1)]
    )
    outside = np.array([ox, oy]) + res * np.array([[0, 0], [w, h], [w - 1e-9, h - 1e-9], [-1e-12, 3]])
    points = np.concatenate(
        [rng.uniform(-70, 70, size=(4000, 2)), edges, outside, [[np.nan, 0], [0, np.inf], [1e300, 0]]]
    )
    with np.errstate(invalid="ignore"):
        for k in range(0, len(points), 4):
            group = points[k : k + 4]
            assert paved.covers(group.tolist()) == bool(paved.contains(group).all())
        assert [paved.covers([p]) for p in points.tolist()] == paved.contains(points).tolist()


@pytest.mark.parametrize("kind", ["obstacle", "roundabout_town"])
def test_ego_is_placed_before_every_query_that_needs_it(kind):
    with DrivingEnv() as env:
        env.reset(0, Condition(ScenarioConfig.from_yaml(CONF / "scenario" / f"{kind}.yaml"), None), render=False)
        world, client = env.scene, env.client
        rng = np.random.default_rng(3)
        hits = 0
        for k in range(300):
            _, px, py, radius = world._collidable[rng.integers(len(world._collidable))]
            x, y = px + rng.uniform(-1, 1) * (radius + 4), py + rng.uniform(-1, 1) * (radius + 4)
            yaw = rng.uniform(-3, 3)
            world.set_ego_pose(x, y, yaw)
            if k % 2:
                collision, clearance = world.in_collision(x, y), world.clearance()
            else:
                clearance, collision = world.clearance(), world.in_collision(x, y)
            client.resetBasePositionAndOrientation(world.ego_id, [x, y, 0.0], [0, 0, np.sin(yaw / 2), np.cos(yaw / 2)])
            near = [client.getClosestPoints(world.ego_id, body, distance=5.0) for body, *_ in world._collidable]
            assert collision == any(pt[8] <= 0.0 for pts in near for pt in pts)
            assert clearance == min([5.0] + [pt[8] for pts in near for pt in pts])
            hits += collision
        assert 30 < hits < 270


def rain_cover_by_masks(shape, weather, rng):
    """`_rain_cover` as it was: streaks picked by a mask per opacity step."""
    u = rng.random((weather.rain_streaks, 5))
    x0, y0 = u[:, 0] * 160, u[:, 1] * 120
    reach = weather.rain_length * (0.5 + u[:, 2])
    angle = np.radians(weather.rain_angle_deg + 8.0 * u[:, 3] - 4.0)
    ends = np.stack([x0, y0, x0 + np.sin(angle) * reach, y0 + np.cos(angle) * reach], axis=1)
    ends = ends.astype(np.int32).reshape(-1, 2, 2)
    level = (u[:, 4] * 5).astype(int)
    cover = np.zeros((120, 160), np.float32)
    for k in range(5):
        if (level == k).any():
            cv2.polylines(cover, ends[level == k], False, weather.rain_intensity * (0.5 + 0.5 * (k + 0.5) / 5))
    cover = cv2.resize(cover, shape[::-1], interpolation=cv2.INTER_AREA) if shape != cover.shape else cover
    return 1 - cover, cover


@pytest.mark.parametrize("streaks, length, angle", [(70, 9.0, 12.0), (1, 3.0, -80.0), (400, 30.0, 80.0)])
def test_rain_is_the_rain_it_was(streaks, length, angle):
    weather = WeatherConfig(rain_streaks=streaks, rain_length=length, rain_angle_deg=angle, rain_intensity=0.4)
    for shape in ((48, 64), (120, 160), (37, 91)):
        rng, ref_rng = np.random.default_rng(4), np.random.default_rng(4)
        for _ in range(30):
            assert all(
                np.array_equal(a, b)
                for a, b in zip(_rain_cover(shape, weather, rng), rain_cover_by_masks(shape, weather, ref_rng))
            )
        assert rng.random() == ref_rng.random()


def test_eight_bit_conversion_is_the_clipped_rounding():
    """add_noise's one-call conversion is max(x, 0) then convertScaleAbs, also at every rounding boundary."""
    boundaries = ((np.arange(-3, 260) + 0.5) / 255).astype(np.float32).view(np.int32)
    near = (boundaries[:, None] + np.arange(-64, 65)).astype(np.int32).view(np.float32).ravel()
    rng = np.random.default_rng(5)
    special = [0.0, -0.0, 1.0, 1e-30, -1e-30, 2.0, -2.0]
    values = np.concatenate([near, special, rng.uniform(-0.3, 1.3, 30000)]).astype(np.float32)
    img = np.resize(values, (len(values) // 192 + 1) * 192).reshape(-1, 64, 3)
    assert np.array_equal(add_noise(img.copy(), 0.0, rng), cv2.convertScaleAbs(np.maximum(img, 0.0), alpha=255.0))
