"""Recording a run: JSONL telemetry + ``.viser`` scene (+ raw stereo frames on request);
listing and download.

Recordings a crash interrupted are recovered when the service starts (``status:
"interrupted"``): listed, telemetry downloadable; their scene file is lost (``scene_file: null``,
``scene_note`` says why) and its download answers 404 with that reason.

A failing disk never answers a plain-text 500: a start that cannot write answers 507 (full
disk, or a frame recording under ``AAR_RECORDING_MIN_FREE_MB``) or 503 (not writable) with the
reason; a recording whose writes fail stops as ``status: "failed"`` (``stop_reason`` says why)
and its telemetry stays downloadable.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Depends, HTTPException, Query, status
from fastapi.responses import FileResponse

from app.model.frames import RawFrame
from app.server.dependencies import StateDep, require_token
from app.server.schemas import Message
from app.service.recording import RecordingError, RecordingMeta
from app.service.recording.budget import RecordingProgress
from app.streams.frame_encoding import FrameCodec, FrameEncoding
from app.streams.processor import StreamTick

router = APIRouter(tags=["recording"])

CodecQuery = Annotated[
    FrameCodec,
    Query(
        description="the frames' codec: png-huffman (lossless, the default: the smallest and "
        "fastest lossless form of dark, noisy LED frames), png (lossless, deflate at "
        "png_level) or jpeg (LOSSY, at jpeg_quality: a replay is close, not identical)"
    ),
]
PngLevelQuery = Annotated[int, Query(ge=1, le=9, description="deflate level of codec=png")]
JpegQualityQuery = Annotated[int, Query(ge=1, le=100, description="quality of codec=jpeg")]


@router.get("/recording", response_model=RecordingProgress)
def recording_progress(
    state: StateDep,
    frames: Annotated[bool, Query(description="estimate a recording with frames")] = True,
    codec: CodecQuery = "png-huffman",
    png_level: PngLevelQuery = 1,
    jpeg_quality: JpegQualityQuery = 90,
) -> RecordingProgress:
    """The active recording's write rate (bytes/s over the recording, MB a minute) and the
    time left at that rate against its bounds (``max_s``, the frames' budget, the telemetry's
    size bound, the free space above ``AAR_RECORDING_MIN_FREE_MB``), and which bound comes
    first. With no recording active: an estimate of how long one with these options can run,
    from a frame of the current stream encoded with them (or the last measured pair size)."""
    encoding = FrameEncoding(codec, png_level, jpeg_quality) if frames else None
    return state.recorder.progress(encoding)


@router.post(
    "/recording/start",
    response_model=RecordingMeta,
    dependencies=[Depends(require_token)],
    responses={
        409: {"model": Message},
        503: {"model": Message, "description": "the recordings directory is not writable"},
        507: {"model": Message, "description": "no space (or under the free-space floor)"},
    },
)
def recording_start(
    state: StateDep,
    frames: Annotated[
        bool,
        Query(description="also record the raw stereo frames (images, times, calibration)"),
    ] = False,
    codec: CodecQuery = "png-huffman",
    png_level: PngLevelQuery = 1,
    jpeg_quality: JpegQualityQuery = 90,
) -> RecordingMeta:
    """Start a recording. With ``frames=true`` the stereo pairs are recorded too, and a
    camera stream's track restarts with a full-frame acquisition on the first recorded pair,
    so that ``aar-dock track --left <id>.frames`` replays it to the live results."""
    streams = getattr(state, "streams", None)
    calibrations = getattr(state, "calibrations", None)
    processor = None if streams is None else streams.processor
    accept = None
    if frames and processor is not None:
        first_epoch = processor.epoch + 1

        def accept(raw: RawFrame) -> bool:
            if not isinstance(raw, StreamTick) or raw.processor is not processor:
                return True  # the simulation, or a source switched to since: a fresh track
            return raw.track_epoch >= first_epoch

    try:
        info = state.recorder.start(
            frames=frames,
            calibration=None if calibrations is None else calibrations.current,
            accept_frame=accept,
            source=None if streams is None else streams.spec,
            drogue=None if streams is None else streams.drogue_in_use(),
            encoding=FrameEncoding(codec, png_level, jpeg_quality),
        )
    except RecordingError as exc:
        raise HTTPException(exc.status, exc.detail) from None
    if processor is not None and frames:
        processor.request_reset()
    return info


@router.post(
    "/recording/stop",
    response_model=RecordingMeta,
    dependencies=[Depends(require_token)],
    responses={409: {"model": Message}},
)
def recording_stop(state: StateDep) -> RecordingMeta:
    info = state.recorder.stop()
    if info is None:
        raise HTTPException(status.HTTP_409_CONFLICT, "no active recording")
    return info


@router.get("/recordings", response_model=list[RecordingMeta])
def recordings(state: StateDep) -> list[RecordingMeta]:
    return state.recorder.list()


@router.get(
    "/recordings/{rec_id}", response_model=RecordingMeta, responses={404: {"model": Message}}
)
def recording(rec_id: str, state: StateDep) -> RecordingMeta:
    info = state.recorder.get(rec_id)
    if info is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, f"no recording {rec_id!r}")
    return info


def _download(
    state: StateDep, rec_id: str, kind: Literal["telemetry", "scene", "mcap"], media_type: str
) -> FileResponse:
    """One of a recording's files (``kind`` as :meth:`Recorder.locate` names it), or 404."""
    path, why = state.recorder.locate(rec_id, kind)
    if path is None:
        raise HTTPException(status.HTTP_404_NOT_FOUND, why)
    return FileResponse(path, media_type=media_type, filename=path.name)


@router.get("/recordings/{rec_id}/telemetry.jsonl", responses={404: {"model": Message}})
def recording_telemetry(rec_id: str, state: StateDep) -> FileResponse:
    return _download(state, rec_id, "telemetry", "application/x-ndjson")


@router.get("/recordings/{rec_id}/scene.viser", responses={404: {"model": Message}})
def recording_scene(rec_id: str, state: StateDep) -> FileResponse:
    """The ``.viser`` file; replay it at ``/viser-client/?playbackPath=<this URL>``."""
    return _download(state, rec_id, "scene", "application/octet-stream")


@router.get("/recordings/{rec_id}/recording.mcap", responses={404: {"model": Message}})
def recording_mcap(rec_id: str, state: StateDep) -> FileResponse:
    """The recording's MCAP log: open it in Foxglove (docs/ecosystem.md)."""
    return _download(state, rec_id, "mcap", "application/octet-stream")
