"""Recording a run: JSONL telemetry + ``.viser`` scene; listing and download."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException, status
from fastapi.responses import FileResponse

from app.server.dependencies import StateDep, require_token
from app.server.schemas import Message, RecordingInfo

router = APIRouter(tags=["recording"])


@router.post(
    "/recording/start",
    response_model=RecordingInfo,
    dependencies=[Depends(require_token)],
    responses={409: {"model": Message}},
)
def recording_start(state: StateDep) -> RecordingInfo:
    try:
        return state.recorder.start()
    except RuntimeError as exc:
        raise HTTPException(status.HTTP_409_CONFLICT, str(exc)) from None


@router.post(
    "/recording/stop",
    response_model=RecordingInfo,
    dependencies=[Depends(require_token)],
    responses={409: {"model": Message}},
)
def recording_stop(state: StateDep) -> RecordingInfo:
    info = state.recorder.stop()
    if info is None:
        raise HTTPException(status.HTTP_409_CONFLICT, "no active recording")
    return info


@router.get("/recordings", response_model=list[RecordingInfo])
def recordings(state: StateDep) -> list[RecordingInfo]:
    return state.recorder.list()


@router.get(
    "/recordings/{rec_id}", response_model=RecordingInfo, responses={404: {"model": Message}}
)
def recording(rec_id: str, state: StateDep) -> RecordingInfo:
    info = state.recorder.get(rec_id)
    if info is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no recording {rec_id!r}")
    return info


@router.get("/recordings/{rec_id}/telemetry.jsonl", responses={404: {"model": Message}})
def recording_telemetry(rec_id: str, state: StateDep) -> FileResponse:
    path = state.recorder.file_path(rec_id, "telemetry")
    if path is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no finished recording {rec_id!r}")
    return FileResponse(path, media_type="application/x-ndjson", filename=path.name)


@router.get("/recordings/{rec_id}/scene.viser", responses={404: {"model": Message}})
def recording_scene(rec_id: str, state: StateDep) -> FileResponse:
    """The ``.viser`` file; replay it at ``/viser-client/?playbackPath=<this URL>``."""
    path = state.recorder.file_path(rec_id, "scene")
    if path is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no scene file for {rec_id!r}")
    return FileResponse(path, media_type="application/octet-stream", filename=path.name)
