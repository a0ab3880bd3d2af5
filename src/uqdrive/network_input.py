"""Camera frame → network input: the grey 64x48 frame (the paper's). One home for the sim (which delivers frames at
this size, and its Gymnasium env as observations), the data pipeline (which stores them) and the live controller,
so that what the network sees on the road is exactly what it was trained on."""

from __future__ import annotations

import cv2
import numpy as np

INPUT_HEIGHT, INPUT_WIDTH = 48, 64


def preprocess_frame(rgb: np.ndarray, height: int = INPUT_HEIGHT, width: int = INPUT_WIDTH) -> np.ndarray:
    """RGB uint8 [H, W, 3] → grayscale uint8 [height, width] (area interpolation, no aliasing)."""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an RGB uint8 image [H, W, 3], got dtype={rgb.dtype} shape={rgb.shape}")
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return cv2.resize(gray, (width, height), interpolation=cv2.INTER_AREA)
