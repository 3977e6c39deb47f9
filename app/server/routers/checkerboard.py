"""``POST /calibration/checkerboard``: stereo calibration from uploaded checkerboard pairs.

Mounted by the service under ``/api/v1``. Multipart form: ``left`` and ``right`` (one file per
image, repeated; pair k = k-th left file + k-th right file, in upload order), ``board``
(inner corners, e.g. ``9x6``), ``square_mm``, optional ``model`` (``paper`` | ``full``),
``estimate_skew``, ``max_rms_px``, ``drop_outliers`` and ``include_png``. Returns
``{"calibration": ..., "report": ...}`` (and ``report_png_base64`` on request). The report
is that of ``aar-dock calibrate`` (app.calibration.report): per-view errors with the
held-out residual, ``rejected`` (board missing, or left/right grids not the same corners),
``dropped`` (reprojection outliers, robust z-score rule), ``coverage``, ``held_out``,
``detectors`` and the warnings. The calibration is *not* activated here: send it to
``PUT /api/v1/calibration`` to switch to it.

Errors: 401 without the bearer token (when ``AAR_TOKEN`` is set); 400 for files that are not
decodable images (the header is read first: PNG/JPEG/BMP/TIFF only); 413 for a file over
32 MB, an image over ``AAR_MAX_IMAGE_PIXELS`` / ``AAR_MAX_CALIBRATION_PIXELS`` or a set over
``AAR_MAX_CHECKERBOARD_MPX`` (all refused on the headers, before decoding); 422 for a set that
cannot be calibrated (left/right counts differ, image sizes differ, board not found, fewer than
6 usable views). Decoding and calibration run in a worker thread. In the service, the request
guard (``app.server.security``) also bounds the body (``AAR_MAX_CHECKERBOARD_MB``) and runs
at most ``AAR_MAX_CONCURRENT_CALIBRATIONS`` at once (else 429).
"""

from __future__ import annotations

import asyncio
import base64
from typing import Annotated, Literal

import numpy as np
from fastapi import APIRouter, Depends, File, Form, HTTPException, Request, UploadFile

from app.calibration.board import Board, CheckerboardError, pair_name, parse_board
from app.calibration.report_plot import report_png_bytes
from app.calibration.stereo_calibration import calibrate_checkerboard
from app.geometry.calibration import CalibrationError
from app.server.dependencies import request_settings, require_token
from app.service.image_guard import (
    AmbiguousHeaderError,
    ImageHeader,
    ImageHeaderError,
    peek_header,
)
from app.types import JsonObject
from app.vision.io import decode_image
from app.vision.preprocess import ImageError

router = APIRouter(tags=["calibration"])

MAX_PAIRS = 100
MAX_FILE_BYTES = 32 * 1024 * 1024
BOARD_CORNERS = (2, 64)  # inner corners per row / per column


def _not_an_image(label: str) -> HTTPException:
    return HTTPException(
        status_code=400, detail=f"{label} is not a decodable image (PNG, JPEG, ...)"
    )


def _screen(data: bytes, label: str, max_pixels: int) -> ImageHeader:
    """The header (no decoding): 400 if empty or not PNG/JPEG/BMP/TIFF, 413 if too large."""
    if not data:
        raise HTTPException(status_code=400, detail=f"{label} is empty")
    try:
        header = peek_header(data)
    except AmbiguousHeaderError as exc:
        raise HTTPException(
            status_code=422,
            detail=f"{label}: ambiguous image header ({exc}); refused before decoding",
        ) from None
    except ImageHeaderError:
        raise _not_an_image(label) from None
    if header.pixels > max_pixels:
        raise HTTPException(
            status_code=413,
            detail=f"{label} is {header.width}x{header.height} px "
            f"({header.pixels / 1e6:.4g} Mpx), over the limit of {max_pixels / 1e6:.4g} Mpx "
            "(AAR_MAX_IMAGE_PIXELS / AAR_MAX_CALIBRATION_PIXELS); refused before decoding",
        )
    return header


def _check_set(
    names: list[str],
    lefts: list[ImageHeader],
    rights: list[ImageHeader],
    max_total_mpx: float,
) -> None:
    """Same size everywhere (the message of ``check_image_sizes``) and a bounded total."""
    ref = (lefts[0].width, lefts[0].height)
    for name, lh, rh in zip(names, lefts, rights, strict=True):
        for side, h in (("left", lh), ("right", rh)):
            if (h.width, h.height) != ref:
                raise HTTPException(
                    status_code=422,
                    detail=f"image sizes differ: {side} image of pair {name} is "
                    f"{h.width}x{h.height} px, the first left image is {ref[0]}x{ref[1]} px",
                )
    total = sum(h.pixels for h in lefts) + sum(h.pixels for h in rights)
    if total > max_total_mpx * 1e6:
        raise HTTPException(
            status_code=413,
            detail=f"the set has {total / 1e6:.4g} Mpx in all, over the limit of "
            f"{max_total_mpx:g} Mpx (AAR_MAX_CHECKERBOARD_MPX)",
        )


def _decode(data: bytes, label: str) -> np.ndarray:
    if not data:
        raise HTTPException(status_code=400, detail=f"{label} is empty")
    try:  # the package's one decoder; corner detection greys a colour board itself
        return decode_image(data, label)
    except ImageError:
        raise HTTPException(
            status_code=400, detail=f"{label} is not a decodable image (PNG, JPEG, ...)"
        ) from None


def _calibrate(
    names: list[str],
    left_bytes: list[bytes],
    right_bytes: list[bytes],
    left_labels: list[str],
    right_labels: list[str],
    board: Board,
    model: str,
    max_rms_px: float,
    include_png: bool,
    estimate_skew: bool,
    drop_outliers: bool,
) -> JsonObject:
    lefts = [_decode(b, lab) for b, lab in zip(left_bytes, left_labels, strict=True)]
    rights = [_decode(b, lab) for b, lab in zip(right_bytes, right_labels, strict=True)]
    result = calibrate_checkerboard(
        names,
        lefts,
        rights,
        board,
        model=model,
        max_stereo_rms_px=max_rms_px,
        estimate_skew=estimate_skew,
        drop_outliers=drop_outliers,
    )
    payload: JsonObject = {
        "calibration": result.calibration.to_dict(),
        "report": result.report.to_dict(),
    }
    if include_png:
        k = result.used[0]
        png = report_png_bytes(result, lefts[k], rights[k])
        payload["report_png_base64"] = base64.b64encode(png).decode("ascii")
    return payload


@router.post(
    "/calibration/checkerboard",
    dependencies=[Depends(require_token)],
    responses={
        400: {"description": "a file is not a decodable PNG/JPEG/BMP/TIFF image"},
        401: {"description": "missing or wrong bearer token"},
        413: {"description": "a file, an image or the set is too large"},
        422: {"description": "the set cannot be calibrated"},
        429: {"description": "AAR_MAX_CONCURRENT_CALIBRATIONS already running"},
    },
)
async def calibrate_from_checkerboard(
    request: Request,
    left: Annotated[list[UploadFile], File(description="left images, one per pair, in pair order")],
    right: Annotated[
        list[UploadFile], File(description="right images, one per pair, in pair order")
    ],
    board: Annotated[str, Form(description="inner corners per row x per column, e.g. 9x6")] = "9x6",
    square_mm: Annotated[
        float, Form(gt=0, le=1000, allow_inf_nan=False, description="square side (mm)")
    ] = 25.0,
    model: Annotated[
        Literal["paper", "full"], Form(description="paper: k1,k2; full: 5 terms")
    ] = "paper",
    max_rms_px: Annotated[
        float,
        Form(gt=0, le=100, allow_inf_nan=False, description="warn above this stereo RMS (px)"),
    ] = 0.5,
    include_png: Annotated[bool, Form(description="add the report PNG (base64)")] = False,
    estimate_skew: Annotated[
        bool, Form(description="also estimate the skew γ (OpenCV alone writes γ = 0)")
    ] = False,
    drop_outliers: Annotated[
        bool, Form(description="drop reprojection-outlier views (robust z-score rule)")
    ] = True,
) -> JsonObject:
    """Calibrate the stereo rig from checkerboard pairs (Zhang's method, OpenCV)."""
    if len(left) != len(right):
        raise HTTPException(
            status_code=422,
            detail=f"{len(left)} left images but {len(right)} right images: send one right image per left image",
        )
    if len(left) > MAX_PAIRS:
        raise HTTPException(
            status_code=422, detail=f"too many pairs ({len(left)}), at most {MAX_PAIRS}"
        )
    try:
        cols, rows = parse_board(board)
        board_spec = Board(cols, rows, float(square_mm))
    except CheckerboardError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    lo, hi = BOARD_CORNERS
    if not (lo <= cols <= hi and lo <= rows <= hi):
        raise HTTPException(
            status_code=422,
            detail=f"board {board!r}: inner corners per side must be in [{lo}, {hi}]",
        )
    settings = request_settings(request)
    max_pixels = min(settings.max_image_pixels, settings.max_calibration_pixels)
    left_bytes: list[bytes] = []
    right_bytes: list[bytes] = []
    for files, dest in ((left, left_bytes), (right, right_bytes)):
        for f in files:
            data = await f.read(MAX_FILE_BYTES + 1)
            if len(data) > MAX_FILE_BYTES:
                raise HTTPException(
                    status_code=413, detail=f"{f.filename} is larger than {MAX_FILE_BYTES} bytes"
                )
            dest.append(data)
    left_labels = [f"left image #{k} ({f.filename})" for k, f in enumerate(left)]
    right_labels = [f"right image #{k} ({f.filename})" for k, f in enumerate(right)]
    names = [
        pair_name(lf.filename or f"left_{k:02d}", rf.filename or f"right_{k:02d}")
        for k, (lf, rf) in enumerate(zip(left, right, strict=True))
    ]
    left_headers = [
        _screen(b, lab, max_pixels) for b, lab in zip(left_bytes, left_labels, strict=True)
    ]
    right_headers = [
        _screen(b, lab, max_pixels) for b, lab in zip(right_bytes, right_labels, strict=True)
    ]
    if left_headers:
        _check_set(names, left_headers, right_headers, settings.max_checkerboard_mpx)
    try:
        return await asyncio.to_thread(
            _calibrate,
            names,
            left_bytes,
            right_bytes,
            left_labels,
            right_labels,
            board_spec,
            model,
            max_rms_px,
            include_png,
            estimate_skew,
            drop_outliers,
        )
    except (CheckerboardError, CalibrationError) as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
