"""`uqdrive bench sim`: frames per second of `DrivingEnv.step` with the camera, against a bare
`getCameraImage` of the same scene, resolution and lighting in the same run.

The bare render is the floor: TinyRenderer rasterising the scene the env renders (bodies out
of view hidden, as `World.cull` leaves them; the render of every body is printed too). An env
step adds the culling, the car model, the pybullet collision query, the paved-area and route
checks, the image-space weather and sensor noise. Both are timed from the same poses (those the
autopilot drives), on one pybullet client. Times are CPU seconds of this process
(`time.process_time`): the cost per core, and far steadier than the wall clock on a machine shared with other work.
Target: an env step costs at most 1.5x the bare render.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from uqdrive.sim import Autopilot, DrivingEnv, ScenarioConfig, WeatherConfig
from uqdrive.sim.bullet import pybullet as p
from uqdrive.sim.condition import Condition

CONF = Path(__file__).resolve().parents[3] / "conf"


def autopilot_commands(
    env: DrivingEnv, scenario: ScenarioConfig, weather: WeatherConfig, noise: float, steps: int, seed: int
) -> list[tuple[float, float, float, float, float]]:
    """(steer, speed, x, y, yaw) of ``steps`` autopilot steps; episodes restart with seed + 1, … when they end."""
    out: list[tuple[float, float, float, float, float]] = []
    episode = 0
    while len(out) < steps:
        env.reset(seed + episode, Condition(scenario, weather, noise), render=False)
        pilot = Autopilot(env.route, env.vehicle_config, control_hz=env.control_hz, seed=seed + episode)
        info = env.last_info
        while not env.done and len(out) < steps:
            action = pilot.act(info)
            _, info = env.step(action.steer, action.speed)
            out.append((action.steer, action.speed, info["x"], info["y"], info["yaw"]))
        episode += 1
    return out


def time_env_steps(env: DrivingEnv, commands, scenario, weather, noise: float, seed: int) -> float:
    """CPU seconds for the env to replay ``commands`` with the camera on (episodes restart as recorded)."""
    start = time.process_time()
    episode = 0
    env.reset(seed, Condition(scenario, weather, noise))
    for steer, speed, *_ in commands:
        if env.done:
            episode += 1
            env.reset(seed + episode, Condition(scenario, weather, noise))
        env.step(steer, speed)
    return time.process_time() - start


def time_bare_renders(env: DrivingEnv, poses, weather: WeatherConfig, cull: bool = True) -> float:
    """CPU seconds for `getCameraImage` alone at the same poses, resolution, projection and lights.

    ``cull``: of the scene the env renders (bodies out of view hidden, untimed); otherwise of
    every body, as the env rendered before it culled.
    """
    cam, client, world = env.camera, env.client, env.scene
    cfg = cam.config
    light = np.asarray(weather.light_direction, float)
    light = (light / np.linalg.norm(light)).tolist()
    seconds = 0.0
    for x, y, yaw in poses:
        world.cull(*(cam.view_wedge(x, y, yaw) if cull else (x, y, yaw, math.pi)))
        view = cam.view_matrix(x, y, yaw)
        start = time.process_time()
        client.getCameraImage(
            cfg.width,
            cfg.height,
            view,
            cam.projection,
            renderer=p.ER_TINY_RENDERER,
            lightDirection=light,
            lightColor=list(weather.light_color),
            lightAmbientCoeff=weather.ambient,
            lightDiffuseCoeff=weather.diffuse,
            lightSpecularCoeff=weather.specular,
            shadow=int(weather.shadow),
        )
        seconds += time.process_time() - start
    return seconds


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="uqdrive bench sim", description=__doc__)
    ap.add_argument("--scenario", default="roundabout", help="conf/scenario/<name>.yaml")
    ap.add_argument("--weather", default="rain", help="conf/weather/<name>.yaml (rain: every image effect on)")
    ap.add_argument("--noise", type=float, default=0.05, help="sensor noise sigma on the network's frame")
    ap.add_argument("--steps", type=int, default=300, help="steps per timing")
    ap.add_argument("--repeats", type=int, default=3, help="alternating timings; the median ratio is reported")
    ap.add_argument("--seed", type=int, default=0, help="episode seed of the autopilot's drive")
    args = ap.parse_args(argv)
    scenario = ScenarioConfig.from_yaml(CONF / "scenario" / f"{args.scenario}.yaml")
    weather = WeatherConfig.from_yaml(CONF / "weather" / f"{args.weather}.yaml")
    with DrivingEnv() as env:
        commands = autopilot_commands(env, scenario, weather, args.noise, args.steps, args.seed)
        poses = [c[2:] for c in commands]
        time_env_steps(env, commands[:20], scenario, weather, args.noise, args.seed)  # warm-up
        step_s, render_s, full_s = [], [], []
        for _ in range(args.repeats):
            step_s.append(time_env_steps(env, commands, scenario, weather, args.noise, args.seed))
            render_s.append(time_bare_renders(env, poses, weather))
            full_s.append(time_bare_renders(env, poses, weather, cull=False))
    ratios = sorted(s / r for s, r in zip(step_s, render_s))
    ratio = ratios[len(ratios) // 2]
    cfg = env.camera_config
    print(
        f"{args.scenario}, {weather.name}, noise {args.noise:g}, {cfg.width}x{cfg.height} TinyRenderer, "
        f"{args.steps} steps x {args.repeats}"
    )
    print(f"bare getCameraImage, every body: {args.steps / float(np.median(full_s)):7.1f} frames/s")
    print(f"bare getCameraImage, culled:     {args.steps / float(np.median(render_s)):7.1f} frames/s")
    print(
        f"DrivingEnv.step:                 {args.steps / float(np.median(step_s)):7.1f} frames/s   "
        f"step/render {ratio:.2f}x (target <= 1.5)"
    )
    print(f"RESULT sim step_over_render={ratio:.2f}")
    return 0
