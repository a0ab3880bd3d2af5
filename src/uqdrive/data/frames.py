"""Camera frame → network input. Shared by the `preprocess` stage and the live closed-loop controller,
so that what the network sees on the road is exactly what it was trained on."""

from __future__ import annotations

import cv2
import numpy as np

from uqdrive import INPUT_HEIGHT, INPUT_WIDTH


def preprocess_frame(rgb: np.ndarray, height: int = INPUT_HEIGHT, width: int = INPUT_WIDTH) -> np.ndarray:
    """RGB uint8 [H, W, 3] → grayscale uint8 [height, width] (area interpolation, no aliasing)."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an RGB uint8 image [H, W, 3], got dtype={rgb.dtype} shape={rgb.shape}")
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return cv2.resize(gray, (width, height), interpolation=cv2.INTER_AREA)


def encode_png(image: np.ndarray) -> bytes:
    """Lossless and ~5x smaller than raw pixels, so raw episodes stay small on disk."""
    ok, buf = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def decode_png(data: bytes) -> np.ndarray:
    """Inverse of `encode_png`: RGB [H, W, 3] or grayscale [H, W], uint8."""
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError("not a PNG image")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB) if image.ndim == 3 else image
