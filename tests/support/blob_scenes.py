"""Blob scenes drawn with OpenCV alone (independent of the project renderer)."""

from __future__ import annotations

import cv2
import numpy as np


def blob_scene(seed: int, n: int, size: tuple[int, int] = (1024, 1280)) -> np.ndarray:
    """Noisy background with ``n`` blurred discs of random size and brightness (OpenCV drawing,
    independent of the project's renderer), some touching each other or the image border."""
    rng = np.random.default_rng(seed)
    h, w = size
    img = np.zeros(size, np.float32)
    for _ in range(n):
        r = int(rng.integers(1, 14))
        x = int(rng.integers(-r, w + r))
        y = int(rng.integers(-r, h + r))
        cv2.circle(img, (x, y), r, float(rng.uniform(80, 255)), -1, lineType=cv2.LINE_AA)
        if rng.random() < 0.3:  # a neighbour within the centroid margin
            cv2.circle(img, (x + 2 * r + 2, y + 1), max(1, r // 2), 200.0, -1)
    img = cv2.GaussianBlur(img, (0, 0), 1.2)
    img += rng.normal(14.0, 3.0, size)
    return np.clip(img, 0, 255).astype(np.uint8)
