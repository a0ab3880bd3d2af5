"""``uqdrive frames --compare-render 160x120``: is the network's input as informative when the camera
renders at its own 64x48 as when 160x120 is rendered and area-reduced?

Both cameras look from the same poses (autopilot episodes, same seeds) with the same rain-streak
and noise draws; both frames go through the network's preprocessing (`preprocess_frame`).
Writes ``resolution.png`` (rows: scenario x weather; columns: the reference, the configured
render, their difference x4) and ``resolution.json``:

- ``difference``: per (scenario, weather), the mean absolute grey-level difference per frame
  (mean and 95th percentile over frames) and the share of pixels off by more than 16 levels,
  beside the mean difference between consecutive reference frames (how much 1/15 s of driving
  changes the input) for scale;
- ``markings``: on the straight road, the grey-level contrast of the right edge line, the dashed
  centre line and the left edge line over the asphalt at 20 and 40 m ahead: mean, spread over
  frames (aliasing shows as flicker) and the share of frames in which a solid line is lost
  (contrast under a quarter of the reference's mean);
- ``sigma_seen``: the standard deviation of sensor noise on the network's input at each setting.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import cv2
import numpy as np

from uqdrive.files import atomic_path, write_json
from uqdrive.network_input import preprocess_frame
from uqdrive.sim.autopilot import Autopilot
from uqdrive.sim.condition import Condition
from uqdrive.sim.config import CameraConfig, ScenarioConfig, WeatherConfig
from uqdrive.sim.env import DrivingEnv

WEATHERS = ("clear_noon", "afternoon", "rain", "fog")
SCENARIOS = ("roundabout", "obstacle")
DISTANCES = (20.0, 40.0)
_ZOOM = 4


def render_at(
    env: DrivingEnv, pose: tuple[float, float, float], weather: WeatherConfig, noise: float, seed: int
) -> np.ndarray:
    """Network input (grey 64x48) of ``env``'s camera at ``pose``; rain and noise drawn from ``seed``."""
    x, y, yaw = pose
    env.scene.cull(*env.camera.view_wedge(x, y, yaw))
    streak_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    rgb = env.camera.render(x, y, yaw, weather, env.scene.road_lookup, streak_rng, noise, noise_rng)
    return preprocess_frame(rgb)


def autopilot_poses(
    env: DrivingEnv, scenario: ScenarioConfig, seeds: range, every: int
) -> list[tuple[float, float, float]]:
    """Every ``every``-th pose of unperturbed autopilot episodes, one per seed."""
    poses = []
    for seed in seeds:
        env.reset(seed, Condition(scenario, None), render=False)
        pilot = Autopilot(env.route, env.vehicle_config, control_hz=env.control_hz, seed=seed)
        info, step = env.last_info, 0
        while not info["done"]:
            if step % every == 0:
                poses.append((info["x"], info["y"], info["yaw"]))
            action = pilot.act(info)
            _, info = env.step(action.steer, action.speed)
            step += 1
    return poses


def project(env: DrivingEnv, pose: tuple[float, float, float], points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Pixel (column, row) in an image of ``size`` (width, height) of world points [n, 3], through the camera."""
    view = np.asarray(env.camera.view_matrix(*pose)).reshape(4, 4).T  # pybullet matrices are column-major
    proj = np.asarray(env.camera.projection).reshape(4, 4).T
    clip = (proj @ view @ np.column_stack([points, np.ones(len(points))]).T).T
    ndc = clip[:, :2] / clip[:, 3:4]
    return np.column_stack([(ndc[:, 0] + 1) / 2 * size[0], (1 - ndc[:, 1]) / 2 * size[1]])


def marking_contrast(frames: list[np.ndarray], env: DrivingEnv, poses, lines: dict[str, float]) -> dict:
    """Per line and distance, the contrast (grey levels) of the marking over the asphalt beside it, per frame.

    On the image row holding the point ``d`` metres ahead, the lines are projected at the distance
    that row's centre sees; the marking's pixel is the brightest of the three around its projection,
    the asphalt the pixel halfway to the lane centre.
    """
    ahead = np.linspace(5.0, 80.0, 1501)
    out: dict[str, dict[str, list[float]]] = {}
    for frame, pose in zip(frames, poses):
        h, w = frame.shape
        eye_x = env.camera.eye(*pose)[0]
        for name, lateral in lines.items():
            lane = lateral - math.copysign(1.75 / 2, lateral) if lateral else 1.75 / 2
            line_px = project(
                env, pose, np.column_stack([eye_x + ahead, np.full_like(ahead, lateral), 0 * ahead]), (w, h)
            )
            lane_px = project(env, pose, np.column_stack([eye_x + ahead, np.full_like(ahead, lane), 0 * ahead]), (w, h))
            for d in DISTANCES:
                r = int(line_px[np.argmin(np.abs(ahead - d)), 1])
                k = int(np.argmin(np.abs(line_px[:, 1] - (r + 0.5))))
                c, ca = int(line_px[k, 0]), int(lane_px[k, 0])
                if not (0 <= r < h and 1 <= c < w - 1 and 0 <= ca < w):
                    continue
                marking = frame[r, c - 1 : c + 2].max()
                out.setdefault(name, {}).setdefault(f"{d:g}m", []).append(float(marking) - float(frame[r, ca]))
    return out


def _summary(values: list[float], reference_mean: float) -> dict:
    v = np.asarray(values)
    return {
        "mean": round(float(v.mean()), 2),
        "std": round(float(v.std()), 2),
        "lost_fraction": round(float((v < 0.25 * reference_mean).mean()), 3),
        "frames": len(v),
    }


def frame_differences(conf: Path, envs: dict, seeds: range, every: int) -> tuple[dict, list]:
    """Per scenario × weather, how far the configured render is from the reference on the autopilot's poses; and
    one (reference, configured) frame pair per figure row."""
    differences, rows = {}, []
    for scenario_name in SCENARIOS:
        scenario = ScenarioConfig.from_yaml(conf / "scenario" / f"{scenario_name}.yaml")
        poses = autopilot_poses(envs["reference"], scenario, seeds, every)
        for env in envs.values():
            env.reset(seeds.start, Condition(scenario, None), render=False)
        for weather_name in WEATHERS:
            weather = WeatherConfig.from_yaml(conf / "weather" / f"{weather_name}.yaml")
            pairs = [[render_at(env, pose, weather, 0.0, k) for env in envs.values()] for k, pose in enumerate(poses)]
            ref = np.asarray([p[0] for p in pairs], float)
            diff = np.abs(np.asarray([p[1] for p in pairs], float) - ref)
            per_frame = diff.mean(axis=(1, 2))
            differences[f"{scenario_name}/{weather_name}"] = {
                "mean_abs": round(float(per_frame.mean()), 2),
                "p95_abs": round(float(np.percentile(per_frame, 95)), 2),
                "pixels_off_by_16": round(float((diff > 16).mean()), 4),
                "consecutive_reference_frames": round(float(np.abs(np.diff(ref, axis=0)).mean()), 2),
                "frames": len(pairs),
            }
            rows.append((f"{scenario_name} {weather_name}", *pairs[len(pairs) // 3]))
    return differences, rows


def marking_contrasts(conf: Path, envs: dict, seeds: range) -> dict:
    """Per weather, the contrast of the straight road's three lane markings at each size."""
    straight = ScenarioConfig.from_yaml(conf / "scenario" / "straight.yaml")
    poses = autopilot_poses(envs["reference"], straight, seeds, 1)
    half = straight.num_lanes * straight.lane_width / 2 - 0.15 - straight.marking_width / 2
    lines = {"right_edge": -half, "centre_dashed": 0.0, "left_edge": half}
    markings = {}
    for weather_name in WEATHERS:
        weather = WeatherConfig.from_yaml(conf / "weather" / f"{weather_name}.yaml")
        contrast = {}
        for key, env in envs.items():
            env.reset(seeds.start, Condition(straight, None), render=False)
            frames = [render_at(env, pose, weather, 0.0, k) for k, pose in enumerate(poses)]
            contrast[key] = marking_contrast(frames, envs["reference"], poses, lines)
        markings[weather_name] = {
            line: {
                d: {
                    key: _summary(contrast[key][line][d], float(np.mean(contrast["reference"][line][d])))
                    for key in envs
                }
                for d in contrast["reference"][line]
            }
            for line in lines
        }
    return markings


def noise_seen(conf: Path, envs: dict, seeds: range, every: int, noise: float) -> dict:
    """The sensor noise σ the network sees at each size (rain at the roundabout, as a share of full intensity)."""
    scenario = ScenarioConfig.from_yaml(conf / "scenario" / "roundabout.yaml")
    rain = WeatherConfig.from_yaml(conf / "weather" / "rain.yaml")
    poses = autopilot_poses(envs["reference"], scenario, range(seeds.start, seeds.start + 1), every)
    seen = {}
    for key, env in envs.items():
        env.reset(seeds.start, Condition(scenario, None), render=False)
        diffs = [
            render_at(env, p, rain, noise, k).astype(float) - render_at(env, p, rain, 0.0, k)
            for k, p in enumerate(poses)
        ]
        seen[key] = round(float(np.std(diffs)) / 255, 4)
    return {**seen, "configured_noise": noise}


def compare(conf: Path, reference: tuple[int, int], seeds: range, every: int, noise: float) -> tuple[dict, list]:
    """The numbers of ``resolution.json`` and one (reference, configured) frame pair per figure row."""
    camera = CameraConfig()
    sizes = {"reference": reference, "configured": (camera.width, camera.height)}
    envs = {k: DrivingEnv(dataclasses.replace(camera, width=w, height=h)) for k, (w, h) in sizes.items()}
    try:
        differences, rows = frame_differences(conf, envs, seeds, every)
        result = {
            "reference": "x".join(map(str, reference)),
            "configured": f"{camera.width}x{camera.height}",
            "seeds": [seeds.start, seeds.stop],
            "every_nth_step": every,
            "difference": differences,
            "markings": marking_contrasts(conf, envs, seeds),
            "sigma_seen": noise_seen(conf, envs, seeds, every, noise),
        }
    finally:
        for env in envs.values():
            env.close()
    return result, rows


def figure(rows: list[tuple[str, np.ndarray, np.ndarray]], labels: tuple[str, str]) -> np.ndarray:
    """Rows of [reference | configured | |difference| x4], enlarged, labelled; BGR uint8."""
    tiles = []
    for name, ref, new in rows:
        diff = np.clip(np.abs(new.astype(int) - ref.astype(int)) * 4, 0, 255).astype(np.uint8)
        row = cv2.cvtColor(np.hstack([ref, new, diff]), cv2.COLOR_GRAY2BGR)
        row = cv2.resize(row, None, fx=_ZOOM, fy=_ZOOM, interpolation=cv2.INTER_NEAREST)
        cv2.putText(row, name, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 0), 1, cv2.LINE_AA)
        tiles.append(row)
    header = np.zeros((22, tiles[0].shape[1], 3), np.uint8)
    w = tiles[0].shape[1] // 3
    for k, text in enumerate((*labels, "|difference| x4")):
        cv2.putText(header, text, (k * w + 4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return np.vstack([header, *tiles])


def write(out: Path, conf: Path, reference: tuple[int, int], seeds: range, every: int, noise: float) -> dict:
    result, rows = compare(conf, reference, seeds, every, noise)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "resolution.json", result)
    labels = (f"{result['reference']} rendered, reduced", f"{result['configured']} rendered")
    ok, png = cv2.imencode(".png", figure(rows, labels))
    if not ok:
        raise RuntimeError("PNG encoding failed")
    with atomic_path(out / "resolution.png") as tmp:
        tmp.write_bytes(png.tobytes())
    return result
