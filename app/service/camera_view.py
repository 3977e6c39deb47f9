"""The cameras' latest images with their detections drawn, for the operators' page.

A tick-loop subscriber keeps, at most ``image_hz`` times a second, the newest navigation record
with images (the simulated stream or a camera/video/pushed stream: ``live``), and the newest
upload (``upload``). A simulated tick from the worker process holds its images in a
shared-memory ring whose slots are soon reused, so a kept tick's images are read at once (one
copy of the pair, the same read the 3-D view makes; nothing is encoded on the tick thread). A
request encodes the image of one side as JPEG with :func:`app.streams.annotations.draw_marks`
(the drawing the 3-D view uses too), once per record and side (cached), so any number of
viewers cost one encoding per image.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Literal

import cv2

from app.model.frames import RawFrame
from app.model.tick import TickRecord
from app.streams.annotations import Side, draw_marks, image_marks

Kind = Literal["live", "upload"]


@dataclass(frozen=True)
class CameraImage:
    """One annotated camera image (JPEG) and what is drawn on it."""

    seq: int
    side: Side
    jpeg: bytes
    led_ids: tuple[int, ...]
    lock: bool
    windows: int
    rejected: int  # candidates drawn as rejected (grey crosses)


class CameraView:
    """Latest annotated images per kind (``live`` / ``upload``) and side."""

    def __init__(self, width_px: int = 480, jpeg_quality: int = 85, image_hz: float = 5.0) -> None:
        self.width_px = width_px
        self.jpeg_quality = jpeg_quality
        self.period_s = 1.0 / image_hz
        self._kept_at = -1e9
        self._lock = threading.Lock()
        self._latest: dict[Kind, tuple[TickRecord, RawFrame]] = {}
        self._encoded: dict[tuple[Kind, Side], CameraImage] = {}
        self.encoded_count = 0

    def on_tick(self, record: TickRecord, raw: RawFrame | None = None) -> None:
        if raw is None:
            return
        kind: Kind = "upload" if record.source == "upload" else "live"
        if kind == "live":
            now = time.monotonic()
            if now - self._kept_at < self.period_s:
                return
            if raw.left_image is None:  # read now: the slot is soon reused
                return
            self._kept_at = now
        with self._lock:
            self._latest[kind] = (record, raw)

    def image(self, kind: Kind, side: Side) -> CameraImage | None:
        """The newest annotated image of ``side`` (None: none yet)."""
        with self._lock:
            latest = self._latest.get(kind)
            cached = self._encoded.get((kind, side))
        if latest is None:
            return cached
        record, raw = latest
        if cached is not None and cached.seq == record.seq:
            return cached
        img = raw.left_image if side == "left" else raw.right_image
        if img is None:  # overwritten before it was read (or none this tick)
            return cached
        windows = raw.image_windows_px
        marks = image_marks(
            record.pose,
            side,
            windows_px=None if windows is None else windows[side == "right"],
            lock=record.lock,
        )
        rgb = draw_marks(img, marks, width=self.width_px)
        ok, buf = cv2.imencode(
            ".jpg",
            cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
            [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality],
        )
        if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
            return cached
        out = CameraImage(
            seq=record.seq,
            side=side,
            jpeg=buf.tobytes(),
            led_ids=tuple(marks.led_ids),
            lock=bool(record.lock),
            windows=len(marks.windows_px),
            rejected=len(marks.rejected_px),
        )
        with self._lock:
            self._encoded[(kind, side)] = out
            self.encoded_count += 1
        return out
