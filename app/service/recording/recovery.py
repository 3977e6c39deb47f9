"""Recovering the recordings a crash left behind: metadata still ``recording`` with no live
owner (no ``flock`` held on its JSONL), or a JSONL without metadata. The torn last line is
dropped, the records counted, an MCAP log cut by the crash rebuilt from the telemetry and the
frames, and ``status="interrupted"`` metadata written — so they are listed and downloadable."""

from __future__ import annotations

import json
import logging
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from app.service.recording.disk import try_lock, wall_time
from app.service.recording.meta import (
    ID_RE,
    INTERRUPTED_REASON,
    SCENE_LOST_NOTE,
    RecordingMeta,
    meta_path,
    write_meta,
)

if TYPE_CHECKING:
    from app.model.mount import CameraMount

log = logging.getLogger(__name__)


def recover_recordings(
    directory: Path, live_id: str | None, mount: Callable[[], CameraMount]
) -> list[RecordingMeta]:
    """Mark the recordings a crash left behind in ``directory`` as ``interrupted`` (never
    ``live_id``, this process's own); returns them. ``mount``: the rig mount the /tf of a
    rebuilt MCAP log uses."""
    if not directory.is_dir():
        return []
    out: list[RecordingMeta] = []
    for tele in sorted(directory.glob("rec-*.jsonl")):
        rec_id = tele.stem
        if not ID_RE.match(rec_id) or rec_id == live_id:
            continue
        meta_file = meta_path(directory, rec_id)
        prior: RecordingMeta | None = None
        if meta_file.is_file():
            try:
                prior = RecordingMeta.model_validate_json(meta_file.read_bytes())
            except Exception:
                log.warning("unreadable recording metadata %s: rebuilding it", meta_file)
            if prior is not None and prior.status != "recording":
                continue
        try:
            rec = _recover_one(directory, tele, prior, mount)
        except Exception:
            log.exception("could not recover recording %s", rec_id)
            continue
        if rec is not None:
            log.warning("recovered interrupted recording %s: %d records", rec.id, rec.ticks)
            out.append(rec)
    return out


def _recover_one(
    directory: Path, tele: Path, prior: RecordingMeta | None, mount: Callable[[], CameraMount]
) -> RecordingMeta | None:
    """One interrupted recording (its JSONL ``tele`` locked while its metadata is written);
    None when it is live in another process."""
    rec_id = tele.stem
    with tele.open("r+b") as fh:
        if not try_lock(fh):
            return None  # live in another process
        count, good, first, last = 0, 0, None, None
        for line in fh:
            if not line.endswith(b"\n"):
                break  # torn last record
            try:
                json.loads(line)
            except ValueError:
                break  # garbage tail (e.g. a power loss before the fsync)
            count += 1
            good += len(line)
            if first is None:
                first = line
            last = line
        size = fh.seek(0, os.SEEK_END)
        notes: list[str] = []
        if size > good:
            fh.truncate(good)
            fh.flush()
            os.fsync(fh.fileno())
            notes.append(f"dropped an incomplete last record ({size - good} bytes)")
        if prior is None:
            notes.append("metadata was missing: rebuilt from the telemetry")
        mtime = tele.stat().st_mtime
        last_wall = wall_time(last)
        scene_name = f"{rec_id}.viser"
        for tmp in (f".{rec_id}.viser.tmp", f".{rec_id}.json.tmp"):
            (directory / tmp).unlink(missing_ok=True)
        scene_path = directory / scene_name
        scene_ok = scene_path.is_file()  # written atomically: complete if present
        frames_path = directory / f"{rec_id}.frames"
        frame_pairs = 0
        if (frames_path / "frames.jsonl").is_file():
            from app.streams.frame_log import read_index

            frame_pairs = len(read_index(frames_path))  # complete pairs only
        mcap_file, mcap_note = _recover_mcap(directory, rec_id, tele, frames_path, mount)
        started = prior.started_wall if prior is not None else wall_time(first)
        meta = RecordingMeta(
            id=rec_id,
            started_wall=started if started is not None else mtime,
            stopped_wall=last_wall if last_wall is not None else mtime,
            ticks=count,
            active=False,
            telemetry_file=tele.name,
            scene_file=scene_name if scene_ok else None,
            telemetry_bytes=good,
            scene_bytes=scene_path.stat().st_size if scene_ok else 0,
            stop_reason=INTERRUPTED_REASON,
            status="interrupted",
            max_s=prior.max_s if prior is not None else None,
            max_mb=prior.max_mb if prior is not None else None,
            last_record_wall=last_wall,
            scene_note=None if scene_ok else SCENE_LOST_NOTE,
            recovered_wall=time.time(),
            recovery_note="; ".join(notes) or None,
            frames_dir=frames_path.name if frame_pairs or frames_path.is_dir() else None,
            frame_pairs=frame_pairs,
            mcap_file=mcap_file,
            mcap_bytes=0 if mcap_file is None else (directory / mcap_file).stat().st_size,
            mcap_note=mcap_note,
        )
        write_meta(directory, meta)  # while still holding the lock
    return meta


def _recover_mcap(
    directory: Path, rec_id: str, tele: Path, frames: Path, mount: Callable[[], CameraMount]
) -> tuple[str | None, str | None]:
    """An MCAP log cut by the crash is rebuilt, complete, from the (already truncated)
    telemetry and the complete frame pairs; the cut one is kept if that fails."""
    path = directory / f"{rec_id}.mcap"
    if not path.is_file():
        return None, None
    from app.streams.mcap_log import export_recording, is_complete

    if is_complete(path):
        return path.name, None
    try:
        from app.service.recording.mcap import telemetry_schema
        from app.streams.frame_log import recording_calibration

        calib = recording_calibration(frames) if frames.is_dir() else None
        export_recording(
            tele,
            path,
            telemetry_schema=telemetry_schema(),
            frames_dir=frames if frames.is_dir() else None,
            calibration=calib,
            mount=mount(),
        )
    except Exception as exc:
        log.exception("recording %s: the MCAP log could not be rebuilt", rec_id)
        return path.name, f"cut by the crash (readable up to its last chunk); rebuild: {exc}"
    return path.name, "rebuilt from the telemetry and frames after the crash"
