"""``POST /stereo``: run the navigation pipeline on an uploaded stereo pair.

Before anything is decoded, both images' headers are read (``app.service.image_guard``): not a
PNG/JPEG/BMP/TIFF → 400, more than ``AAR_MAX_IMAGE_PIXELS`` → 413, sizes that differ or do not
match the calibration → 422. Decoding and the pipeline then run, by one path, in the
:class:`~app.service.upload_pool.UploadPool` (``process_upload``: worker processes, off the web
server's GIL; tests may inject another executor); never on the event loop. Token, request size
and concurrency are checked earlier, on the headers (``app.server.security``).

The dashboard shows an upload's images: they are decoded again here, lazily (when the 3-D scene
reads them) and for at most ``AAR_IMAGE_HZ`` uploads a second; the others are published
without images (the scene keeps the last ones).
"""

from __future__ import annotations

import logging
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, File, Form, HTTPException, UploadFile, status

from app.geometry.calibration import StereoCalibration
from app.model.pose import PoseResult
from app.server.dependencies import StateDep, require_token
from app.server.schemas import Message
from app.service import records
from app.service.image_guard import ImageHeader, ImageRefused, check
from app.service.lazy_images import ImagePair, LazyImagePair
from app.service.records import RawFrame
from app.service.sim_worker.wire import calibration_to_wire
from app.service.state import AppState
from app.service.upload_pool import (
    UploadError,
    UploadWorkerCrashed,
    check_pair_sizes,
    decode_upload_image,
    process_upload,
)

log = logging.getLogger(__name__)
router = APIRouter(tags=["stereo"])


class LazyUploadFrames(LazyImagePair):
    """An upload's images, decoded on first access (the 3-D scene, at its image rate)."""

    def __init__(self, left: bytes, right: bytes) -> None:
        super().__init__()
        self._bytes: tuple[bytes, bytes] | None = (left, right)

    def _load(self) -> ImagePair:
        assert self._bytes is not None
        try:
            images: ImagePair = (
                decode_upload_image(self._bytes[0], "left"),
                decode_upload_image(self._bytes[1], "right"),
            )
        except UploadError:  # pragma: no cover - the worker decoded them already
            images = (None, None)
        self._bytes = None
        return images


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


def screen(data: bytes, name: str, *, max_pixels: int) -> ImageHeader:
    """:func:`check` for a route: ``HTTPException`` with the status and the reason."""
    try:
        return check(data, name, max_pixels=max_pixels)
    except ImageRefused as exc:
        raise HTTPException(exc.status, exc.detail) from None


def _check_sizes(lh: ImageHeader, rh: ImageHeader, expected: tuple[int, int] | None) -> None:
    try:
        check_pair_sizes((lh.width, lh.height), (rh.width, rh.height), expected)
    except UploadError as exc:
        raise HTTPException(exc.status, exc.detail) from None


async def _in_upload_pool(
    state: AppState,
    left_bytes: bytes,
    right_bytes: bytes,
    matcher: str,
    calibration: StereoCalibration,
) -> tuple[PoseResult, RawFrame | None]:
    """Decode and pipeline in a worker of the :class:`UploadPool` (the one path)."""
    try:
        out = await state.upload_pool.run(
            process_upload,
            left_bytes,
            right_bytes,
            calibration_to_wire(calibration),
            matcher,
            calibration.image_size,
            state.uploads.drogue.to_dict(),
        )
    except UploadWorkerCrashed as exc:
        log.error("upload worker crashed: %s", exc)
        raise HTTPException(
            status.HTTP_503_SERVICE_UNAVAILABLE,
            "the upload worker crashed; retry",
            headers={"Retry-After": str(state.settings.retry_after_s)},
        ) from None
    if out.status != 200 or out.result is None:
        if out.traceback:
            log.error("pipeline failed on an upload (worker process):\n%s", out.traceback)
        raise HTTPException(out.status, out.detail)
    result = out.result
    raw: RawFrame | None = None
    if state.uploads.images_due(1.0 / state.settings.image_hz):
        raw = LazyUploadFrames(left_bytes, right_bytes)
    return result, raw


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
        503: {"model": Message, "description": "the upload worker process crashed (retry)"},
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
    calibration = state.uploads.calibration  # one calibration for the whole request
    _check_sizes(lh, rh, calibration.image_size)
    result, raw = await _in_upload_pool(state, left_bytes, right_bytes, matcher, calibration)
    del left_bytes, right_bytes
    state.uploads.count += 1
    # an upload is not on the loop's schedule: its timings stay out of the stage statistics
    state.bus.publish(records.from_upload(result, raw), run=state.loop.run, stages=False)
    return result
