"""A scenario's whole geometry: its layout (`uqdrive.sim.layouts`, from the route and paving building blocks) and
the scenery placed around it.

All of it is plain numpy, independent of pybullet, so safety boundaries and analyses can use
the same geometry the world was built from. World frame: x east, y north, z up, metres.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .config import ScenarioConfig
from .layouts import LAYOUTS, Layout, Prop
from .paving import PavedArea


@dataclasses.dataclass(frozen=True)
class ScenarioGeometry(Layout):
    """Everything the world and the safety checks need to know about one scenario: its layout, and around it."""

    config: ScenarioConfig
    scenery: list[Prop]  # trees and buildings off the road
    bounds: tuple[float, float, float, float]  # xmin, ymin, xmax, ymax of the paved area

    def is_paved(self, points: np.ndarray) -> np.ndarray:
        return self.paved.contains(points)

    # the road's lane (`uqdrive.sim.world.Lane`): the route's, the one the car is to keep to
    def position(self, longitudinal: np.ndarray, lateral: np.ndarray) -> np.ndarray:
        x, y, heading = self.route.sample(longitudinal)
        return np.stack([x - lateral * np.sin(heading), y + lateral * np.cos(heading)], axis=-1)

    def local_coordinates(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.route.project(points)

    def heading_at(self, longitudinal: np.ndarray) -> np.ndarray:
        return self.route.sample(longitudinal)[2]

    def width_at(self, longitudinal: np.ndarray) -> np.ndarray:
        """A lane's width on a straight or obstacle road and on a roundabout's arms, the ring's on its ring (the
        route follows the ring's centre line)."""
        cfg = self.config
        if self.island is None:
            return np.full(np.shape(longitudinal), cfg.lane_width)
        x, y, _ = self.route.sample(longitudinal)
        on_ring = np.hypot(x - self.island[0], y - self.island[1]) <= cfg.ring_radius + cfg.ring_width / 2
        return np.where(on_ring, cfg.ring_width, cfg.lane_width)

    def on_lane(self, points: np.ndarray) -> np.ndarray:
        longitudinal, lateral = self.local_coordinates(points)
        inside = (longitudinal >= 0) & (longitudinal <= self.route.length)
        return inside & (np.abs(lateral) <= self.width_at(longitudinal) / 2)

    # what a scenario's kind says about its route: the one place that asks the kind (`uqdrive.safety.safe_sets` and
    # `uqdrive.safety.failures` read these)
    def obstacle_passed(self, vehicle_length: float) -> float:
        """Metres along the route at which the car's centre is a full car length past the first obstacle's centre."""
        obstacle = self.obstacles[0]
        s, _ = self.route.project(np.array([[obstacle.x, obstacle.y]]))
        return float(s[0]) + (obstacle.size[0] + vehicle_length) / 2

    def _on_ring(self) -> np.ndarray:
        """The route's sample indices on a roundabout's ring."""
        cx, cy, _ = self.island
        reach = self.config.ring_radius + self.config.ring_width / 2
        return np.flatnonzero(np.hypot(self.route.x - cx, self.route.y - cy) <= reach)

    def goal_progress(self, vehicle_length: float) -> float | None:
        """Metres along the route a run must reach to have done its task: past the obstacle (an obstacle road),
        where the route leaves the ring (a roundabout: its first exit); None on a straight road (its end)."""
        if self.config.kind == "obstacle":
            return self.obstacle_passed(vehicle_length)
        if self.config.kind == "roundabout":
            return float(self.route.s[self._on_ring()[-1]])
        return None

    def corridor_half_widths(self, half_width: float | None) -> np.ndarray | None:
        """Per route sample, the half-width a run must keep to: a roundabout's lane (``half_width`` in its place);
        None elsewhere (no corridor but the paved road)."""
        if self.config.kind != "roundabout":
            return None
        s = self.route.s
        return self.width_at(s) / 2 if half_width is None else np.full(len(s), half_width)

    def parts(self, vehicle_length: float | None) -> list[tuple[str, float]]:
        """The route's named parts as (name, start in metres), in order: a roundabout's approach, ring and exit arm;
        an obstacle road before and past the obstacle (for a car of ``vehicle_length``; None: whole); a road whole."""
        kind, route = self.config.kind, self.route
        if kind == "roundabout":
            on_ring = self._on_ring()
            entry = float(route.s[on_ring[0]]) if len(on_ring) else 0.0
            exit_ = float(route.s[on_ring[-1]]) if len(on_ring) else float(route.s[-1])
            return [("approach", 0.0), ("ring", entry), ("exit arm", exit_)]
        if kind == "obstacle" and vehicle_length is not None:
            return [("before the obstacle", 0.0), ("past the obstacle", self.obstacle_passed(vehicle_length))]
        return [("road", 0.0)]


def _place_scenery(cfg: ScenarioConfig, paved: PavedArea, bounds, island) -> list[Prop]:
    rng = np.random.default_rng(cfg.scenery_seed)
    xmin, ymin, xmax, ymax = bounds
    ext = cfg.scenery_extent
    distance = paved.distance_field(ext + 1.0)
    items: list[Prop] = []
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
        items.append(Prop("tree" if tree else "building", x, y, yaw, size, color))
    return items


def build_geometry(cfg: ScenarioConfig) -> ScenarioGeometry:
    """Centre-line geometry of a scenario (deterministic in the config, scenery in scenery_seed)."""
    lay = LAYOUTS[cfg.kind](cfg)  # ScenarioConfig checked the kind (SCENARIO_KINDS: the registry's keys)
    xs = np.concatenate([t.reshape(-1, 2) for t in lay.asphalt])
    bounds = (float(xs[:, 0].min()), float(xs[:, 1].min()), float(xs[:, 0].max()), float(xs[:, 1].max()))
    scenery = _place_scenery(cfg, lay.paved, bounds, lay.island)
    layout = {f.name: getattr(lay, f.name) for f in dataclasses.fields(lay)}
    return ScenarioGeometry(**layout, config=cfg, scenery=scenery, bounds=bounds)
