"""``GET``/``PUT /calibration`` (validated with ``StereoCalibration.from_dict``) and rollback."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Body, Depends, HTTPException, status
from fastapi.responses import JSONResponse

from app.geometry.calibration import CalibrationError, StereoCalibration
from app.server.dependencies import StateDep, require_token

router = APIRouter(prefix="/calibration", tags=["calibration"])


@router.get("")
def get_calibration(state: StateDep) -> dict[str, Any]:
    """The active calibration in the project's JSON format (mm, ``X_right = R·X_left + T``)."""
    return state.calibrations.current.to_dict()


@router.put(
    "",
    dependencies=[Depends(require_token)],
    responses={422: {"description": "invalid calibration; `field` names the offending entry"}},
)
def put_calibration(data: Annotated[dict[str, Any], Body()], state: StateDep) -> Any:
    """Replace the calibration (the previous one is kept for ``POST /calibration/rollback``)."""
    try:
        calib = StereoCalibration.from_dict(data)
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
def rollback_calibration(state: StateDep) -> dict[str, Any]:
    """Swap back to the previous calibration (409 if there is none)."""
    calib = state.calibrations.rollback()
    if calib is None:
        raise HTTPException(status.HTTP_409_CONFLICT, "no previous calibration to roll back to")
    state.apply_calibration(calib)
    return calib.to_dict()
