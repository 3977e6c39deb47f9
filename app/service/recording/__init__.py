"""Record a run: JSONL telemetry (one tick record a line), a ``.viser`` scene file and, on
request, the raw stereo frames (``<id>.frames``, :mod:`app.streams.frame_log`).

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
    The same run as one MCAP log for Foxglove (:mod:`app.service.recording.mcap`,
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

from app.service.recording.disk import free_mb, read_jsonl
from app.service.recording.meta import (
    ID_RE,
    INTERRUPTED_REASON,
    SCENE_LOST_NOTE,
    RecordingError,
    RecordingMeta,
    RecordingStatus,
    storage_error,
)
from app.service.recording.recorder import FSYNC_PERIOD_S, Recorder, SceneSerializer

__all__ = [
    "FSYNC_PERIOD_S",
    "ID_RE",
    "INTERRUPTED_REASON",
    "SCENE_LOST_NOTE",
    "Recorder",
    "RecordingError",
    "RecordingMeta",
    "RecordingStatus",
    "SceneSerializer",
    "free_mb",
    "read_jsonl",
    "storage_error",
]
