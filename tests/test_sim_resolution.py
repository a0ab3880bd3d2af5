"""The render-size comparison behind docs/frames/resolution.{png,json} (`uqdrive frames --compare-render`)."""

import math
from pathlib import Path

import numpy as np
import pytest

from uqdrive.sim import CameraConfig, DrivingEnv, ScenarioConfig, WeatherConfig
from uqdrive.sim.condition import Condition
from uqdrive.tools.frame_gallery import main as frames_main
from uqdrive.tools.resolution import marking_contrast, project, render_at

CONF = Path(__file__).resolve().parents[1] / "conf"
STRAIGHT = ScenarioConfig.from_yaml(CONF / "scenario" / "straight.yaml")


@pytest.fixture(scope="module")
def env():
    with DrivingEnv(CameraConfig(width=160, height=120)) as e:
        e.reset(0, Condition(STRAIGHT, None), render=False)
        yield e


def test_projection_puts_the_horizon_where_the_pitch_says(env):
    cam = env.camera.config
    pose = (10.0, -1.75, 0.0)
    eye = env.camera.eye(*pose)
    far_ahead = np.array([[eye[0] + 1e4, eye[1], eye[2]]])
    col, row = project(env, pose, far_ahead, (160, 120))[0]
    f = 60 / math.tan(math.radians(env.camera.fov_y) / 2)
    assert col == pytest.approx(80, abs=0.05)
    assert row == pytest.approx(60 - f * math.tan(math.radians(-cam.pitch_deg)), abs=0.1)


def test_solid_edge_lines_are_found_at_20_and_40_metres(env):
    clear = WeatherConfig.from_yaml(CONF / "weather" / "clear_noon.yaml")
    poses = [(15.0 + 3 * k, -1.75, 0.0) for k in range(5)]
    frames = [render_at(env, pose, clear, 0.0, k) for k, pose in enumerate(poses)]
    half = STRAIGHT.num_lanes * STRAIGHT.lane_width / 2 - 0.15 - STRAIGHT.marking_width / 2
    contrast = marking_contrast(frames, env, poses, {"right_edge": -half, "left_edge": half})
    for line in ("right_edge", "left_edge"):
        for d in ("20m", "40m"):
            assert len(contrast[line][d]) == 5 and min(contrast[line][d]) > 10, (line, d, contrast[line][d])


def test_compare_render_rejects_a_bad_size(capsys):
    with pytest.raises(SystemExit):
        frames_main(["--compare-render", "160by120"])
    assert "must be WIDTHxHEIGHT" in capsys.readouterr().err
