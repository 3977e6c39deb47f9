r"""The recorder: one active recording at a time — its start (telemetry, scene serializer, MCAP
log, frame writer), the tick-loop subscriber that appends each record, the limits (``max_s``,
``max_mb``, the frames' own bound, the free-space floor) enforced by a watchdog thread that also
``fsync``\ s periodically, the stop that finishes the files (never raising for a failing disk),
and listing and locating the recordings. The layout and crash-safety guarantees of a recording:
:mod:`app.service.recording`."""

from __future__ import annotations

import logging
import os
import shutil
import threading
import time
import uuid
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import IO, TYPE_CHECKING, Literal, Protocol

from app.model.frames import RawFrame
from app.model.tick import TickRecord
from app.service.recording.budget import (
    Bounds,
    RateProbe,
    RecordingProgress,
    Written,
    estimated_progress,
    measured_progress,
)
from app.service.recording.disk import free_mb, try_lock, write_all, write_atomic
from app.service.recording.meta import (
    ID_RE,
    RecordingError,
    RecordingMeta,
    meta_path,
    storage_error,
    write_meta,
)
from app.service.recording.recovery import recover_recordings
from app.streams.frame_encoding import FrameEncoding
from app.types import JsonObject

if TYPE_CHECKING:
    from app.geometry.calibration import StereoCalibration
    from app.model.mount import CameraMount
    from app.service.recording.mcap import RecordingMcap
    from app.streams.frame_log import FrameRecordingWriter
    from app.vision.drogue import DrogueProfile

log = logging.getLogger(__name__)
FSYNC_PERIOD_S = 0.5


class SceneSerializer(Protocol):
    def insert_sleep(self, duration: float) -> None: ...

    def serialize(self) -> bytes: ...


def _watchdog(ref: weakref.ReferenceType[Recorder], rec_id: str, wake: threading.Event) -> None:
    """Per-recording thread: time/size bounds and periodic fsync. Holds the recorder weakly."""
    while True:
        rec = ref()
        if rec is None:
            return
        wait = rec.watch(rec_id)
        del rec
        if wait is None:
            return
        wake.wait(wait)
        wake.clear()


class Recorder:
    """One active recording at a time; ``on_tick`` is a tick-loop subscriber."""

    def __init__(
        self,
        directory: Path,
        *,
        max_s: float = 300.0,
        max_mb: float = 200.0,
        max_frames_mb: float = 4000.0,
        min_free_mb: float = 0.0,
        scene_serializer_factory: Callable[[], SceneSerializer] | None = None,
        recover: bool = True,
        mcap: bool = True,
        mcap_plant: str | None = None,
    ) -> None:
        self.directory = Path(directory)
        self.max_s = max_s
        self.max_mb = max_mb
        self.max_bytes = int(max_mb * 1e6)
        self.max_frames_bytes = int(max_frames_mb * 1e6)  # raw frames: a bound of their own
        self.min_free_mb = min_free_mb  # a frame recording starts, and goes on, above this
        self.max_frames_mb = max_frames_mb
        self.probe = RateProbe()  # the ticks' rate and a sample frame: the estimate before a start
        self._encoding: FrameEncoding | None = None  # the active recording's frames (None: none)
        self.scene_serializer_factory = scene_serializer_factory
        self._lock = threading.Lock()
        self._info: RecordingMeta | None = None
        self._finishing: RecordingMeta | None = None  # being serialized by stop()
        self._fh: IO[bytes] | None = None
        self._serializer: SceneSerializer | None = None
        self._t0 = 0.0
        self._scene_bytes_est = 0
        self._limit_reason: str | None = None
        self._failure: str | None = None  # the write error that stopped the recording
        self._unsaved: dict[str, RecordingMeta] = {}  # final metadata the disk refused
        self._wake: threading.Event | None = None
        self._last_sync = 0.0
        self._dirty = False
        self._frames: FrameRecordingWriter | None = None
        self._accept_frame: Callable[[RawFrame], bool] | None = None
        self.mcap = mcap  # also write <id>.mcap (app.service.recording.mcap)
        self.mcap_plant = mcap_plant  # the airframe whose rig mount /tf uses (None: default)
        self._mcap: RecordingMcap | None = None
        self._mount: CameraMount | None = None
        self.recovered: list[RecordingMeta] = self.recover() if recover else []

    @property
    def active(self) -> RecordingMeta | None:
        """The recording in progress, until its files are finished (``None`` once its final
        metadata is written)."""
        return self._info or self._finishing

    @property
    def frame_writer(self) -> FrameRecordingWriter | None:
        """The active recording's frame writer (None: no recording, or one without frames)."""
        return self._frames

    def _write_meta(self, info: RecordingMeta) -> None:
        write_meta(self.directory, info)

    # ---- recording -------------------------------------------------------------------
    def start(
        self,
        *,
        frames: bool = False,
        calibration: StereoCalibration | None = None,
        accept_frame: Callable[[RawFrame], bool] | None = None,
        source: str | None = None,
        drogue: DrogueProfile | None = None,
        encoding: FrameEncoding | None = None,
    ) -> RecordingMeta:
        """Start a recording. ``frames``: also the raw stereo pairs of every tick that has
        images (encoded with ``encoding``, default lossless ``png-huffman``, + times +
        ``calibration``, in ``<id>.frames``); ``accept_frame``
        filters the raw ticks whose pairs are written (a stream's fresh-track epoch);
        ``drogue``: the profile the source's navigation looks for, stored with the frames and
        in the MCAP log (a replay uses it)."""
        with self._lock:
            if self._info is not None:
                raise RecordingError(409, f"recording {self._info.id} is already active")
            try:
                self.directory.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise storage_error("cannot create the recordings directory", exc) from None
            self._save_unsaved()
            if frames:
                self._check_free_space()
            rec_id = time.strftime("rec-%Y%m%d-%H%M%S-") + uuid.uuid4().hex[:6]
            tele = self.directory / f"{rec_id}.jsonl"
            try:
                fh = tele.open("xb", buffering=0)  # one write per record, short writes seen
            except OSError as exc:
                raise storage_error("cannot write to the recordings directory", exc) from None
            try_lock(fh)
            serializer = None
            scene_file = None
            if self.scene_serializer_factory is not None:
                try:
                    serializer = self.scene_serializer_factory()
                    scene_file = f"{rec_id}.viser"
                except Exception:
                    log.exception("could not start the scene serializer")
            encoding = (encoding or FrameEncoding()) if frames else None
            mcap = self._open_mcap(rec_id, calibration, drogue, encoding)
            writer = None
            if frames:
                from app.streams.frame_log import FrameRecordingWriter

                try:
                    writer = FrameRecordingWriter(
                        self.directory / f"{rec_id}.frames",
                        calibration,
                        max_s=self.max_s,
                        max_bytes=self.max_frames_bytes,
                        source=source,
                        on_pair=None if mcap is None else mcap.on_pair,
                        drogue=drogue,
                        encoding=encoding,
                    )
                except Exception as exc:
                    self._discard_mcap(mcap)
                    fh.close()
                    tele.unlink(missing_ok=True)
                    shutil.rmtree(self.directory / f"{rec_id}.frames", ignore_errors=True)
                    if isinstance(exc, OSError):
                        raise storage_error("cannot start the frame recording", exc) from None
                    raise
            info = RecordingMeta(
                id=rec_id,
                started_wall=time.time(),
                active=True,
                telemetry_file=tele.name,
                scene_file=scene_file,
                status="recording",
                max_s=self.max_s,
                max_mb=self.max_mb,
                frames_dir=None if writer is None else writer.directory.name,
                frames_encoding=None if encoding is None else encoding.label,
                mcap_file=None if mcap is None else mcap.path.name,
                mcap_note=None if mcap is not None or not self.mcap else "could not be opened",
            )
            try:
                self._write_meta(info)
            except Exception as exc:
                self._discard_mcap(mcap)
                fh.close()
                tele.unlink(missing_ok=True)
                if writer is not None:
                    writer.close("metadata write failed")
                    shutil.rmtree(writer.directory, ignore_errors=True)
                if isinstance(exc, OSError):
                    raise storage_error("cannot write the recording's metadata", exc) from None
                raise
            self._frames = writer
            self._encoding = encoding
            self._mcap = mcap
            self._accept_frame = accept_frame
            self._fh = fh
            self._serializer = serializer
            self._info = info
            self._t0 = self._last_sync = time.monotonic()
            self._scene_bytes_est = 0
            self._limit_reason = None
            self._failure = None
            self._dirty = False
            self._wake = wake = threading.Event()
            out = info.model_copy()
        threading.Thread(
            target=_watchdog,
            args=(weakref.ref(self), rec_id, wake),
            name=f"recording-watchdog-{rec_id}",
            daemon=True,
        ).start()
        return out

    def on_tick(self, record: TickRecord, raw: RawFrame | None = None) -> None:
        """Tick-loop subscriber: append and flush the record; request a stop at a bound."""
        if self.probe.on_tick():
            self._sample(record, raw)
        with self._lock:
            info, fh = self._info, self._fh
            if info is None or fh is None or self._limit_reason is not None:
                return
            if time.monotonic() - self._t0 >= self.max_s:
                self._request_stop(f"reached {self.max_s:g} s")
                return
            line = record.model_dump_json().encode() + b"\n"
            try:
                write_all(fh, line)  # unbuffered: in the OS's hands, survives a kill
            except (OSError, ValueError) as exc:
                self._fail(info, f"write failed: {exc}")
                return
            self._dirty = True
            info.ticks += 1
            info.telemetry_bytes += len(line)
            info.last_record_wall = record.wall_time
            if self._mcap is not None:
                self._mcap.on_record(record, line, raw)  # queued: never blocks
            writer = self._frames
            if writer is not None and raw is not None:
                self._submit_frame(writer, record, raw)
            if self._total_bytes(info) > self.max_bytes:
                self._request_stop(f"reached {self.max_bytes / 1e6:g} MB")
            elif writer is not None and writer.stop_reason is not None:
                self._frames_stopped(info, writer.stop_reason)

    def _sample(self, record: TickRecord, raw: RawFrame | None) -> None:
        """Give the probe a telemetry line's size and the tick's left image (if any)."""
        image = None
        if raw is not None:
            frame = raw.stereo_frame
            image = frame.left if frame is not None else raw.left_image
        self.probe.take_sample(len(record.model_dump_json()) + 1, image)

    def progress(self, encoding: FrameEncoding | None = None) -> RecordingProgress:
        """``GET /recording``: the active recording's write rate (bytes/s over the recording)
        and the time left at it against each bound; with none active, the estimate for a
        recording with ``encoding`` (None: without frames)."""
        bounds = Bounds(self.max_s, self.max_mb, self.max_frames_mb, self.min_free_mb)
        free = free_mb(self.directory) if self.directory.is_dir() else None
        with self._lock:
            info, writer, mcap = self._info, self._frames, self._mcap
            active_encoding, elapsed = self._encoding, time.monotonic() - self._t0
            telemetry = 0 if info is None else info.telemetry_bytes + self._scene_bytes_est
        if info is None:
            return estimated_progress(self.probe, encoding, self.mcap, bounds, free)
        written = Written(
            telemetry=telemetry,
            frames=0 if writer is None else writer.bytes,
            mcap=0 if mcap is None else mcap.bytes_on_disk,
        )
        return measured_progress(info.id, active_encoding, elapsed, written, bounds, free)

    def _total_bytes(self, info: RecordingMeta) -> int:
        """Telemetry + scene (``max_mb``); the frames have their own bound (the writer's)."""
        return info.telemetry_bytes + self._scene_bytes_est

    def _submit_frame(
        self, writer: FrameRecordingWriter, record: TickRecord, raw: RawFrame
    ) -> None:
        """(lock held) Queue the tick's stereo pair for the frame writer (never blocks)."""
        accept = self._accept_frame
        if accept is not None and not accept(raw):
            return
        frame = raw.stereo_frame  # a stream tick carries its StereoFrame
        if frame is None:
            left, right = raw.left_image, raw.right_image
            if left is None or right is None:
                return
            from app.model.frames import StereoFrame

            frame = StereoFrame(left=left, right=right, t_s=record.t_s, seq=record.seq)
        writer.submit(frame, record.seq)

    def _open_mcap(
        self,
        rec_id: str,
        calibration: StereoCalibration | None,
        drogue: DrogueProfile | None = None,
        encoding: FrameEncoding | None = None,
    ) -> RecordingMcap | None:
        """(lock held) The recording's MCAP log, or None (disabled, or it cannot be opened:
        logged; the recording goes on without it)."""
        if not self.mcap:
            return None
        try:
            from app.service.recording.mcap import RecordingMcap

            path = self.directory / f"{rec_id}.mcap"
            fmt = "png" if encoding is None else encoding.image_format
            return RecordingMcap(path, calibration, self._rig_mount(), drogue, fmt)
        except Exception:
            log.exception("recording %s: the MCAP log could not be opened", rec_id)
            return None

    def _discard_mcap(self, mcap: RecordingMcap | None) -> None:
        if mcap is not None:
            mcap.close()
            mcap.path.unlink(missing_ok=True)

    def _fail(self, info: RecordingMeta, reason: str) -> None:
        """(lock held) A write error: the recording stops as ``failed`` with ``reason``."""
        if self._failure is None:
            log.error("recording %s: %s", info.id, reason)
            self._failure = reason
        self._request_stop(reason)

    def _frames_stopped(self, info: RecordingMeta, why: str) -> None:
        """(lock held) The frame writer stopped: at its bound, or failed (a write error)."""
        if why.startswith("write failed"):
            self._fail(info, f"frames: {why}")
        else:
            self._request_stop(f"frames: {why}")

    def _under_floor(self) -> str | None:
        """(lock held) Why a frame recording must stop for the free-space floor, or None."""
        if self._frames is None or self.min_free_mb <= 0:
            return None
        free = free_mb(self.directory)
        if free is None or free >= self.min_free_mb:
            return None
        return f"free space {free:.4g} MB under the floor of {self.min_free_mb:g} MB"

    def _check_free_space(self) -> None:
        """(lock held) 507 when a frame recording would start under the free-space floor."""
        free = free_mb(self.directory)
        if self.min_free_mb > 0 and free is not None and free < self.min_free_mb:
            raise RecordingError(
                507,
                f"only {free:.4g} MB free for recordings, under the floor of "
                f"{self.min_free_mb:g} MB for a frame recording (AAR_RECORDING_MIN_FREE_MB)",
            )

    def _request_stop(self, reason: str) -> None:
        """(lock held) The watchdog thread stops it: serializing must not block the tick thread."""
        self._limit_reason = reason
        if self._wake is not None:
            self._wake.set()

    def watch(self, rec_id: str) -> float | None:
        """One watchdog step: stop at a bound, fsync when due; seconds to the next step or None."""
        with self._lock:
            info = self._info
            if info is None or info.id != rec_id:
                return None
            now = time.monotonic()
            remaining = self.max_s - (now - self._t0)
            reason = self._limit_reason
            if reason is None and remaining <= 0:
                reason = f"reached {self.max_s:g} s"
            if reason is None and self._total_bytes(info) > self.max_bytes:
                reason = f"reached {self.max_bytes / 1e6:g} MB"
            if reason is None:
                reason = self._under_floor()
            if reason is None and self._frames is not None and self._frames.stop_reason:
                self._frames_stopped(info, self._frames.stop_reason)
                reason = self._limit_reason
            fh = self._fh
            sync = fh if self._dirty and now - self._last_sync >= FSYNC_PERIOD_S else None
            if sync is not None:
                self._last_sync = now
                self._dirty = False
        if reason is not None:
            self._stop(rec_id, reason)
            return None
        if sync is not None:
            try:
                os.fsync(sync.fileno())
            except ValueError:  # closed by a concurrent stop: it fsyncs itself
                pass
            except OSError as exc:  # a delayed write error (full disk)
                with self._lock:
                    if self._info is info:
                        self._fail(info, f"write failed: {exc}")
                self._stop(rec_id, f"write failed: {exc}")
                return None
        return max(0.0, min(FSYNC_PERIOD_S, remaining))

    def on_scene_update(self, dt_s: float) -> None:
        """Called by the scene publisher after each scene update (``insert_sleep``)."""
        with self._lock:
            ser = self._serializer
            if ser is None:
                return
            ser.insert_sleep(max(0.0, dt_s))
            buffers = getattr(ser, "_binary_buffers", None)  # size estimate only
            if buffers is not None:
                self._scene_bytes_est = sum(b.nbytes for b in buffers)

    def stop(self, reason: str = "stopped") -> RecordingMeta | None:
        with self._lock:
            self._save_unsaved()
        return self._stop(None, reason)

    def _stop(self, rec_id: str | None, reason: str) -> RecordingMeta | None:
        """Stop and finish the files. Never raises for a failing disk: the recording is then
        ``failed`` (the first write error as its ``stop_reason``), its telemetry cut back to
        the last complete record, its metadata kept in memory if the disk refuses it."""
        with self._lock:
            info = self._info
            if info is None or (rec_id is not None and info.id != rec_id):
                return None
            self._info = None
            self._finishing = info
            fh, self._fh = self._fh, None
            ser, self._serializer = self._serializer, None
            writer, self._frames = self._frames, None
            encoding, self._encoding = self._encoding, None
            mcap, self._mcap = self._mcap, None
            wake, self._wake = self._wake, None
            failure, self._failure = self._failure, None
            self._limit_reason = None
        if wake is not None:
            wake.set()
        errors: list[str] = [] if failure is None else [failure]
        update: JsonObject = {"active": False, "stopped_wall": time.time()}
        try:
            if fh is not None:
                try:
                    if failure is not None:  # a torn last record: back to the last complete one
                        os.ftruncate(fh.fileno(), info.telemetry_bytes)
                    os.fsync(fh.fileno())
                except (OSError, ValueError) as exc:
                    log.error("recording %s: final flush failed: %s", info.id, exc)
                    errors.append(f"write failed: {exc}")
            if writer is not None:
                fmeta = writer.close(reason)
                update["frame_pairs"] = int(fmeta["pairs"])
                update["frames_bytes"] = int(fmeta["bytes"])
                update["frames_dropped"] = int(fmeta["dropped"])
                if encoding is not None and fmeta["pairs"]:
                    self.probe.measured(encoding, int(fmeta["bytes"]) / int(fmeta["pairs"]))
                why = str(fmeta.get("stop_reason") or "")
                if why.startswith("write failed") and f"frames: {why}" not in errors:
                    errors.append(f"frames: {why}")
            if mcap is not None:  # after the frames: their last pairs are in its queue
                mstats = mcap.close()
                update["mcap_bytes"] = mstats.bytes
                if mstats.error is not None:
                    update["mcap_note"] = mstats.error
                elif mstats.dropped:
                    update["mcap_note"] = f"{mstats.dropped} items dropped (writer behind)"
            if ser is not None and info.scene_file is not None:
                if errors:  # the disk already failed: the scene (in memory) is not written
                    update["scene_file"] = None
                    update["scene_note"] = f"not written: {errors[0]}"
                else:
                    try:
                        data = ser.serialize()
                        write_atomic(self.directory / info.scene_file, data)
                        update["scene_bytes"] = len(data)
                    except Exception as exc:
                        log.exception("scene serialization failed")
                        update["scene_file"] = None
                        update["scene_note"] = f"scene serialization failed: {exc}"
            if errors:
                update["status"] = "failed"
                update["stop_reason"] = errors[0]
            else:
                update["status"] = "complete"
                update["stop_reason"] = reason
            done = info.model_copy(update=update)
            try:
                self._write_meta(done)
            except OSError as exc:
                log.error("recording %s: metadata not written (%s): kept in memory", done.id, exc)
                if not errors:
                    done = done.model_copy(
                        update={"status": "failed", "stop_reason": f"write failed: {exc}"}
                    )
                with self._lock:
                    self._unsaved[done.id] = done
        finally:
            if fh is not None:
                fh.close()  # releases the lock only once the metadata says how it ended
            with self._lock:
                self._finishing = None
        return done

    def _save_unsaved(self) -> None:
        """(lock held) Write the final metadata a failing disk refused, now that it may not."""
        for rec_id, meta in list(self._unsaved.items()):
            try:
                self._write_meta(meta)
            except OSError:
                continue
            del self._unsaved[rec_id]

    def close(self) -> None:
        self.stop(reason="server shutdown")

    # ---- recovery --------------------------------------------------------------------
    def recover(self) -> list[RecordingMeta]:
        """Mark the recordings a crash left behind as ``interrupted``; returns them
        (:func:`app.service.recording.recovery.recover_recordings`)."""
        live = None if self._info is None else self._info.id
        return recover_recordings(self.directory, live, self._rig_mount)

    def _rig_mount(self) -> CameraMount:
        """The rig mount the MCAP logs' /tf uses (the airframe's ``mcap_plant``; made once)."""
        if self._mount is None:
            from app.sim.rig_mount import default_mount

            self._mount = default_mount(self.mcap_plant)
        return self._mount

    # ---- reading ---------------------------------------------------------------------
    def list(self) -> list[RecordingMeta]:
        out: list[RecordingMeta] = []
        for live in (self._info, self._finishing, *self._unsaved.values()):
            if live is not None:
                out.append(live.model_copy())
        ids = {r.id for r in out}
        if self.directory.is_dir():
            for meta in sorted(self.directory.glob("rec-*.json"), reverse=True):
                try:
                    rec = RecordingMeta.model_validate_json(meta.read_bytes())
                    if rec.id not in ids:
                        out.append(rec)
                except Exception:
                    log.warning("unreadable recording metadata %s", meta)
        return out

    def get(self, rec_id: str) -> RecordingMeta | None:
        if not ID_RE.match(rec_id):
            return None
        for live in (self._info, self._finishing, self._unsaved.get(rec_id)):
            if live is not None and live.id == rec_id:
                return live.model_copy()
        meta = meta_path(self.directory, rec_id)
        if not meta.is_file():
            return None
        try:
            return RecordingMeta.model_validate_json(meta.read_bytes())
        except Exception:
            log.warning("unreadable recording metadata %s", meta)
            return None

    def locate(
        self, rec_id: str, kind: Literal["telemetry", "scene", "mcap"]
    ) -> tuple[Path | None, str]:
        """The file of a finished recording, or ``None`` and why not (for a 404's detail)."""
        info = self.get(rec_id)
        if info is None:
            return None, f"no recording {rec_id!r}"
        if info.active:
            return None, f"recording {rec_id!r} is still active"
        name = {"telemetry": info.telemetry_file, "scene": info.scene_file}.get(kind)
        if kind == "mcap":
            name = info.mcap_file
            if name is None:
                why = info.mcap_note or "recorded without an MCAP log"
                return None, f"recording {rec_id!r} has no MCAP log: {why}"
        if name is None:
            why = info.scene_note or "recorded without the 3-D scene"
            return None, f"recording {rec_id!r} has no scene file: {why}"
        path = self.directory / name
        if not path.is_file():
            return None, f"the {kind} file of recording {rec_id!r} is missing"
        return path, ""
