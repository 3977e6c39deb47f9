"""``/camera/{side}.jpg``: the cameras' latest images with the detections drawn."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, HTTPException, Query, status
from fastapi.responses import Response

from app.server.dependencies import StateDep
from app.server.schemas import Message

router = APIRouter(tags=["camera"])


@router.get(
    "/camera/{side}.jpg",
    response_class=Response,
    responses={
        200: {"content": {"image/jpeg": {}}, "description": "the annotated image"},
        404: {"model": Message},
    },
)
def camera_image(
    side: Literal["left", "right"],
    state: StateDep,
    source: Annotated[
        Literal["live", "upload"],
        Query(description="live: the running stream (simulated or camera); upload: the last pair"),
    ] = "live",
) -> Response:
    """The newest image of ``side`` (downscaled JPEG) with each matched LED circled and
    labelled with its id, each rejected candidate a grey cross, the tracker's windows where the
    frame has them and the lock banner. Headers: ``X-Seq`` (the telemetry record it belongs
    to), ``X-Led-Ids`` (ids drawn), ``X-Lock`` (1/0), ``X-Rejected`` (crosses drawn)."""
    img = state.camera_view.image(source, side)
    if img is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no {source} {side} image yet")
    return Response(
        content=img.jpeg,
        media_type="image/jpeg",
        headers={
            "Cache-Control": "no-store",
            "X-Seq": str(img.seq),
            "X-Led-Ids": ",".join(str(i) for i in img.led_ids),
            "X-Lock": "1" if img.lock else "0",
            "X-Rejected": str(img.rejected),
        },
    )
