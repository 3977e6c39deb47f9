"""What the cameras saw, drawn: the one producer of annotated camera images (the operators'
page, the 3-D view's side panel; its marks are what image-annotation channels carry).

:func:`image_marks` collects, for one image of a stereo pair, the matched LEDs (their
centroids, px, and ids — a matched pair carries the same id and colour in both images, paper
§4's correspondence), the rejected candidates (blobs of a full-frame acquisition that are not
among the LEDs: gated out, unmatched or refused) and the tracker's windows where the frame has
them (x0, y0, x1, y1, px);
:func:`draw_marks` draws them with OpenCV on a copy of the image, downscaled to ``width`` px.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from app.model.pose import PoseResult
from app.types import Rect

Side = Literal["left", "right"]

# LED id → RGB colour (ids 1..5, then cycling): the same palette in the 3-D scene.
LED_COLORS_RGB: tuple[tuple[int, int, int], ...] = (
    (230, 60, 60),
    (240, 170, 40),
    (60, 200, 90),
    (50, 140, 240),
    (190, 80, 230),
)
WINDOW_RGB = (90, 170, 255)
REJECTED_RGB = (150, 150, 150)


def led_color(led_id: int) -> tuple[int, int, int]:
    """The RGB colour of LED ``led_id`` (1-based)."""
    return LED_COLORS_RGB[(int(led_id) - 1) % len(LED_COLORS_RGB)]


@dataclass(frozen=True)
class LedMark:
    """A matched LED's centroid in one image (px, full resolution) and its id."""

    led_id: int
    u_px: float
    v_px: float


@dataclass(frozen=True)
class ImageMarks:
    """Everything drawn on one camera image."""

    side: Side
    leds: tuple[LedMark, ...] = ()
    windows_px: tuple[Rect, ...] = ()
    rejected_px: tuple[tuple[float, float], ...] = ()  # candidates not among the LEDs
    lock: bool | None = None  # None: no lock banner
    reason: str | None = None

    @property
    def led_ids(self) -> list[int]:
        return [m.led_id for m in self.leds]


def image_marks(
    pose: PoseResult | None,
    side: Side,
    *,
    windows_px: list[Rect] | tuple[Rect, ...] | None = None,
    lock: bool | None = None,
) -> ImageMarks:
    """The marks of ``side`` for a pipeline result (``pose`` None: windows and banner only)."""
    leds: tuple[LedMark, ...] = ()
    rejected: tuple[tuple[float, float], ...] = ()
    if pose is not None:
        leds = tuple(
            LedMark(led.id, *(led.left_px if side == "left" else led.right_px)) for led in pose.leds
        )
        rejected = tuple(pose.rejected_left_px if side == "left" else pose.rejected_right_px)
    return ImageMarks(
        side=side,
        leds=leds,
        windows_px=tuple(tuple(int(c) for c in w) for w in (windows_px or ())),  # type: ignore[misc]
        rejected_px=rejected,
        lock=lock,
        reason=None if pose is None else pose.reason,
    )


def draw_marks(
    image: NDArray[np.generic], marks: ImageMarks, *, width: int = 320
) -> NDArray[np.uint8]:
    """An RGB uint8 copy of ``image`` (gray or BGR) ``width`` px wide with ``marks`` drawn: each
    LED circled and labelled with its id in its colour, each rejected candidate a grey cross,
    the tracker's windows outlined, and a
    LOCK / NO LOCK banner when ``marks.lock`` is set."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    h, w = img.shape[:2]
    scale = width / float(w)
    small = cv2.resize(img, (width, max(1, round(h * scale))), interpolation=cv2.INTER_AREA)
    code = cv2.COLOR_GRAY2RGB if small.ndim == 2 else cv2.COLOR_BGR2RGB
    rgb = cv2.cvtColor(small, code)
    rgb = cv2.convertScaleAbs(rgb, alpha=1.6, beta=10)  # the dark background brightened
    for x0, y0, x1, y1 in marks.windows_px:
        p0 = (int(round(x0 * scale)), int(round(y0 * scale)))
        p1 = (int(round(x1 * scale)), int(round(y1 * scale)))
        cv2.rectangle(rgb, p0, p1, WINDOW_RGB, 1, lineType=cv2.LINE_AA)
    for u, v in marks.rejected_px:  # a grey cross: seen, not an LED of the lock
        c = (int(round(u * scale)), int(round(v * scale)))
        cv2.drawMarker(rgb, c, REJECTED_RGB, cv2.MARKER_TILTED_CROSS, 9, 1, cv2.LINE_AA)
    for m in marks.leds:
        c = (int(round(m.u_px * scale)), int(round(m.v_px * scale)))
        color = led_color(m.led_id)
        cv2.circle(rgb, c, 7, color, 2, lineType=cv2.LINE_AA)
        cv2.putText(
            rgb,
            str(m.led_id),
            (c[0] + 8, c[1] - 6),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            color,
            1,
            cv2.LINE_AA,
        )
    if marks.lock is not None:
        label = "LOCK" if marks.lock else "NO LOCK"
        color = (60, 220, 90) if marks.lock else (240, 70, 70)
        cv2.putText(rgb, f"{marks.side} {label}", (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, color, 1)
    return np.asarray(rgb, dtype=np.uint8)


def annotate(
    image: NDArray[np.generic],
    pose: PoseResult | None,
    side: Side,
    *,
    lock: bool | None = None,
    windows_px: list[Rect] | tuple[Rect, ...] | None = None,
    width: int = 320,
) -> NDArray[np.uint8]:
    """:func:`draw_marks` of :func:`image_marks`: one call for a frame and its result."""
    return draw_marks(image, image_marks(pose, side, windows_px=windows_px, lock=lock), width=width)
