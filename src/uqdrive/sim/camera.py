"""Front camera: TinyRenderer image plus weather and sensor noise in image space.

pybullet lighting (direction, colour, ambient/diffuse/specular, shadows) gives the sun;
sky, wet road, fog, tint, blur and rain streaks are image-space effects driven by the
depth and segmentation buffers, so every weather costs one render.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from .bullet import pybullet as p

from .config import CameraConfig, WeatherConfig

_REF_WIDTH, _REF_HEIGHT = 160, 120  # blur and rain sizes are given at this resolution


class Camera:
    """Renders what a windscreen camera sees; ``fov_deg`` is the horizontal field of view."""

    def __init__(self, client, config: CameraConfig):
        self.client = client
        self.config = config
        aspect = config.width / config.height
        self.fov_y = math.degrees(2 * math.atan(math.tan(math.radians(config.fov_deg) / 2) / aspect))
        self.projection = client.computeProjectionMatrixFOV(self.fov_y, aspect, config.near, config.far)
        f = (config.height / 2) / math.tan(math.radians(self.fov_y) / 2)
        horizon = config.height / 2 + f * math.tan(math.radians(config.pitch_deg))
        rows = np.arange(config.height, dtype=np.float32)
        self._sky_t = np.clip(rows / max(horizon, 1.0), 0.0, 1.0)[:, None, None]
        self.last_depth: np.ndarray | None = None  # metres along the view axis, inf for sky

    def view_matrix(self, x: float, y: float, yaw: float):
        cfg = self.config
        eye = [x + cfg.mount_forward * math.cos(yaw), y + cfg.mount_forward * math.sin(yaw), cfg.mount_height]
        pitch = math.radians(cfg.pitch_deg)
        fwd = [math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)]
        return self.client.computeViewMatrix(eye, [eye[i] + fwd[i] for i in range(3)], [0, 0, 1])

    def render(self, x: float, y: float, yaw: float, weather: WeatherConfig, road_ids, streak_rng: np.random.Generator,
               noise: float, noise_rng: np.random.Generator) -> np.ndarray:
        """RGB uint8 [H, W, 3] seen from the body-centre pose (x, y, yaw)."""
        cfg = self.config
        light = np.asarray(weather.light_direction, float)
        _, _, rgba, depth_buf, seg = self.client.getCameraImage(
            cfg.width, cfg.height, self.view_matrix(x, y, yaw), self.projection, renderer=p.ER_TINY_RENDERER,
            lightDirection=(light / np.linalg.norm(light)).tolist(), lightColor=list(weather.light_color),
            lightAmbientCoeff=weather.ambient, lightDiffuseCoeff=weather.diffuse,
            lightSpecularCoeff=weather.specular, shadow=int(weather.shadow))
        rgba = np.asarray(rgba, np.uint8).reshape(cfg.height, cfg.width, 4)
        depth_buf = np.asarray(depth_buf, np.float32).reshape(cfg.height, cfg.width)
        seg = np.asarray(seg, np.int32).reshape(cfg.height, cfg.width)
        img = rgba[..., :3].astype(np.float32) / 255.0
        sky = seg < 0
        near, far = cfg.near, cfg.far
        depth = far * near / (far - (far - near) * depth_buf)
        depth[sky] = np.inf
        self.last_depth = depth
        img = apply_weather(img, depth, sky, np.isin(seg, road_ids), weather, self._sky_t, streak_rng)
        return add_noise(img, noise, noise_rng)


def apply_weather(img: np.ndarray, depth: np.ndarray, sky: np.ndarray, road: np.ndarray, weather: WeatherConfig,
                  sky_t: np.ndarray, streak_rng: np.random.Generator) -> np.ndarray:
    """Image-space weather on a float32 image in [0, 1] (modified in place); returns float32 in [0, 1].

    In-place and masked operations: this runs on every rendered frame, and the bare render is
    the budget it is measured against (`uqdrive bench sim`).
    """
    h, w = img.shape[:2]
    top, horizon = np.asarray(weather.sky_top, np.float32), np.asarray(weather.sky_horizon, np.float32)
    gradient = top * (1 - sky_t) + horizon * sky_t
    np.copyto(img, np.broadcast_to(gradient, img.shape), where=sky[..., None])
    if weather.road_darkening != 1.0 or weather.road_sheen > 0:
        # wet asphalt: darker, and reflects the horizon more at grazing angles (far away)
        grazing = 1.0 - np.exp(depth[road] / -25.0)
        img[road] = img[road] * weather.road_darkening + weather.road_sheen * grazing[:, None] * horizon
    if weather.fog_density > 0:  # depth is inf on the sky, so the sky turns fully to fog colour
        keep = np.exp(-weather.fog_density * depth)[..., None]
        img *= keep
        img += np.asarray(weather.fog_color, np.float32) * (1 - keep)
    img *= np.asarray(weather.tint, np.float32) * (weather.brightness * weather.contrast)
    img += 0.5 * (1 - weather.contrast)
    if weather.blur > 0:
        img = cv2.GaussianBlur(img, (0, 0), weather.blur * w / _REF_WIDTH)
    if weather.rain_streaks > 0:
        img = _rain(img, weather, streak_rng)
    return np.clip(img, 0.0, 1.0, out=img)


def _rain(img: np.ndarray, weather: WeatherConfig, rng: np.random.Generator) -> np.ndarray:
    """Seeded, slanted, semi-transparent streaks; a fresh pattern every frame."""
    h, w = img.shape[:2]
    scale = w / _REF_WIDTH
    n = int(round(weather.rain_streaks * (w * h) / (_REF_WIDTH * _REF_HEIGHT)))
    xy = rng.uniform([0, 0], [w, h], size=(n, 2))
    length = weather.rain_length * scale * rng.uniform(0.5, 1.5, size=n)
    angle = np.radians(weather.rain_angle_deg + rng.uniform(-4, 4, size=n))
    end = xy + np.stack([np.sin(angle), np.cos(angle)], axis=1) * length[:, None]
    alpha = weather.rain_intensity * rng.uniform(0.5, 1.0, size=n)
    overlay = np.zeros((h, w), np.float32)
    thickness = max(1, int(round(scale)))
    for (x0, y0), (x1, y1), a in zip(xy, end, alpha):
        cv2.line(overlay, (int(x0), int(y0)), (int(x1), int(y1)), float(a), thickness, cv2.LINE_AA)
    overlay = np.clip(overlay, 0, 1)[..., None]
    return img * (1 - overlay) + 0.85 * overlay


def add_noise(img: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian pixel noise, sigma in units of full intensity; float [0, 1] RGB -> uint8.

    OpenCV draws the normals (3x faster than numpy: this runs on every frame), its generator
    re-seeded from ``rng`` each frame, so the noise stays a function of the episode seed alone.
    """
    if sigma > 0:
        noise = np.empty_like(img)
        cv2.setRNGSeed(int(rng.integers(2**31)))
        cv2.randn(noise, (0.0,) * img.shape[2], (float(sigma),) * img.shape[2])  # per channel: a scalar fills only the first
        img = img + noise
    img = np.clip(img, 0.0, 1.0) * 255.0
    return np.rint(img, out=img).astype(np.uint8)
