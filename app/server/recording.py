"""Record a run: JSONL telemetry (one tick record a line) plus a ``.viser`` scene file.

The scene file comes from viser's scene serializer (``server.get_scene_serializer()``,
``insert_sleep(dt)`` after each scene update, ``serialize()`` on stop). Both are bounded: a
recording stops itself after ``max_s`` seconds or once it holds ``max_mb`` MB.
Replay offline: open viser's client with ``?playbackPath=<url of the .viser file>`` (the
service serves the client at ``/viser-client/``) or read the JSONL.
"""

from __future__ import annotations

import json
import logging
import re
import threading
import time
import uuid
from pathlib import Path
from typing import Any, Protocol

from app.server.schemas import RecordingInfo, TickRecord

log = logging.getLogger(__name__)
ID_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


class SceneSerializer(Protocol):
    def insert_sleep(self, duration: float) -> None: ...

    def serialize(self) -> bytes: ...


class Recorder:
    """One active recording at a time; ``on_tick`` is a tick-loop subscriber."""

    def __init__(
        self,
        directory: Path,
        *,
        max_s: float = 300.0,
        max_mb: float = 200.0,
        scene_serializer_factory: Any = None,
    ) -> None:
        self.directory = Path(directory)
        self.max_s = max_s
        self.max_bytes = int(max_mb * 1e6)
        self.scene_serializer_factory = scene_serializer_factory
        self._lock = threading.Lock()
        self._info: RecordingInfo | None = None
        self._finishing: RecordingInfo | None = None  # being serialized by stop()
        self._fh: Any = None
        self._serializer: SceneSerializer | None = None
        self._t0 = 0.0
        self._scene_bytes_est = 0

    @property
    def active(self) -> RecordingInfo | None:
        return self._info

    def _meta_path(self, rec_id: str) -> Path:
        return self.directory / f"{rec_id}.json"

    def start(self) -> RecordingInfo:
        with self._lock:
            if self._info is not None:
                raise RuntimeError(f"recording {self._info.id} is already active")
            self.directory.mkdir(parents=True, exist_ok=True)
            rec_id = time.strftime("rec-%Y%m%d-%H%M%S-") + uuid.uuid4().hex[:6]
            tele = self.directory / f"{rec_id}.jsonl"
            self._fh = tele.open("w", encoding="utf-8")
            self._serializer = None
            scene_file = None
            if self.scene_serializer_factory is not None:
                try:
                    self._serializer = self.scene_serializer_factory()
                    scene_file = f"{rec_id}.viser"
                except Exception:
                    log.exception("could not start the scene serializer")
            self._t0 = time.monotonic()
            self._scene_bytes_est = 0
            self._info = RecordingInfo(
                id=rec_id,
                started_wall=time.time(),
                active=True,
                telemetry_file=tele.name,
                scene_file=scene_file,
            )
            return self._info.model_copy()

    def on_tick(self, record: TickRecord, raw: Any = None) -> None:
        """Tick-loop subscriber: append the record; stop when a bound is reached."""
        reason = None
        with self._lock:
            info = self._info
            if info is None or self._fh is None:
                return
            line = record.model_dump_json() + "\n"
            self._fh.write(line)
            info.ticks += 1
            info.telemetry_bytes += len(line.encode())
            if time.monotonic() - self._t0 > self.max_s:
                reason = f"reached {self.max_s:g} s"
            elif info.telemetry_bytes + self._scene_bytes_est > self.max_bytes:
                reason = f"reached {self.max_bytes / 1e6:g} MB"
        if reason is not None:
            # Serializing can take a while: do not block the tick thread.
            threading.Thread(target=self.stop, kwargs={"reason": reason}, daemon=True).start()

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

    def stop(self, reason: str = "stopped") -> RecordingInfo | None:
        with self._lock:
            info = self._info
            if info is None:
                return None
            self._info = None
            self._finishing = info
            fh, self._fh = self._fh, None
            ser, self._serializer = self._serializer, None
        if fh is not None:
            fh.close()
        if ser is not None and info.scene_file is not None:
            try:
                data = ser.serialize()
                (self.directory / info.scene_file).write_bytes(data)
                info.scene_bytes = len(data)
            except Exception:
                log.exception("scene serialization failed")
                info.scene_file = None
        done = info.model_copy(
            update={"active": False, "stopped_wall": time.time(), "stop_reason": reason}
        )
        self._meta_path(info.id).write_text(done.model_dump_json(indent=2))
        with self._lock:
            self._finishing = None
        return done

    def list(self) -> list[RecordingInfo]:
        out: list[RecordingInfo] = []
        for live in (self._info, self._finishing):
            if live is not None:
                out.append(live.model_copy())
        ids = {r.id for r in out}
        if self.directory.is_dir():
            for meta in sorted(self.directory.glob("rec-*.json"), reverse=True):
                try:
                    rec = RecordingInfo.model_validate_json(meta.read_text())
                    if rec.id not in ids:
                        out.append(rec)
                except Exception:
                    log.warning("unreadable recording metadata %s", meta)
        return out

    def get(self, rec_id: str) -> RecordingInfo | None:
        if not ID_RE.match(rec_id):
            return None
        for live in (self._info, self._finishing):
            if live is not None and live.id == rec_id:
                return live.model_copy()
        meta = self._meta_path(rec_id)
        if not meta.is_file():
            return None
        return RecordingInfo.model_validate_json(meta.read_text())

    def file_path(self, rec_id: str, kind: str) -> Path | None:
        info = self.get(rec_id)
        if info is None or info.active:
            return None
        name = info.telemetry_file if kind == "telemetry" else info.scene_file
        if name is None:
            return None
        path = self.directory / name
        return path if path.is_file() else None

    def close(self) -> None:
        self.stop(reason="server shutdown")


def read_jsonl(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
