"""``POST /stereo``: run the navigation pipeline on an uploaded stereo pair.

Before anything is decoded, both images' headers are read (``app.server.image_guard``): not a
PNG/JPEG/BMP/TIFF → 400, more than ``AAR_MAX_IMAGE_PIXELS`` → 413, sizes that differ or do not
match the calibration → 422. Decoding and the pipeline run in worker threads, never on the
event loop. Token, request size and concurrency are checked earlier, on the headers
(``app.server.security``).
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass
from typing import Annotated, Literal

import cv2
import numpy as np
from fastapi import APIRouter, Depends, File, Form, HTTPException, UploadFile, status

from app.server.dependencies import StateDep, require_token
from app.server.image_guard import ImageHeader, screen
from app.server.schemas import Message, TickRecord
from app.vision.result import PoseResult

log = logging.getLogger(__name__)
router = APIRouter(tags=["stereo"])


@dataclass
class UploadFrames:
    """The raw side of an upload record (what the 3-D scene shows)."""

    left_image: np.ndarray
    right_image: np.ndarray


async def _read_limited(upload: UploadFile, limit: int, name: str) -> bytes:
    chunks: list[bytes] = []
    total = 0
    while True:
        chunk = await upload.read(1 << 20)
        if not chunk:
            break
        total += len(chunk)
        if total > limit:
            raise HTTPException(
                413,
                f"{name}: upload exceeds {limit / 1e6:g} MB (AAR_MAX_UPLOAD_MB)",
            )
        chunks.append(chunk)
    return b"".join(chunks)


def decode_image(data: bytes, name: str) -> np.ndarray:
    """Bytes (PNG/JPEG/BMP/TIFF) → uint8 grey image; ``HTTPException(400)`` if not an image."""
    if not data:
        raise HTTPException(status.HTTP_400_BAD_REQUEST, f"{name}: empty file")
    try:
        img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        img = None
    if img is None or img.size == 0:
        raise HTTPException(
            status.HTTP_400_BAD_REQUEST,
            f"{name}: could not decode the image (corrupt, or not PNG/JPEG/BMP/TIFF)",
        )
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise HTTPException(
            status.HTTP_400_BAD_REQUEST, f"{name}: unsupported pixel type {img.dtype} (8 or 16 bit)"
        )
    if img.ndim == 3:
        code = {4: cv2.COLOR_BGRA2GRAY, 3: cv2.COLOR_BGR2GRAY}.get(img.shape[2])
        if code is None:
            img = img[:, :, 0]
        else:
            img = cv2.cvtColor(img, code)
    return np.ascontiguousarray(img)


def _decode_pair(left: bytes, right: bytes) -> tuple[np.ndarray, np.ndarray]:
    return decode_image(left, "left"), decode_image(right, "right")


def _shape_header(img: np.ndarray) -> ImageHeader:
    return ImageHeader("decoded", img.shape[1], img.shape[0], 1, 8)


def _check_sizes(lh: ImageHeader, rh: ImageHeader, expected: tuple[int, int] | None) -> None:
    if (lh.width, lh.height) != (rh.width, rh.height):
        raise HTTPException(
            422,
            f"left and right sizes differ: {lh.width}x{lh.height} vs {rh.width}x{rh.height}",
        )
    if expected is not None and (lh.width, lh.height) != tuple(expected):
        w, h = expected
        raise HTTPException(
            422,
            f"image size {lh.width}x{lh.height} does not match the calibration ({w}x{h})",
        )


@router.post(
    "/stereo",
    response_model=PoseResult,
    responses={
        400: {"model": Message, "description": "undecodable image"},
        401: {"model": Message},
        403: {"model": Message, "description": "cross-origin request"},
        413: {
            "model": Message,
            "description": "upload larger than AAR_MAX_UPLOAD_MB, or more pixels than "
            "AAR_MAX_IMAGE_PIXELS (refused on the header)",
        },
        422: {"model": Message, "description": "sizes differ or do not match the calibration"},
        429: {"model": Message, "description": "AAR_MAX_CONCURRENT_UPLOADS already running"},
    },
    dependencies=[Depends(require_token)],
)
async def post_stereo(
    left: Annotated[UploadFile, File(description="left image (PNG/JPEG/BMP/TIFF)")],
    right: Annotated[UploadFile, File(description="right image (PNG/JPEG/BMP/TIFF)")],
    state: StateDep,
    matcher: Annotated[Literal["epipolar", "paper"], Form()] = "epipolar",
) -> PoseResult:
    """Detect, match and triangulate the LEDs of one pair; returns the PoseResult contract.

    The pair and its result are also published to the dashboard (telemetry + 3-D scene).
    """
    settings = state.settings
    limit = int(settings.max_upload_mb * 1e6)
    left_bytes = await _read_limited(left, limit, "left")
    right_bytes = await _read_limited(right, limit, "right")
    lh = screen(left_bytes, "left", max_pixels=settings.max_image_pixels)
    rh = screen(right_bytes, "right", max_pixels=settings.max_image_pixels)
    expected = state.uploads.calibration.image_size
    _check_sizes(lh, rh, expected)
    left_img, right_img = await asyncio.to_thread(_decode_pair, left_bytes, right_bytes)
    del left_bytes, right_bytes
    _check_sizes(_shape_header(left_img), _shape_header(right_img), expected)  # as decoded
    pipeline = state.uploads.pipeline(matcher)
    try:
        result: PoseResult = await asyncio.to_thread(pipeline.process, left_img, right_img)
    except Exception as exc:  # the contract is a 4xx with a detail, never a 500
        log.exception("pipeline failed on an upload")
        raise HTTPException(422, f"pipeline failed: {type(exc).__name__}: {exc}") from None
    state.uploads.count += 1
    loop = state.loop
    record = TickRecord(
        seq=loop.next_seq(),
        source="upload",
        t_s=0.0,
        clock_s=loop.clock.now(),
        wall_time=time.time(),
        run=loop.run,
        pose=result,
        lock=result.lock,
        lock_reason=result.reason,
        timings_ms={k: float(v) for k, v in result.timing_ms.model_dump().items()},
    )
    loop.publish(record, UploadFrames(left_img, right_img))
    return result
