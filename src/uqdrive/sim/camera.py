"""Front camera: TinyRenderer image plus weather and sensor noise in image space.

pybullet lighting (direction, colour, ambient/diffuse/specular, shadows) gives the sun;
sky, wet road, fog, tint, blur and rain streaks are image-space effects driven by the
depth and segmentation buffers, so every weather costs one render. Blur and rain are given
at 160x120 and scaled to the render size, so they mean the same at any resolution.

Every frame is delivered at the network's 64x48, whatever the render size: a larger render is
area-reduced after the weather and before the sensor noise, so that σ is the noise on the
network's input at any render size (rendering larger only buys anti-aliasing).
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from uqdrive.network_input import INPUT_HEIGHT, INPUT_WIDTH

from .bullet import pybullet as p
from .config import CameraConfig, WeatherConfig

_REF_WIDTH, _REF_HEIGHT = 160, 120  # blur and rain sizes are given at this resolution
_RAIN_GREY = 0.85  # what a streak shows where it covers a pixel fully
_RAIN_LEVELS = 5


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
        self._look: WeatherLook | None = None
        # the ground projection of the view is the wedge of the widest corner ray (pitch tilts the sides)
        tan_v = math.tan(math.radians(self.fov_y) / 2)
        level = math.cos(math.radians(config.pitch_deg)) - tan_v * abs(math.sin(math.radians(config.pitch_deg)))
        self.half_angle = math.atan2(math.tan(math.radians(config.fov_deg) / 2), level) if level > 0 else math.pi

    def eye(self, x: float, y: float, yaw: float) -> list[float]:
        cfg = self.config
        return [x + cfg.mount_forward * math.cos(yaw), y + cfg.mount_forward * math.sin(yaw), cfg.mount_height]

    def view_wedge(self, x: float, y: float, yaw: float) -> tuple[float, float, float, float]:
        """(apex x, apex y, yaw, half-angle): every ray of the camera projects onto the ground inside it."""
        eye = self.eye(x, y, yaw)
        return eye[0], eye[1], yaw, self.half_angle

    def view_matrix(self, x: float, y: float, yaw: float):
        cfg = self.config
        eye = self.eye(x, y, yaw)
        pitch = math.radians(cfg.pitch_deg)
        fwd = [math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)]
        return self.client.computeViewMatrix(eye, [eye[i] + fwd[i] for i in range(3)], [0, 0, 1])

    def render(
        self,
        x: float,
        y: float,
        yaw: float,
        weather: WeatherConfig,
        road_lookup: np.ndarray,
        streak_rng: np.random.Generator,
        noise: float,
        noise_rng: np.random.Generator,
    ) -> np.ndarray:
        """RGB uint8 [48, 64, 3] seen from the body-centre pose (x, y, yaw); ``road_lookup[body id + 1]``
        says which bodies are road (`World.road_lookup`). ``last_depth`` keeps the render's size."""
        cfg = self.config
        look = self._look_of(weather)
        _, _, rgba, depth_buf, seg = self.client.getCameraImage(
            cfg.width,
            cfg.height,
            self.view_matrix(x, y, yaw),
            self.projection,
            renderer=p.ER_TINY_RENDERER,
            lightDirection=look.light_direction,
            lightColor=look.light_color,
            lightAmbientCoeff=weather.ambient,
            lightDiffuseCoeff=weather.diffuse,
            lightSpecularCoeff=weather.specular,
            shadow=int(weather.shadow),
        )
        rgba = np.asarray(rgba, np.uint8).reshape(cfg.height, cfg.width, 4)
        depth_buf = np.asarray(depth_buf, np.float32).reshape(cfg.height, cfg.width)
        seg = np.asarray(seg, np.int32).reshape(cfg.height, cfg.width)
        img = cv2.cvtColor(rgba, cv2.COLOR_RGBA2RGB).astype(np.float32)  # 5x faster than slicing off alpha
        img *= np.float32(1 / 255)
        sky = seg < 0
        near, far = cfg.near, cfg.far
        depth = far * near / (far - (far - near) * depth_buf)
        np.copyto(depth, np.float32(np.inf), where=sky)
        self.last_depth = depth
        img = apply_weather(img, depth, sky, road_lookup.take(seg + 1), look, streak_rng)
        if img.shape[:2] != (INPUT_HEIGHT, INPUT_WIDTH):
            img = cv2.resize(img, (INPUT_WIDTH, INPUT_HEIGHT), interpolation=cv2.INTER_AREA)
        return add_noise(img, noise, noise_rng)

    def _look_of(self, weather: WeatherConfig) -> WeatherLook:
        if self._look is None or (self._look.weather is not weather and self._look.weather != weather):
            self._look = WeatherLook.of(weather, self._sky_t, self.config.width)
        return self._look


@dataclasses.dataclass(frozen=True)
class WeatherLook:
    """What a weather does to every frame of one camera, worked out once as whole images: this runs
    on every frame, and numpy broadcasting over a last axis of 3 is ~10x slower than a whole-image
    operation (the bare render is the budget it is measured against: `uqdrive bench sim`)."""

    weather: WeatherConfig
    light_direction: list[float]
    light_color: list[float]
    sky: np.ndarray  # gradient from sky_top (image top) to sky_horizon (horizon row)
    wet_sheen: np.ndarray  # wet asphalt reflects the horizon, more at grazing angles (far away)
    fog_color: np.ndarray
    rain_color: np.ndarray
    gain: np.ndarray  # tint x brightness x contrast
    offset: np.float32  # contrast pulls towards mid-grey
    blur_sigma: float  # pixels at this width

    @classmethod
    def of(cls, weather: WeatherConfig, sky_t: np.ndarray, width: int) -> WeatherLook:
        light = np.asarray(weather.light_direction, float)
        shape = (len(sky_t), width, 3)

        def image(rgb) -> np.ndarray:
            return np.ascontiguousarray(np.broadcast_to(np.asarray(rgb, np.float32), shape))

        top, horizon = np.asarray(weather.sky_top, np.float32), np.asarray(weather.sky_horizon, np.float32)
        return cls(
            weather,
            (light / np.linalg.norm(light)).tolist(),
            list(weather.light_color),
            image(top * (1 - sky_t) + horizon * sky_t),
            image(weather.road_sheen * horizon),
            image(weather.fog_color),
            image((_RAIN_GREY,) * 3),
            image(np.asarray(weather.tint) * (weather.brightness * weather.contrast)),
            np.float32(0.5 * (1 - weather.contrast)),
            weather.blur * width / _REF_WIDTH,
        )


def _planes3(plane: np.ndarray) -> np.ndarray:
    """[H, W] -> [H, W, 3], the same plane in every channel."""
    return cv2.merge((plane, plane, plane))


def apply_weather(
    img: np.ndarray,
    depth: np.ndarray,
    sky: np.ndarray,
    road: np.ndarray,
    look: WeatherLook,
    streak_rng: np.random.Generator,
) -> np.ndarray:
    """Image-space weather on a float32 image in [0, 1] (modified in place); returns float32 in [0, 1]."""
    weather = look.weather
    cv2.copyTo(look.sky, sky.view(np.uint8), img)
    if weather.road_darkening != 1.0 or weather.road_sheen > 0:
        grazing = np.exp(depth / np.float32(-25.0))
        np.subtract(1.0, grazing, out=grazing)
        wet = _planes3(grazing)
        wet *= look.wet_sheen
        wet += img * np.float32(weather.road_darkening)
        cv2.copyTo(wet, road.view(np.uint8), img)
    if weather.fog_density > 0:  # depth is inf on the sky, so the sky turns fully to fog colour
        keep = np.exp(depth * np.float32(-weather.fog_density))
        img = cv2.blendLinear(img, look.fog_color, keep, 1 - keep)
    img *= look.gain
    img += look.offset
    if look.blur_sigma > 0:
        img = cv2.GaussianBlur(img, (0, 0), look.blur_sigma)
    if weather.rain_streaks > 0:
        img = cv2.blendLinear(img, look.rain_color, *_rain_cover(img.shape[:2], weather, streak_rng))
    return np.clip(img, 0.0, 1.0, out=img)


def _rain_cover(
    shape: tuple[int, int], weather: WeatherConfig, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Blend weights (of the image, of the rain) of seeded, slanted, semi-transparent streaks; a fresh
    pattern every frame.

    Drawn at the 160x120 the config's sizes are given at, then area-averaged to the render size:
    a streak thinner than a pixel there covers a share of it, so the rain covers the same share
    of the view, as faintly, at every resolution. Opacity comes in `_RAIN_LEVELS` steps so that
    all streaks of one step are one `cv2.polylines` call (a streak overwrites, never adds).
    """
    h, w = shape
    u = rng.random((weather.rain_streaks, 5))
    x0, y0 = u[:, 0] * _REF_WIDTH, u[:, 1] * _REF_HEIGHT
    reach = weather.rain_length * (0.5 + u[:, 2])
    angle = np.radians(weather.rain_angle_deg + 8.0 * u[:, 3] - 4.0)
    ends = np.array([x0, y0, x0 + np.sin(angle) * reach, y0 + np.cos(angle) * reach]).astype(np.int32)
    ends = ends.T.reshape(-1, 2, 2)  # np.array, not np.stack: this runs every frame, and np.stack is Python
    level = (u[:, 4] * _RAIN_LEVELS).astype(int)
    ends = ends[np.argsort(level, kind="stable")]  # by opacity step: each step's streaks are one slice
    cover = np.zeros((_REF_HEIGHT, _REF_WIDTH), np.float32)
    start = 0
    for k, count in enumerate(np.bincount(level, minlength=_RAIN_LEVELS).tolist()):
        if count:
            lines = ends[start : start + count]
            cv2.polylines(cover, lines, False, weather.rain_intensity * (0.5 + 0.5 * (k + 0.5) / _RAIN_LEVELS))
        start += count
    if (h, w) != cover.shape:
        cover = cv2.resize(cover, (w, h), interpolation=cv2.INTER_AREA)
    return 1 - cover, cover


def add_noise(img: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian luminance noise, sigma in units of full intensity; float [0, 1] RGB -> uint8.

    One normal per pixel of the delivered 64x48 frame, added to R, G and B alike: the grey value
    the network is fed (weights summing to 1) gets exactly sigma, at any render size, before
    clipping to [0, 1] and 8-bit rounding.
    OpenCV draws the normals (3x faster than numpy: this runs on every frame), its generator
    re-seeded from ``rng`` each frame, so the noise stays a function of the episode seed alone.
    """
    if sigma > 0:
        noise = np.empty(img.shape[:2], np.float32)
        cv2.setRNGSeed(int(rng.integers(2**31)))
        cv2.randn(noise, 0.0, float(sigma))
        img = img + _planes3(noise)
    # 255 img rounded to nearest (as np.rint) and saturated at 0 and 255 in one call: OpenCV's Python API has no
    # convertTo (convertScaleAbs takes |x|, so it needed a floor first), so the second term has weight 0
    return cv2.addWeighted(img, 255.0, img, 0.0, 0.0, dtype=cv2.CV_8U)
