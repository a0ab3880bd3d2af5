"""pybullet bodies of a scenario: ground, road, markings, props and the ego car.

Road and markings are visual-only so they never take part in collision checks; the obstacle
car, scenery and the roundabout island have collision shapes. Nothing here is ever stepped
by the physics engine: the ego pose is set kinematically and collisions are queried.

TinyRenderer transforms and clips every triangle of every visible body, in view or not; for
the trees and buildings that is about half of a 64x48 render. `Scene.cull` hides (alpha 0,
which TinyRenderer skips) the bodies whose ground footprint lies outside the camera's view,
so the image is unchanged and only what can be seen is rasterised.
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from .bullet import pybullet as p
from .config import VehicleConfig
from .geometry import ScenarioGeometry

_MAX_TRIANGLES = 2500  # pybullet caps vertices per mesh (8192 on some builds); 3 per triangle
_CHASSIS_CLEARANCE = 0.25  # collision box starts above the ground so it never touches it
_ASPHALT_Z, _MARKING_Z = 0.01, 0.025


def _rgba(color) -> list[float]:
    return [float(color[0]), float(color[1]), float(color[2]), 1.0]


def _yaw_quat(yaw: float) -> list[float]:
    return [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]


class Scene:
    """Static bodies of one scenario plus the ego car, in one pybullet client."""

    def __init__(self, client, geometry: ScenarioGeometry, vehicle: VehicleConfig):
        self.client = client
        self.geometry = geometry
        cfg = geometry.config
        client.resetSimulation()
        self.road_ids: list[int] = []
        self._collidable: list[tuple[int, float, float, float]] = []  # id, x, y, bounding radius
        self._cullable: list[
            tuple[int, float, float, float, list[list[float]]]
        ] = []  # id, x, y, radius, rgba per shape

        xmin, ymin, xmax, ymax = geometry.bounds
        cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
        half = max(xmax - xmin, ymax - ymin) / 2 + cfg.scenery_extent + 300.0
        ground = client.createVisualShape(p.GEOM_BOX, halfExtents=[half, half, 0.05], rgbaColor=_rgba(cfg.ground_color))
        self.ground_id = client.createMultiBody(0, -1, ground, basePosition=[cx, cy, -0.05])

        for tris in geometry.asphalt:
            self.road_ids += self._mesh(tris, _ASPHALT_Z, cfg.asphalt_color)
        self.marking_ids = self._mesh(geometry.markings, _MARKING_Z, cfg.marking_color)
        self.road_ids += self.marking_ids

        for ob in geometry.obstacles:
            body = self.car_body(client, ob.size, ob.color, wheelbase=0.6 * ob.size[0])
            client.resetBasePositionAndOrientation(body, [ob.x, ob.y, 0.0], _yaw_quat(ob.yaw))
            radius = 0.5 * math.hypot(ob.size[0], ob.size[1])
            self._collidable.append((body, ob.x, ob.y, radius))
            self._cullable.append((body, ob.x, ob.y, radius, self.car_colors(ob.color)))
        if geometry.island is not None:
            self._add_island(*geometry.island)
        for item in geometry.scenery:
            body, colors = self._prop(item)
            radius = item.size[1] if item.kind == "tree" else 0.5 * math.hypot(*item.size[:2])
            self._collidable.append((body, item.x, item.y, radius))
            self._cullable.append((body, item.x, item.y, radius, colors))
        self._cull_xy = np.array([[c[1], c[2]] for c in self._cullable]).reshape(-1, 2)
        self._cull_reach = -np.array([c[3] for c in self._cullable])[:, None]  # signed distance a body reaches
        self._shown = np.ones(len(self._cullable), bool)

        self.vehicle = vehicle
        self.ego_id = self.car_body(
            client, (vehicle.length, vehicle.width, vehicle.height), vehicle.color, vehicle.wheelbase, visible=False
        )
        # road mask of a segmentation image in one lookup: road_lookup[seg + 1] (seg is -1 on the sky)
        self.road_lookup = np.zeros(client.getNumBodies() + 1, bool)
        self.road_lookup[np.asarray(self.road_ids, int) + 1] = True
        # in_collision's props sorted by x (x, y, squared reach, id), and the farthest reach, for a window on x
        half_diagonal = 0.5 * math.hypot(vehicle.length, vehicle.width)
        reach = sorted((float(x), float(y), r + half_diagonal + 0.1, body) for body, x, y, r in self._collidable)
        self._near_x = [x for x, *_ in reach]
        self._near_test = [(x, y, d * d, body) for x, y, d, body in reach]
        self._near_reach = max((d for *_, d, _ in reach), default=0.0) + 1e-6  # more than rounding can move
        self._ego_pose: tuple[float, float, float] | None = None  # set but not yet placed in pybullet

    def _add_island(self, ix: float, iy: float, r: float) -> None:
        """The roundabout's central island (collidable) with its kerb (visual only)."""
        client, cfg = self.client, self.geometry.config
        kerb_rgba = [0.75, 0.75, 0.72, 1.0]
        kerb = client.createVisualShape(p.GEOM_CYLINDER, radius=r + 0.3, length=0.2, rgbaColor=kerb_rgba)
        self._cullable.append(
            (client.createMultiBody(0, -1, kerb, basePosition=[ix, iy, 0.1]), ix, iy, r + 0.3, [kerb_rgba])
        )
        col = client.createCollisionShape(p.GEOM_CYLINDER, radius=r, height=cfg.island_height)
        island_rgba = _rgba(np.clip(np.asarray(cfg.ground_color) * 1.15, 0, 1))
        vis = client.createVisualShape(p.GEOM_CYLINDER, radius=r, length=cfg.island_height, rgbaColor=island_rgba)
        body = client.createMultiBody(0, col, vis, basePosition=[ix, iy, cfg.island_height / 2])
        self._collidable.append((body, ix, iy, r))
        self._cullable.append((body, ix, iy, r, [island_rgba]))

    def _mesh(self, triangles: np.ndarray, z: float, color) -> list[int]:
        """Flat triangle mesh bodies (visual only); triangles made counter-clockwise so they face up."""
        tris = np.asarray(triangles, float)
        u, v = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
        area = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
        tris = np.where((area < 0)[:, None, None], tris[:, ::-1], tris)
        ids = []
        for start in range(0, len(tris), _MAX_TRIANGLES):
            chunk = tris[start : start + _MAX_TRIANGLES].reshape(-1, 2)
            verts = np.column_stack([chunk, np.full(len(chunk), z)])
            vis = self.client.createVisualShape(
                p.GEOM_MESH,
                vertices=verts.tolist(),
                indices=list(range(len(verts))),
                normals=[[0.0, 0.0, 1.0]] * len(verts),
                rgbaColor=_rgba(color),
            )
            ids.append(self.client.createMultiBody(0, -1, vis))
            lo, hi = chunk.min(axis=0), chunk.max(axis=0)
            centre = (lo + hi) / 2
            radius = float(np.max(np.hypot(*(chunk - centre).T)))
            self._cullable.append((ids[-1], float(centre[0]), float(centre[1]), radius, [_rgba(color)]))
        return ids

    def _prop(self, item) -> tuple[int, list[list[float]]]:
        """Body of a tree or building, and the RGBA of each of its visual shapes."""
        c = self.client
        if item.kind == "tree":
            trunk_r, crown_r, height = item.size
            trunk_h = height - crown_r
            col = c.createCollisionShape(
                p.GEOM_CYLINDER, radius=trunk_r, height=trunk_h, collisionFramePosition=[0, 0, trunk_h / 2]
            )
            colors = [_rgba(self.geometry.config.trunk_color), _rgba(item.color)]
            vis = c.createVisualShapeArray(
                shapeTypes=[p.GEOM_CYLINDER, p.GEOM_SPHERE],
                radii=[trunk_r, crown_r],
                lengths=[trunk_h, 0],
                rgbaColors=colors,
                visualFramePositions=[[0, 0, trunk_h / 2], [0, 0, trunk_h]],
            )
        else:
            he = [item.size[0] / 2, item.size[1] / 2, item.size[2] / 2]
            col = c.createCollisionShape(p.GEOM_BOX, halfExtents=he, collisionFramePosition=[0, 0, he[2]])
            colors = [_rgba(item.color)]
            vis = c.createVisualShape(
                p.GEOM_BOX, halfExtents=he, rgbaColor=colors[0], visualFramePosition=[0, 0, he[2]]
            )
        body = c.createMultiBody(0, col, vis, basePosition=[item.x, item.y, 0.0], baseOrientation=_yaw_quat(item.yaw))
        return body, colors

    @staticmethod
    def car_colors(color) -> list[list[float]]:
        """RGBA of the visual shapes of `car_body`, in order: body, cabin, four wheels."""
        cabin_color = np.clip(np.asarray(color) * 0.55 + 0.12, 0, 1)
        return [_rgba(color), _rgba(cabin_color)] + [[0.08, 0.08, 0.08, 1.0]] * 4

    @staticmethod
    def car_body(client, size, color, wheelbase: float, visible: bool = True) -> int:
        """Car-shaped static body, origin on the ground under the body centre, x forward.

        Body box, cabin and four dark wheels are visuals; the collision box spans the body
        above a ground clearance so it only ever touches raised things. The ego is not
        ``visible`` (alpha 0, which the renderer skips at no cost): its own camera must not see
        it, and one parked out of sight would still be rasterised. (Without visuals at all,
        pybullet would draw the collision box instead.)
        """
        col_h = size[2] - _CHASSIS_CLEARANCE
        col = client.createCollisionShape(
            p.GEOM_BOX,
            halfExtents=[size[0] / 2, size[1] / 2, col_h / 2],
            collisionFramePosition=[0, 0, _CHASSIS_CLEARANCE + col_h / 2],
        )
        length, width, height = size
        body_h = 0.55 * height
        base_z = 0.3
        cabin_h = height - base_z - body_h
        wheel_r = 0.33
        wx, wy = wheelbase / 2, width / 2 - 0.12
        shapes = [p.GEOM_BOX, p.GEOM_BOX] + [p.GEOM_CYLINDER] * 4
        half = [[length / 2, width / 2, body_h / 2], [0.27 * length, 0.45 * width, cabin_h / 2]] + [[0, 0, 0]] * 4
        positions = [[0, 0, base_z + body_h / 2], [-0.08 * length, 0, base_z + body_h + cabin_h / 2]]
        positions += [[sx * wx, sy * wy, wheel_r] for sx in (1, -1) for sy in (1, -1)]
        colors = [[*rgba[:3], 1.0 if visible else 0.0] for rgba in Scene.car_colors(color)]
        wheel_q = p.getQuaternionFromEuler([math.pi / 2, 0, 0])
        vis = client.createVisualShapeArray(
            shapeTypes=shapes,
            halfExtents=half,
            radii=[0, 0] + [wheel_r] * 4,
            lengths=[0, 0] + [0.25] * 4,
            rgbaColors=colors,
            visualFramePositions=positions,
            visualFrameOrientations=[[0, 0, 0, 1]] * 2 + [wheel_q] * 4,
        )
        return client.createMultiBody(0, col, vis)

    def set_ego_pose(self, x: float, y: float, yaw: float) -> None:
        """Move the ego, in pybullet only once a query needs it (`_place_ego`): the ego is invisible, so
        its pose matters to `in_collision` and `clearance` alone, and an env step is mostly far from props."""
        self._ego_pose = (x, y, yaw)

    def _place_ego(self) -> None:
        if self._ego_pose is not None:
            x, y, yaw = self._ego_pose
            self.client.resetBasePositionAndOrientation(self.ego_id, [x, y, 0.0], _yaw_quat(yaw))
            self._ego_pose = None

    def cull(self, apex_x: float, apex_y: float, yaw: float, half_angle: float) -> None:
        """Show exactly the bodies whose ground footprint (bounding circle) meets the wedge of
        directions ``yaw ± half_angle`` from the apex; hide the others (alpha 0).

        The wedge must contain the ground projection of every camera ray (`Camera.view_wedge`),
        so a hidden body is one the camera could not see: the rendered image does not change.
        Only bodies whose visibility changed are touched.
        """
        if half_angle >= math.pi / 2:
            visible = np.ones_like(self._shown)
        else:
            left, right = yaw + half_angle, yaw - half_angle
            inward = np.array([[math.sin(left), -math.sin(right)], [-math.cos(left), math.cos(right)]])
            inside = (self._cull_xy - (apex_x, apex_y)) @ inward >= self._cull_reach  # of each side's half-plane
            visible = inside[:, 0] & inside[:, 1]
        for k in np.flatnonzero(visible != self._shown):
            body, *_, colors = self._cullable[k]
            for shape, rgba in enumerate(colors):
                self.client.changeVisualShape(
                    body, -1, shapeIndex=shape, rgbaColor=rgba if visible[k] else [*rgba[:3], 0.0]
                )
        self._shown = visible

    def in_collision(self, x: float, y: float) -> bool:
        """Exact pybullet overlap test of the ego (at its current pose) against nearby props.

        "Nearby" is a bounding-circle test with 0.1 m to spare, in plain Python over the props within
        reach along x (numpy's per-call cost was most of an env step's collision check).
        """
        lo = bisect.bisect_left(self._near_x, x - self._near_reach)
        hi = bisect.bisect_right(self._near_x, x + self._near_reach)
        for px, py, reach2, body in self._near_test[lo:hi]:
            dx, dy = px - x, py - y
            if dx * dx + dy * dy <= reach2:
                self._place_ego()
                if self.client.getClosestPoints(self.ego_id, body, distance=0.0):
                    return True
        return False

    def clearance(self, max_distance: float = 5.0) -> float:
        """Smallest distance (m) from the ego to any collidable body within max_distance."""
        best = max_distance
        self._place_ego()
        for body, *_ in self._collidable:
            for pt in self.client.getClosestPoints(self.ego_id, body, distance=max_distance):
                best = min(best, pt[8])
        return best
