"""``GET``/``PUT /calibration`` and rollback.

A new calibration is validated for form (``StereoCalibration.from_dict``), unknown fields and
physical plausibility (``app.calibration.plausibility``) before anything uses it; a refused
one is dropped (nothing keeps a reference to it).
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Body, Depends, HTTPException, status
from fastapi.responses import JSONResponse

from app.calibration.plausibility import validated
from app.geometry.calibration import CalibrationError
from app.server.dependencies import StateDep, require_token
from app.types import JsonObject

router = APIRouter(prefix="/calibration", tags=["calibration"])


@router.get("")
def get_calibration(state: StateDep) -> JsonObject:
    """The active calibration in the project's JSON format (mm, ``X_right = R·X_left + T``)."""
    return state.calibrations.current.to_dict()


@router.put(
    "",
    dependencies=[Depends(require_token)],
    responses={
        422: {
            "description": "invalid or implausible calibration; `field` names the offending entry"
        }
    },
)
def put_calibration(data: Annotated[JsonObject, Body()], state: StateDep) -> object:
    """Replace the calibration (the previous one is kept for ``POST /calibration/rollback``).

    Refused (422, ``field`` named) unless plausible: fx, fy in [50, 1e5] px, principal point
    inside the image, |skew| < 0.1·fx, |T| in [1, 10000] mm, distortion terms within ±10 and
    monotonic over the image, image size ≤ ``AAR_MAX_CALIBRATION_PIXELS``; unknown fields too.
    """
    try:
        calib = validated(data, state.settings.max_calibration_pixels)
    except CalibrationError as exc:
        return JSONResponse(
            status_code=422,
            content={"detail": str(exc), "field": exc.field},
        )
    try:
        state.apply_calibration(calib)
    except (ValueError, TypeError) as exc:  # the simulation refused it: the old one stays
        return JSONResponse(
            status_code=422, content={"detail": f"calibration rejected: {exc}", "field": "<root>"}
        )
    state.calibrations.replace(calib)
    return calib.to_dict()


@router.post("/rollback", dependencies=[Depends(require_token)])
def rollback_calibration(state: StateDep) -> JsonObject:
    """Swap back to the previous calibration (409 if there is none)."""
    calib = state.calibrations.rollback()
    if calib is None:
        raise HTTPException(status.HTTP_409_CONFLICT, "no previous calibration to roll back to")
    state.apply_calibration(calib)
    return calib.to_dict()
