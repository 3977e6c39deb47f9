"""Draw detections on camera images (OpenCV), downscaled for the dashboard."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

# LED id → BGR/RGB colour (ids 1..5, then cycling): the same palette in the 3-D scene.
LED_COLORS_RGB: tuple[tuple[int, int, int], ...] = (
    (230, 60, 60),
    (240, 170, 40),
    (60, 200, 90),
    (50, 140, 240),
    (190, 80, 230),
)


def led_color(led_id: int) -> tuple[int, int, int]:
    return LED_COLORS_RGB[(int(led_id) - 1) % len(LED_COLORS_RGB)]


def draw_detections(
    image: np.ndarray,
    pose: Any,
    side: str,
    *,
    width: int = 320,
    lock: bool | None = None,
) -> np.ndarray:
    """Return an RGB uint8 image ``width`` px wide with each matched LED circled and labelled.

    ``pose`` is a :class:`~app.vision.result.PoseResult` (or None); ``side`` is ``"left"`` or
    ``"right"`` and picks ``left_px``/``right_px``.
    """
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    h, w = img.shape[:2]
    scale = width / float(w)
    small = cv2.resize(img, (width, max(1, round(h * scale))), interpolation=cv2.INTER_AREA)
    if small.ndim == 2:
        rgb = cv2.cvtColor(small, cv2.COLOR_GRAY2RGB)
    else:
        rgb = cv2.cvtColor(small, cv2.COLOR_BGR2RGB)
    # brighten the dark background so the overlays read well
    rgb = cv2.convertScaleAbs(rgb, alpha=1.6, beta=10)
    if pose is not None:
        key = "left_px" if side == "left" else "right_px"
        for led in pose.leds:
            u, v = getattr(led, key)
            c = (int(round(u * scale)), int(round(v * scale)))
            color = led_color(led.id)
            cv2.circle(rgb, c, 7, color, 2, lineType=cv2.LINE_AA)
            cv2.putText(
                rgb,
                str(led.id),
                (c[0] + 8, c[1] - 6),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.45,
                color,
                1,
                cv2.LINE_AA,
            )
    if lock is not None:
        label = "LOCK" if lock else "NO LOCK"
        color = (60, 220, 90) if lock else (240, 70, 70)
        cv2.putText(rgb, f"{side} {label}", (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, color, 1)
    return rgb
