"""Record a run: JSONL telemetry (one tick record a line), a ``.viser`` scene file and, on
request, the raw stereo frames (``<id>.frames``, :mod:`app.streams.recording`).

Layout of one recording ``<id>`` (``rec-YYYYmmdd-HHMMSS-xxxxxx``) in the recordings directory:

``<id>.json``
    Metadata (:class:`RecordingMeta`), always replaced atomically (temp file + ``os.replace``).
    Written at start with ``status="recording"`` and the limits; rewritten at stop with
    ``status="complete"`` (``stop_reason`` says why: ``stopped``, ``reached 5 s``, ...), or at
    recovery with ``status="interrupted"``.
``<id>.jsonl``
    Telemetry, one :class:`TickRecord` a line. Each line is flushed to the OS as it is written
    (a killed process loses at most the record being written); ``os.fsync`` runs every
    ``FSYNC_PERIOD_S`` (an OS crash or power loss loses at most that much). While a recording is
    active its process holds an ``flock`` on this file, so recovery never touches a recording that
    is live in another process.
``<id>.viser``
    The scene, from viser's scene serializer (``server.get_scene_serializer()``,
    ``insert_sleep(dt)`` after each scene update, ``serialize()`` on stop). The serializer keeps
    everything in memory, so this file only exists after a clean stop; a crash loses it (the
    recovered metadata says so: ``scene_file: null``, ``scene_note``). Replay offline: viser's
    client with ``?playbackPath=<url of the .viser file>`` (served at ``/viser-client/``).

``<id>.mcap``
    The same run as one MCAP log for Foxglove (:mod:`app.server.mcap_recording`,
    docs/ecosystem.md): telemetry, /tf, pose, scene, annotations and, with frames, the very PNG
    bytes of ``<id>.frames``; written by a thread of its own, chunked and flushed every second,
    so a kill leaves it readable up to its last complete chunk; recovery rebuilds a complete one
    from the JSONL and the frames (``mcap_note`` says so).

``<id>.frames/`` (``POST /recording/start?frames=true``)
    Lossless PNG pairs, per-pair times and the calibration used, written by a thread of its
    own (a pair it cannot keep up with is dropped and counted, never blocking the tick
    thread); every pair is on disk before its index line, so a crash keeps all complete pairs.
    ``aar-dock track --left <id>.frames`` and ``serve --source video:<id>.frames`` replay it.

A failing disk (``ENOSPC``, ``EACCES``, the directory removed): the first write error stops
the recording, ``status="failed"`` with the error as ``stop_reason``; the telemetry is cut back
to its last complete record and stays downloadable. Metadata that cannot be written is kept in
memory (listed, served) and written by the next start or stop. A start that cannot write
raises :class:`RecordingError` (507 for a full disk, 503 otherwise); a frame recording starts
only with ``min_free_mb`` free (507 otherwise).

Recovery: a :class:`Recorder` created over a directory recovers the recordings a crash left
behind (metadata still ``recording`` and no live owner, or a JSONL without metadata): it drops a
torn last line, counts the records, and writes ``status="interrupted"`` metadata, so they are
listed and downloadable. Bounds: a recording stops after ``max_s`` (a watchdog thread, ticks or
not) or once it holds ``max_mb`` MB.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import shutil
import threading
import time
import uuid
import weakref
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any, Literal, Protocol

from app.server.schemas import RecordingInfo, TickRecord

try:  # POSIX advisory locks: which recordings are live in some process
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger(__name__)
ID_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
FSYNC_PERIOD_S = 0.5
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


def free_mb(directory: Path) -> float | None:
    """Free space (MB) of the file system holding ``directory``; None if it cannot be read."""
    try:
        return shutil.disk_usage(directory).free / 1e6
    except OSError:
        return None


class RecordingMeta(RecordingInfo):
    """The metadata file and the API's answer (``RecordingInfo`` plus the crash-safety fields)."""

    status: RecordingStatus = "complete"  # files written before these fields were clean stops
    max_s: float | None = None
    max_mb: float | None = None
    last_record_wall: float | None = None  # ``wall_time`` of the last record on disk
    scene_note: str | None = None  # why there is no scene file, when there is none
    recovered_wall: float | None = None  # when an interrupted recording was recovered
    recovery_note: str | None = None
    frames_dir: str | None = None  # raw stereo frames (app.streams.recording), if recorded
    frame_pairs: int = 0
    frames_bytes: int = 0
    frames_dropped: int = 0  # pairs the frame writer could not keep up with
    mcap_file: str | None = None  # the MCAP log of the run (docs/ecosystem.md)
    mcap_bytes: int = 0
    mcap_note: str | None = None  # why the MCAP log is missing or was rebuilt


class SceneSerializer(Protocol):
    def insert_sleep(self, duration: float) -> None: ...

    def serialize(self) -> bytes: ...


def _try_lock(fh: IO[bytes]) -> bool:
    """Non-blocking exclusive ``flock``; released when the file is closed or the process dies."""
    if fcntl is None:  # pragma: no cover
        return True
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    return True


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)  # a torn temp file must not hold the space it took
        raise
    _fsync_dir(path.parent)


def _write_all(fh: IO[bytes], data: bytes) -> None:
    """Unbuffered file: all of ``data`` or ``OSError`` (a short write is retried)."""
    view = memoryview(data)
    while view:
        n = fh.write(view)
        if not n:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        view = view[n:]


def _wall_time(line: bytes | None) -> float | None:
    if line is None:
        return None
    try:
        value = json.loads(line).get("wall_time")
    except (ValueError, AttributeError):
        return None
    return float(value) if isinstance(value, int | float) else None


def _watchdog(ref: weakref.ReferenceType[Recorder], rec_id: str, wake: threading.Event) -> None:
    """Per-recording thread: time/size bounds and periodic fsync. Holds the recorder weakly."""
    while True:
        rec = ref()
        if rec is None:
            return
        wait = rec._watch(rec_id)
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
        scene_serializer_factory: Any = None,
        recover: bool = True,
        mcap: bool = True,
        mcap_plant: str | None = None,
    ) -> None:
        self.directory = Path(directory)
        self.max_s = max_s
        self.max_mb = max_mb
        self.max_bytes = int(max_mb * 1e6)
        self.max_frames_bytes = int(max_frames_mb * 1e6)  # raw frames: a bound of their own
        self.min_free_mb = min_free_mb  # a frame recording needs this much free space to start
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
        self._frames: Any = None  # app.streams.recording.FrameRecordingWriter
        self._accept_frame: Callable[[Any], bool] | None = None
        self.mcap = mcap  # also write <id>.mcap (app.server.mcap_recording)
        self.mcap_plant = mcap_plant  # the airframe whose rig mount /tf uses (None: default)
        self._mcap: Any = None  # app.server.mcap_recording.RecordingMcap
        self._mount: Any = None
        self.recovered: list[RecordingMeta] = self.recover() if recover else []

    @property
    def active(self) -> RecordingMeta | None:
        """The recording in progress, until its files are finished (``None`` once its final
        metadata is written)."""
        return self._info or self._finishing

    def _meta_path(self, rec_id: str) -> Path:
        return self.directory / f"{rec_id}.json"

    def _write_meta(self, info: RecordingMeta) -> None:
        _write_atomic(self._meta_path(info.id), info.model_dump_json(indent=2).encode())

    # ---- recording -------------------------------------------------------------------
    def start(
        self,
        *,
        frames: bool = False,
        calibration: Any = None,
        accept_frame: Callable[[Any], bool] | None = None,
        source: str | None = None,
    ) -> RecordingMeta:
        """Start a recording. ``frames``: also the raw stereo pairs of every tick that has
        images (lossless PNG + times + ``calibration``, in ``<id>.frames``); ``accept_frame``
        filters the raw ticks whose pairs are written (a stream's fresh-track epoch)."""
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
            _try_lock(fh)
            serializer = None
            scene_file = None
            if self.scene_serializer_factory is not None:
                try:
                    serializer = self.scene_serializer_factory()
                    scene_file = f"{rec_id}.viser"
                except Exception:
                    log.exception("could not start the scene serializer")
            mcap = self._open_mcap(rec_id, calibration)
            writer = None
            if frames:
                from app.streams.recording import FrameRecordingWriter

                try:
                    writer = FrameRecordingWriter(
                        self.directory / f"{rec_id}.frames",
                        calibration,
                        max_s=self.max_s,
                        max_bytes=self.max_frames_bytes,
                        source=source,
                        on_pair=None if mcap is None else mcap.on_pair,
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

    def on_tick(self, record: TickRecord, raw: Any = None) -> None:
        """Tick-loop subscriber: append and flush the record; request a stop at a bound."""
        with self._lock:
            info, fh = self._info, self._fh
            if info is None or fh is None or self._limit_reason is not None:
                return
            if time.monotonic() - self._t0 >= self.max_s:
                self._request_stop(f"reached {self.max_s:g} s")
                return
            line = record.model_dump_json().encode() + b"\n"
            try:
                _write_all(fh, line)  # unbuffered: in the OS's hands, survives a kill
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

    def _total_bytes(self, info: RecordingMeta) -> int:
        """Telemetry + scene (``max_mb``); the frames have their own bound (the writer's)."""
        return info.telemetry_bytes + self._scene_bytes_est

    def _submit_frame(self, writer: Any, record: TickRecord, raw: Any) -> None:
        """(lock held) Queue the tick's stereo pair for the frame writer (never blocks)."""
        accept = self._accept_frame
        if accept is not None and not accept(raw):
            return
        frame = getattr(raw, "frame", None)  # a stream tick carries its StereoFrame
        if frame is None:
            left, right = getattr(raw, "left_image", None), getattr(raw, "right_image", None)
            if left is None or right is None:
                return
            from app.streams.frames import StereoFrame

            frame = StereoFrame(left=left, right=right, t_s=record.t_s, seq=record.seq)
        writer.submit(frame, record.seq)

    def _open_mcap(self, rec_id: str, calibration: Any) -> Any:
        """(lock held) The recording's MCAP log, or None (disabled, or it cannot be opened:
        logged; the recording goes on without it)."""
        if not self.mcap:
            return None
        try:
            from app.server.mcap_recording import RecordingMcap, default_mount

            if self._mount is None:
                self._mount = default_mount(self.mcap_plant)
            return RecordingMcap(self.directory / f"{rec_id}.mcap", calibration, self._mount)
        except Exception:
            log.exception("recording %s: the MCAP log could not be opened", rec_id)
            return None

    def _discard_mcap(self, mcap: Any) -> None:
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

    def _watch(self, rec_id: str) -> float | None:
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
            mcap, self._mcap = self._mcap, None
            wake, self._wake = self._wake, None
            failure, self._failure = self._failure, None
            self._limit_reason = None
        if wake is not None:
            wake.set()
        errors: list[str] = [] if failure is None else [failure]
        update: dict[str, Any] = {"active": False, "stopped_wall": time.time()}
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
                        _write_atomic(self.directory / info.scene_file, data)
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
        """Mark the recordings a crash left behind as ``interrupted``; returns them."""
        if not self.directory.is_dir():
            return []
        out: list[RecordingMeta] = []
        for tele in sorted(self.directory.glob("rec-*.jsonl")):
            rec_id = tele.stem
            if not ID_RE.match(rec_id) or (self._info is not None and self._info.id == rec_id):
                continue
            meta_path = self._meta_path(rec_id)
            prior: RecordingMeta | None = None
            if meta_path.is_file():
                try:
                    prior = RecordingMeta.model_validate_json(meta_path.read_bytes())
                except Exception:
                    log.warning("unreadable recording metadata %s: rebuilding it", meta_path)
                if prior is not None and prior.status != "recording":
                    continue
            try:
                rec = self._recover_one(tele, prior)
            except Exception:
                log.exception("could not recover recording %s", rec_id)
                continue
            if rec is not None:
                log.warning("recovered interrupted recording %s: %d records", rec.id, rec.ticks)
                out.append(rec)
        return out

    def _recover_one(self, tele: Path, prior: RecordingMeta | None) -> RecordingMeta | None:
        rec_id = tele.stem
        with tele.open("r+b") as fh:
            if not _try_lock(fh):
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
            last_wall = _wall_time(last)
            scene_name = f"{rec_id}.viser"
            for tmp in (f".{rec_id}.viser.tmp", f".{rec_id}.json.tmp"):
                (self.directory / tmp).unlink(missing_ok=True)
            scene_path = self.directory / scene_name
            scene_ok = scene_path.is_file()  # written atomically: complete if present
            frames_path = self.directory / f"{rec_id}.frames"
            frame_pairs = 0
            if (frames_path / "frames.jsonl").is_file():
                from app.streams.recording import read_index

                frame_pairs = len(read_index(frames_path))  # complete pairs only
            mcap_file, mcap_note = self._recover_mcap(rec_id, tele, frames_path)
            started = prior.started_wall if prior is not None else _wall_time(first)
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
                mcap_bytes=0 if mcap_file is None else (self.directory / mcap_file).stat().st_size,
                mcap_note=mcap_note,
            )
            self._write_meta(meta)  # while still holding the lock
        return meta

    def _recover_mcap(self, rec_id: str, tele: Path, frames: Path) -> tuple[str | None, str | None]:
        """An MCAP log cut by the crash is rebuilt, complete, from the (already truncated)
        telemetry and the complete frame pairs; the cut one is kept if that fails."""
        path = self.directory / f"{rec_id}.mcap"
        if not path.is_file():
            return None, None
        from app.streams.mcap_log import export_recording, is_complete

        if is_complete(path):
            return path.name, None
        try:
            from app.server.mcap_recording import default_mount, telemetry_schema
            from app.streams.recording import recording_calibration

            calib = recording_calibration(frames) if frames.is_dir() else None
            if self._mount is None:
                self._mount = default_mount(self.mcap_plant)
            export_recording(
                tele,
                path,
                telemetry_schema=telemetry_schema(),
                frames_dir=frames if frames.is_dir() else None,
                calibration=calib,
                mount=self._mount,
            )
        except Exception as exc:
            log.exception("recording %s: the MCAP log could not be rebuilt", rec_id)
            return path.name, f"cut by the crash (readable up to its last chunk); rebuild: {exc}"
        return path.name, "rebuilt from the telemetry and frames after the crash"

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
        meta = self._meta_path(rec_id)
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

    def file_path(self, rec_id: str, kind: str) -> Path | None:
        return self.locate(rec_id, "telemetry" if kind == "telemetry" else "scene")[0]


def read_jsonl(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
