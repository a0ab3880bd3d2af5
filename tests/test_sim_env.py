import contextlib
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from uqdrive.network_input import INPUT_HEIGHT, INPUT_WIDTH, preprocess_frame
from uqdrive.sim import CameraConfig, DrivingEnv, ScenarioConfig, WeatherConfig, build_geometry
from uqdrive.sim.camera import _rain_cover
from uqdrive.sim.condition import Condition
from uqdrive.sim.scene import Scene

CONF = Path(__file__).resolve().parents[1] / "conf"
WEATHERS = {
    n: WeatherConfig.from_yaml(CONF / "weather" / f"{n}.yaml") for n in ("clear_noon", "afternoon", "rain", "fog")
}
OBSTACLE = ScenarioConfig(kind="obstacle", name="obstacle")


@pytest.fixture(scope="module")
def env():
    with DrivingEnv() as e:
        yield e


def run(env, seed, weather, noise=0.0, steps=4, scenario=OBSTACLE, render=True):
    frames = [env.reset(seed, Condition(scenario, weather, noise), render=render)]
    for k in range(steps):
        obs, _ = env.step(0.1 * np.sin(k), 8.0)
        frames.append(obs)
    return frames, env.trajectory


def test_observation_shape_and_render_off(env):
    frames, traj = run(env, 0, WEATHERS["clear_noon"], steps=1)
    assert frames[0].shape == (INPUT_HEIGHT, INPUT_WIDTH, 3) and frames[0].dtype == np.uint8  # the network's size
    with DrivingEnv(CameraConfig(width=160, height=120)) as large:  # a larger render is delivered reduced
        assert run(large, 0, WEATHERS["clear_noon"], steps=0)[0][0].shape == (INPUT_HEIGHT, INPUT_WIDTH, 3)
        assert large.camera.last_depth.shape == (120, 160)
    frames, _ = run(env, 0, WEATHERS["clear_noon"], steps=1, render=False)
    assert frames == [None, None]
    assert set(traj) == {"t", "x", "y", "yaw", "speed", "steering"} and len(traj["t"]) == 2
    assert np.isclose(traj["t"][1], 1 / 15)


def test_same_seed_same_path_and_images_different_seed_differs(env):
    rain = WEATHERS["rain"]
    a, ta = run(env, 7, rain, noise=0.05)
    b, tb = run(env, 7, rain, noise=0.05)
    c, tc = run(env, 8, rain, noise=0.05)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert all(np.array_equal(ta[k], tb[k]) for k in ta)
    assert not np.array_equal(ta["y"], tc["y"])
    assert not any(np.array_equal(x, y) for x, y in zip(a, c))


def test_same_path_in_a_fresh_process_and_with_render_off(env, tmp_path):
    _, here = run(env, 5, WEATHERS["clear_noon"], render=False)
    _, rendered = run(env, 5, WEATHERS["rain"], noise=0.05, render=True)
    out = tmp_path / "trajectory.json"  # a file, not stdout: the child's output is not ours to parse
    code = (
        "import json, sys, numpy as np\nfrom uqdrive.sim import DrivingEnv, ScenarioConfig\n"
        "from uqdrive.sim.condition import Condition\n"
        "print('before', flush=True)\n"
        "with DrivingEnv() as env:\n"
        "    env.reset(5, Condition(ScenarioConfig(kind='obstacle', name='obstacle'), None), render=False)\n"
        "    for k in range(4): env.step(0.1 * np.sin(k), 8.0)\n"
        "    open(sys.argv[1], 'w').write(json.dumps({k: v.tolist() for k, v in env.trajectory.items()}))\n"
        "print('after')\n"
    )
    child = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True, text=True, check=True)
    other = json.loads(out.read_text())
    for key in here:
        assert here[key].tolist() == other[key]
        assert np.array_equal(here[key], rendered[key])
    assert child.stdout == "before\nafter\n"  # pybullet's native "argv[0]=" is silenced at the descriptor
    assert "pybullet build time" not in child.stderr


def test_collision_driving_straight_into_the_obstacle(env):
    scenario = dataclasses.replace(OBSTACLE, start_jitter_lateral=0.0, start_jitter_yaw_deg=0.0)
    env.reset(0, Condition(scenario, None), render=False)
    info = env.last_info
    while not info["done"]:
        _, info = env.step(0.0, env.vehicle_config.max_speed)
    obstacle = env.geometry.obstacles[0]
    assert info["termination"] == "collision" and info["collision"] and not info["off_road"]
    gap = obstacle.x - info["x"] - (obstacle.size[0] + env.vehicle_config.length) / 2
    assert -1.5 < gap <= 0.0
    with pytest.raises(RuntimeError, match="reset"):
        env.step(0.0, 0.0)


def test_off_road_with_full_left_steering(env):
    env.reset(0, Condition(ScenarioConfig(kind="straight"), None), render=False)
    info = env.last_info
    while not info["done"]:
        _, info = env.step(1.0, 8.0)
    assert info["termination"] == "off_road" and not info["collision"]
    assert info["lateral_deviation"] > 0  # positive steering turns left, i.e. to +lateral
    assert info["t"] < 3.0


def test_timeout(env):
    with DrivingEnv(horizon_s=1.0) as short:
        short.reset(0, Condition(ScenarioConfig(kind="straight"), None), render=False)
        info = short.last_info
        while not info["done"]:
            _, info = short.step(0.0, 8.0)
    assert info["termination"] == "timeout" and np.isclose(info["t"], 1.0)


def test_every_weather_changes_the_image(env):
    clear = run(env, 0, WEATHERS["clear_noon"], steps=0)[0][0].astype(float)
    for name in ("afternoon", "rain", "fog"):
        img = run(env, 0, WEATHERS[name], steps=0)[0][0].astype(float)
        assert np.abs(img - clear).mean() > 8, name


def test_fog_lowers_contrast_with_depth(env):
    fog = WEATHERS["fog"]
    clear = run(env, 0, WEATHERS["clear_noon"], steps=0)[0][0].astype(float)
    foggy = run(env, 0, fog, steps=0)[0][0].astype(float)
    depth = env.camera.last_depth
    fog_rgb = np.asarray(fog.fog_color) * 255 * fog.brightness
    dist = np.abs(foggy - fog_rgb).mean(axis=2)
    near, far = depth < 8, np.isfinite(depth) & (depth > 50)
    assert near.sum() > 100 and far.sum() > 100
    assert dist[far].mean() < 0.35 * dist[near].mean()
    ratio_far = foggy[far].std() / clear[far].std()
    ratio_near = foggy[near].std() / clear[near].std()
    assert ratio_far < 0.5 * ratio_near


@pytest.mark.parametrize("size", [None, (80, 60), (160, 120)])
def test_noise_only_adds_noise_and_sigma_is_what_the_network_sees(env, size):
    """At every render size: the frame is reduced to 64x48 before the noise, so σ is not averaged away."""
    rain = WEATHERS["rain"]
    sized = DrivingEnv(CameraConfig(width=size[0], height=size[1])) if size else contextlib.nullcontext(env)
    with sized as env:
        clean, t_clean = run(env, 3, rain, noise=0.0)
        noisy, t_noisy = run(env, 3, rain, noise=0.05)
    for c, n in zip(clean, noisy):
        diff = n.astype(float) - c.astype(float)
        assert abs(diff.mean()) < 1.5
        assert (np.abs(diff[..., 0] - diff[..., 1]) <= 1).mean() > 0.95  # one luminance draw, all channels
        seen = preprocess_frame(n).astype(float) - preprocess_frame(c).astype(float)
        assert 0.05 * 255 * 0.93 < seen.std() < 0.05 * 255 * 1.07  # sigma on the network's input
        assert (np.abs(diff) > 5.5 * 12.75).mean() < 1e-3  # same rain streaks underneath
    assert all(np.array_equal(t_clean[k], t_noisy[k]) for k in t_clean)


@pytest.mark.parametrize("scenario", ["roundabout", "obstacle"])
def test_culling_hides_bodies_but_never_changes_the_image(env, scenario):
    config = ScenarioConfig.from_yaml(CONF / "scenario" / f"{scenario}.yaml")
    culled, _ = run(env, 2, WEATHERS["rain"], noise=0.05, steps=12, scenario=config)
    hidden = int((~env.scene._shown).sum())
    with DrivingEnv() as every_body:
        every_body.reset(2, Condition(config, None), render=False)  # builds the world
        world = every_body.scene
        world.cull = lambda x, y, yaw, half_angle: Scene.cull(world, x, y, yaw, np.pi)  # a wedge hiding nothing
        shown, _ = run(every_body, 2, WEATHERS["rain"], noise=0.05, steps=12, scenario=config)
        assert world._shown.all()
    assert hidden > 0
    assert all(np.array_equal(a, b) for a, b in zip(culled, shown))


def test_rain_covers_the_same_share_of_the_image_at_every_resolution():
    rain = WEATHERS["rain"]
    rng = np.random.default_rng(0)
    share = {
        size: np.mean([_rain_cover(size, rain, rng)[1].mean() for _ in range(200)]) for size in ((48, 64), (120, 160))
    }
    assert share[(120, 160)] > 0.005 and abs(share[(48, 64)] / share[(120, 160)] - 1) < 0.05


def test_world_is_cached_per_scenario(env):
    env.reset(0, Condition(OBSTACLE, None), render=False)
    world = env.scene
    env.reset(1, Condition(ScenarioConfig(kind="obstacle", name="obstacle"), None), render=False)
    assert env.scene is world
    env.reset(1, Condition(ScenarioConfig(kind="straight"), None), render=False)
    assert env.scene is not world


def test_paved_area_and_route_geometry(env):
    env.reset(0, Condition(ScenarioConfig(kind="roundabout"), None), render=False)
    geo = env.geometry
    cfg = geo.config
    r_in, r_out = cfg.ring_radius - cfg.ring_width / 2, cfg.ring_radius + cfg.ring_width / 2
    pts = np.array(
        [[0, 0], [cfg.ring_radius, 0], [0, -r_out - 5], [r_out + 10, r_out + 10], [3.8, -17.2], [0, -r_in + 0.5]]
    )
    assert geo.is_paved(pts).tolist() == [False, True, True, False, True, False]  # island, ring, arm, grass, fillet
    s, lat = geo.route.project(geo.route.points[::50] + [0.0, 0.0])
    assert np.allclose(s, geo.route.s[::50], atol=1e-6) and np.allclose(lat, 0, atol=1e-6)
    assert geo.is_paved(geo.route.points).all()
    start = geo.route.sample(0.0)
    assert np.isclose(start[2], np.pi / 2)
    end = geo.route.sample(geo.route.length)
    assert np.isclose(end[2], 0.0, atol=1e-6)


@pytest.mark.parametrize("name", ["roundabout", "obstacle"])
def test_a_roads_lane_answers_in_lane_coordinates(name: str) -> None:
    """`ScenarioGeometry` as a `Lane`: a point at (s, lateral) maps back to (s, lateral), the route is on the lane and
    a point a lane width beside it is not, and the width is the lane's (the ring's on a roundabout's ring)."""
    cfg = ScenarioConfig.from_yaml(CONF / "scenario" / f"{name}.yaml")
    lane = build_geometry(cfg)
    s = np.linspace(5.0, lane.route.length - 5.0, 40)
    for lateral in (-0.5, 0.0, 0.8):
        back_s, back_lateral = lane.local_coordinates(lane.position(s, np.full_like(s, lateral)))
        np.testing.assert_allclose(back_s, s, atol=0.05)
        np.testing.assert_allclose(back_lateral, lateral, atol=1e-3)  # a polyline: off a vertex, nearly exact
    assert lane.on_lane(lane.position(s, np.zeros_like(s))).all()
    assert not lane.on_lane(lane.position(s, np.full_like(s, cfg.lane_width + cfg.ring_width))).any()
    np.testing.assert_allclose(lane.heading_at(s), lane.route.sample(s)[2])
    widths = set(np.unique(lane.width_at(lane.route.s)))
    assert widths == ({cfg.lane_width, cfg.ring_width} if cfg.kind == "roundabout" else {cfg.lane_width})
