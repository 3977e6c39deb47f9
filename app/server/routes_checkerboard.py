"""``POST /calibration/checkerboard``: stereo calibration from uploaded checkerboard pairs.

Mounted by the service under ``/api/v1``. Multipart form: ``left`` and ``right`` (one file per
image, repeated; pair k = k-th left file + k-th right file, in upload order), ``board``
(inner corners, e.g. ``9x6``), ``square_mm``, optional ``model`` (``paper`` | ``full``),
``estimate_skew``, ``max_rms_px`` and ``include_png``. Returns ``{"calibration": ..., "report": ...}`` (and
``report_png_base64`` on request). The calibration is *not* activated here: send it to
``PUT /api/v1/calibration`` to switch to it.

Errors: 400 for files that are not decodable images; 422 for a set that cannot be calibrated
(left/right counts differ, image sizes differ, board not found, fewer than 6 usable views).
"""

from __future__ import annotations

import asyncio
import base64
from typing import Annotated, Any, Literal

import cv2
import numpy as np
from fastapi import APIRouter, File, Form, HTTPException, UploadFile

from app.geometry.calibration import CalibrationError
from app.geometry.checkerboard import (
    Board,
    CheckerboardError,
    calibrate_checkerboard,
    pair_name,
    parse_board,
    report_png_bytes,
)

router = APIRouter(tags=["calibration"])

MAX_PAIRS = 100
MAX_FILE_BYTES = 32 * 1024 * 1024


def _decode(data: bytes, label: str) -> np.ndarray:
    if not data:
        raise HTTPException(status_code=400, detail=f"{label} is empty")
    img = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise HTTPException(
            status_code=400, detail=f"{label} is not a decodable image (PNG, JPEG, ...)"
        )
    return np.asarray(img, dtype=np.uint8)


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
) -> dict[str, Any]:
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
    )
    payload: dict[str, Any] = {
        "calibration": result.calibration.to_dict(),
        "report": result.report.to_dict(),
    }
    if include_png:
        k = result.used[0]
        png = report_png_bytes(result, lefts[k], rights[k])
        payload["report_png_base64"] = base64.b64encode(png).decode("ascii")
    return payload


@router.post("/calibration/checkerboard")
async def calibrate_from_checkerboard(
    left: Annotated[list[UploadFile], File(description="left images, one per pair, in pair order")],
    right: Annotated[
        list[UploadFile], File(description="right images, one per pair, in pair order")
    ],
    board: Annotated[str, Form(description="inner corners per row x per column, e.g. 9x6")] = "9x6",
    square_mm: Annotated[float, Form(gt=0, description="square side (mm)")] = 25.0,
    model: Annotated[
        Literal["paper", "full"], Form(description="paper: k1,k2; full: 5 terms")
    ] = "paper",
    max_rms_px: Annotated[float, Form(gt=0, description="warn above this stereo RMS (px)")] = 0.5,
    include_png: Annotated[bool, Form(description="add the report PNG (base64)")] = False,
    estimate_skew: Annotated[
        bool, Form(description="also estimate the skew γ (OpenCV alone writes γ = 0)")
    ] = False,
) -> dict[str, Any]:
    """Calibrate the stereo rig from checkerboard pairs (Zhang's method, OpenCV); skew γ = 0."""
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
        )
    except (CheckerboardError, CalibrationError) as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
