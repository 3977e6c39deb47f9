"""A recording's metadata (``<id>.json``, :class:`RecordingMeta`: also the API's answer), its
status, the error a start that cannot proceed raises (:class:`RecordingError`: 409, 503, or 507
for a full disk) and writing the metadata file atomically."""

from __future__ import annotations

import errno
import re
from pathlib import Path
from typing import Literal

from pydantic import BaseModel

from app.service.recording.disk import write_atomic

ID_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
SCENE_LOST_NOTE = "lost in a crash; telemetry complete"
INTERRUPTED_REASON = "interrupted: the server ended without stopping the recording (crash/kill)"

RecordingStatus = Literal["recording", "complete", "interrupted", "failed"]
NO_SPACE = frozenset({errno.ENOSPC, errno.EDQUOT})


class RecordingError(RuntimeError):
    """A recording that cannot start: HTTP status (409, 503, 507) and the reason."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail


def storage_error(what: str, exc: OSError) -> RecordingError:
    """507 for a full disk (or quota), 503 for any other write error, with the reason."""
    code = 507 if exc.errno in NO_SPACE else 503
    return RecordingError(code, f"{what}: {exc.strerror or exc} (AAR_RECORDINGS_DIR)")


class RecordingInfo(BaseModel):
    """A recording as the API lists it (times: wall clock, s since the epoch; sizes: bytes)."""

    id: str
    started_wall: float
    stopped_wall: float | None = None
    ticks: int = 0
    active: bool = False
    telemetry_file: str
    scene_file: str | None = None
    telemetry_bytes: int = 0
    scene_bytes: int = 0
    stop_reason: str | None = None


class RecordingMeta(RecordingInfo):
    """The metadata file and the API's answer (``RecordingInfo`` plus the crash-safety fields)."""

    status: RecordingStatus = "complete"  # files written before these fields were clean stops
    max_s: float | None = None
    max_mb: float | None = None
    last_record_wall: float | None = None  # ``wall_time`` of the last record on disk
    scene_note: str | None = None  # why there is no scene file, when there is none
    recovered_wall: float | None = None  # when an interrupted recording was recovered
    recovery_note: str | None = None
    frames_dir: str | None = None  # raw stereo frames (app.streams.frame_log), if recorded
    frames_encoding: str | None = None  # the frames' codec (app.streams.frame_encoding)
    frame_pairs: int = 0
    frames_bytes: int = 0
    frames_dropped: int = 0  # pairs the frame writer could not keep up with
    mcap_file: str | None = None  # the MCAP log of the run (docs/ecosystem.md)
    mcap_bytes: int = 0
    mcap_note: str | None = None  # why the MCAP log is missing or was rebuilt


def meta_path(directory: Path, rec_id: str) -> Path:
    """Where recording ``rec_id``'s metadata lives in ``directory``."""
    return directory / f"{rec_id}.json"


def write_meta(directory: Path, info: RecordingMeta) -> None:
    """Replace a recording's metadata file atomically (temp file + ``os.replace``)."""
    write_atomic(meta_path(directory, info.id), info.model_dump_json(indent=2).encode())
