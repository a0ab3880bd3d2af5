"""Safe sets against controllers whose safety is known: the autopilot (η̂1 ≈ 1) and full left (η̂1 ≈ 0)."""

import tempfile
from pathlib import Path

import numpy as np
import pytest
from conftest import CONF

from uqdrive.policy.recipes import ConstantSpec, ExpertSpec, PolicyRecipe
from uqdrive.safety.cells import EstimatorSettings
from uqdrive.safety.executors import RolloutJob
from uqdrive.safety.runner import CellRunner
from uqdrive.safety.safe_sets import obstacle_pass_progress, safe_set_for
from uqdrive.sim import ScenarioConfig, WeatherConfig, build_geometry
from uqdrive.sim.condition import Condition


def scenario(name: str) -> ScenarioConfig:
    return ScenarioConfig.from_yaml(CONF / "scenario" / f"{name}.yaml")


def eta1(spec: PolicyRecipe, name: str, theta: float = 0.3, **job) -> tuple[float, list]:
    """η̂1 over chernoff_n(θ, 0.05) rollouts (21 at θ = 0.3), in this process."""
    weather = WeatherConfig.from_yaml(CONF / "weather" / "clear_noon.yaml")
    cell = RolloutJob(spec, Condition(scenario(name), weather, 0.0), base_seed=10, **job)
    with tempfile.TemporaryDirectory() as log, CellRunner("process", 1, progress=False) as runner:
        run = runner.estimate(name, cell, EstimatorSettings("chernoff", theta, 0.05, 10), "key", Path(log) / "log")
    estimate, results = run.outcome, run.results
    assert estimate.n == len(results) and [r.seed for r in results] == list(range(10, 10 + estimate.n))
    return estimate.value, results


AUTOPILOT = ExpertSpec()  # unperturbed pure pursuit (AutopilotConfig defaults, as in conf/sim.yaml)
FULL_LEFT = ConstantSpec(1.0, 6.0)


LOCATIONS = ["roundabout", "roundabout_large", "roundabout_town"]  # the offline-safety sweep's locations


@pytest.mark.parametrize("location", LOCATIONS)
def test_autopilot_drives_every_location_safely(location):
    value, results = eta1(AUTOPILOT, location)
    assert value == 1.0
    assert all(
        r.termination == "route_complete" and r.verdict.reached_goal and not r.verdict.left_corridor for r in results
    )
    assert (
        max(r.verdict.corridor_use for r in results) < 0.95
    )  # the body stays in its lane with a margin (measured 0.89)
    assert max(r.mean_abs_lateral_deviation for r in results) < 0.5
    assert all(
        0 < r.verdict.margin == pytest.approx(1 - r.verdict.corridor_use) for r in results
    )  # the lane binds, not the exit


def test_full_left_is_unsafe_at_the_roundabout():
    value, results = eta1(FULL_LEFT, "roundabout")
    assert value == 0.0
    assert all(r.verdict.left_corridor and not r.verdict.reached_goal and r.verdict.corridor_use > 1 for r in results)
    assert all(r.verdict.margin <= 1 - r.verdict.corridor_use < 0 for r in results)  # its worst moment, signed


def test_a_lane_kept_but_an_exit_not_reached_has_the_exit_as_its_margin():
    """Slow enough to time out on the ring, in lane: unsafe, and the margin is the (negative) way left to the exit."""
    value, results = eta1(ExpertSpec(), "roundabout", horizon_s=4.0)
    assert value == 0.0
    assert all(not r.verdict.reached_goal and not r.verdict.left_corridor and r.verdict.margin < 0 for r in results)


@pytest.mark.parametrize("name", ["straight", "obstacle"])
def test_road_safe_sets_need_no_collision_and_no_off_road(name):
    assert eta1(AUTOPILOT, name, theta=0.5)[0] == 1.0
    value, results = eta1(FULL_LEFT, name, theta=0.5)
    assert value == 0.0 and all(r.verdict.off_road or r.verdict.collision for r in results)


def test_a_timeout_before_the_obstacle_is_not_safe():
    """A car too slow to reach the obstacle within the horizon has answered nothing: unsafe, goal not reached."""
    value, results = eta1(ConstantSpec(0.0, 1.0), "obstacle", theta=0.5, horizon_s=5.0)
    assert value == 0.0
    assert all(r.termination == "timeout" and not r.verdict.reached_goal and not r.verdict.collision for r in results)


def test_passing_the_obstacle_is_the_obstacle_roads_goal():
    value, results = eta1(AUTOPILOT, "obstacle", theta=0.5)
    assert value == 1.0 and all(r.verdict.reached_goal for r in results)
    geometry = build_geometry(scenario("obstacle"))
    safe = safe_set_for(geometry, 1.8, 4.5)
    assert safe.half_width is None
    assert safe.goal_progress == pytest.approx(obstacle_pass_progress(geometry, 4.5))
    assert safe.goal_progress > geometry.config.obstacle_distance


def test_the_body_not_its_centre_must_stay_in_the_lane():
    """A car whose centre is inside the lane but which points out of the ring has a corner beyond the lane: unsafe,
    before any off-road termination (a path that turned too little at the large ring did exactly this)."""
    geometry = build_geometry(scenario("roundabout_large"))
    safe = safe_set_for(geometry, 1.8, 4.5)
    route = geometry.route
    cx, cy, _ = geometry.island
    on_ring = np.flatnonzero(np.abs(np.hypot(route.x - cx, route.y - cy) - geometry.config.ring_radius) < 0.05)
    k = int(on_ring[len(on_ring) // 2])  # the middle of the ring part of the route
    heading = np.arctan2(np.gradient(route.y)[k], np.gradient(route.x)[k])
    normal = np.array([-np.sin(heading), np.cos(heading)])
    centre = np.array([route.x[k], route.y[k]]) - 1.3 * normal  # 1.3 m outwards of the lane's centre line
    along = safe.judge(geometry, np.array([centre[0]]), np.array([centre[1]]), np.array([heading]), "")
    across = safe.judge(geometry, np.array([centre[0]]), np.array([centre[1]]), np.array([heading - 1.0]), "")
    assert along.corridor_use < 1 and not along.left_corridor
    assert across.corridor_use > 1 and across.left_corridor and not across.safe


def test_corridor_half_width_is_configurable():
    """A corridor narrower than the autopilot's tracking error makes the same paths unsafe."""
    value, results = eta1(AUTOPILOT, "roundabout", theta=0.5, half_width=0.05)
    assert value == 0.0 and all(r.verdict.left_corridor and r.termination == "route_complete" for r in results)


def test_default_corridor_is_the_lane_and_ends_at_the_first_exit():
    geometry = build_geometry(scenario("roundabout"))
    safe = safe_set_for(geometry, 1.8, 4.5)
    cfg = geometry.config
    np.testing.assert_allclose(np.unique(safe.half_width), sorted({cfg.lane_width / 2, cfg.ring_width / 2}))
    assert 0 < safe.goal_progress < geometry.route.length
    exit_x, exit_y, _ = geometry.route.sample(safe.goal_progress)
    assert np.hypot(exit_x, exit_y) == pytest.approx(cfg.ring_radius + cfg.ring_width / 2, abs=0.5)
    left, right = safe.boundaries()
    assert left.shape == right.shape == (len(geometry.route.s), 2)
    assert safe_set_for(build_geometry(scenario("straight")), 1.8, 4.5).boundaries() is None


def test_time_to_the_lane_edge_is_the_bodys_room_over_its_speed_and_zero_once_out():
    geometry = build_geometry(scenario("roundabout_large"))
    safe = safe_set_for(geometry, 1.8, 4.5)
    route, (cx, cy, _) = geometry.route, geometry.island
    on_ring = np.flatnonzero(np.abs(np.hypot(route.x - cx, route.y - cy) - geometry.config.ring_radius) < 0.05)
    k = int(on_ring[len(on_ring) // 2])  # the middle of the ring part of the route
    heading = np.arctan2(np.gradient(route.y)[k], np.gradient(route.x)[k])
    x, y, yaw = np.array([route.x[k]]), np.array([route.y[k]]), np.array([heading])
    radius = float(np.hypot(route.x[k] - cx, route.y[k] - cy))  # the outer front corner sticks out furthest:
    out = float(np.hypot(radius + 0.9, 4.5 / 2)) - radius  # half the width, plus the ring's sagitta over the length
    room = float(np.interp(route.project(np.array([[x[0], y[0]]]))[0][0], route.s, safe.half_width)) - out
    assert safe.time_to_boundary(geometry, x, y, yaw, np.array([5.0])) == pytest.approx(room / 5.0, abs=0.02)
    assert safe.time_to_boundary(geometry, x, y, yaw, np.array([10.0])) == pytest.approx(room / 10.0, abs=0.01)
    assert np.isnan(safe.time_to_boundary(geometry, x, y, yaw, np.array([0.0])))  # never moved
    normal = np.array([-np.sin(heading), np.cos(heading)])
    ox, oy = np.array([x[0], y[0]]) - 1.3 * normal  # outwards, pointing out of the ring: a corner beyond the lane
    assert safe.time_to_boundary(geometry, np.array([ox]), np.array([oy]), yaw - 1.0, np.array([5.0])) == 0.0
    straight = build_geometry(scenario("straight"))
    assert np.isnan(safe_set_for(straight, 1.8, 4.5).time_to_boundary(straight, x, y, yaw, np.array([5.0])))
