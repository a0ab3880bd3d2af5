"""Synthetic road frames for tests and benchmarks that must run without collected data.

Shaped like the real data: 48x64 gray frames with sky, grass and a road whose vanishing point moves with the
steering label, 45% of frames "straight ahead" (the majority class, as in the collected data), noise and per-frame
brightness and horizon jitter, so a network learns them much as it learns the pybullet frames.
"""

from __future__ import annotations

import numpy as np


def synthetic_road_frames(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """uint8 frames [n, 48, 64] and steering [n] (positive = left: the road bends, and its vanishing point
    moves, left)."""
    steer = np.where(rng.random(n) < 0.45, 0.0, rng.choice(np.arange(-6, 7) / 10, n))
    yy, xx = np.mgrid[0:48, 0:64].astype(np.float32)
    horizon = 16 + rng.integers(-2, 3, n)[:, None, None]
    vanish = 32 - 40 * steer[:, None, None]
    t = np.clip((yy - horizon) / (47 - horizon), 0, 1)
    road = (np.abs(xx - (vanish + (32 - vanish) * t)) < 2 + 28 * t) & (yy > horizon)
    image = np.where(yy <= horizon, 180.0, np.where(road, 100.0, 60.0))
    image = image + rng.normal(0, 8, image.shape) + rng.integers(-20, 21, n)[:, None, None]
    return np.clip(image, 0, 255).astype(np.uint8), steer.astype(np.float32)
