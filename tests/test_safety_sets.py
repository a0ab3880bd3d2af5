"""Safe sets against controllers whose safety is known: the autopilot (η̂1 ≈ 1) and full left (η̂1 ≈ 0)."""

import numpy as np
import pytest

from uqdrive.safety import EstimatorSettings, PolicySpec, RolloutJob, estimate_safety, make_executor, safe_set_for
from uqdrive.sim import ScenarioConfig, WeatherConfig, build_geometry

from conftest import CONF


def scenario(name: str) -> ScenarioConfig:
    return ScenarioConfig.from_yaml(CONF / "scenario" / f"{name}.yaml")


def eta1(spec: PolicySpec, name: str, theta: float = 0.3, **job) -> tuple[float, list]:
    """η̂1 over chernoff_n(θ, 0.05) rollouts (21 at θ = 0.3), in this process."""
    weather = WeatherConfig.from_yaml(CONF / "weather" / "clear_noon.yaml")
    executor = make_executor("process", RolloutJob(spec, scenario(name), weather, 0.0, base_seed=10, **job), 1)
    estimate, results = estimate_safety(executor, EstimatorSettings("chernoff", theta, 0.05, 10))
    assert estimate.n == len(results) and [r.seed for r in results] == list(range(10, 10 + estimate.n))
    return estimate.value, results


AUTOPILOT = PolicySpec("autopilot", 6.0)  # unperturbed pure pursuit (AutopilotConfig defaults, as in conf/sim.yaml)
FULL_LEFT = PolicySpec("constant", 6.0, steer=1.0)


def test_autopilot_is_safe_at_the_roundabout():
    value, results = eta1(AUTOPILOT, "roundabout")
    assert value == 1.0
    assert all(r.termination == "route_complete" and r.reached_exit and not r.left_corridor for r in results)
    assert max(r.mean_abs_lateral_deviation for r in results) < 0.5


def test_full_left_is_unsafe_at_the_roundabout():
    value, results = eta1(FULL_LEFT, "roundabout")
    assert value == 0.0
    assert all(r.left_corridor and not r.reached_exit for r in results)


@pytest.mark.parametrize("name", ["straight", "obstacle"])
def test_road_safe_sets_need_no_collision_and_no_off_road(name):
    assert eta1(AUTOPILOT, name, theta=0.5)[0] == 1.0
    value, results = eta1(FULL_LEFT, name, theta=0.5)
    assert value == 0.0 and all(r.off_road or r.collision for r in results)


def test_corridor_half_width_is_configurable():
    """A corridor narrower than the autopilot's tracking error makes the same paths unsafe."""
    value, results = eta1(AUTOPILOT, "roundabout", theta=0.5, half_width=0.05)
    assert value == 0.0 and all(r.left_corridor and r.termination == "route_complete" for r in results)


def test_default_corridor_is_the_lane_and_ends_at_the_first_exit():
    geometry = build_geometry(scenario("roundabout"))
    safe = safe_set_for(geometry)
    cfg = geometry.config
    assert set(np.unique(safe.half_width)) == {cfg.lane_width / 2, cfg.ring_width / 2}
    assert 0 < safe.exit_progress < geometry.route.length
    exit_x, exit_y, _ = geometry.route.sample(safe.exit_progress)
    assert np.hypot(exit_x, exit_y) == pytest.approx(cfg.ring_radius + cfg.ring_width / 2, abs=0.5)
    left, right = safe.boundaries()
    assert left.shape == right.shape == (len(geometry.route.s), 2)
    assert safe_set_for(build_geometry(scenario("straight"))).boundaries() is None
    with pytest.raises(ValueError, match=r"safety.half_width=-1"):
        safe_set_for(geometry, -1)
