"""Writing the MCAP log: :class:`FoxgloveLogger` (the channels of
:mod:`app.streams.mcap_log.channels` on one foxglove ``Context``, fed ticks and pairs, in a
thread of its own) and :class:`McapLogWriter`, its MCAP file sink.

Crash safety: chunked writing (1 MB chunks, zstd), the current chunk finished every
``flush_period_s``; a writer killed mid-run leaves a file readable, up to its last complete
chunk, by a streaming reader (:func:`app.streams.mcap_log.reader.iter_messages`). The exact
calibration (``StereoCalibration.to_dict()``) is the ``aar-dock`` metadata record written first
(a replay uses the very numbers of the live run); the drogue profile the navigation looked
for (``DrogueProfile.to_dict()``) is its ``drogue`` entry.
"""

from __future__ import annotations

import atexit
import json
import logging
import queue
import threading
import time
import weakref
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from foxglove import Context

from app.geometry.calibration import StereoCalibration
from app.streams.mcap_log.channels import (
    FORMAT,
    FRAME_IDS,
    FRAME_SCHEMA,
    FRAME_SCHEMA_NAME,
    METADATA_NAME,
    SIDES,
    TELEMETRY_SCHEMA_NAME,
    TOPIC_FRAME,
    TOPIC_POSE,
    TOPIC_SCENE,
    TOPIC_TELEMETRY,
    TOPIC_TF,
    EncodedPair,
    ExposureClock,
    ImageFormat,
    McapStats,
    McapTick,
    RawPair,
    encode_pair,
)
from app.streams.mcap_log.messages import (
    camera_calibration,
    drogue_pose,
    frame_transforms,
    image_annotations,
    scene_update,
    timestamp,
)
from app.vision.drogue import DrogueProfile

if TYPE_CHECKING:
    from app.model.mount import CameraMount

log = logging.getLogger(__name__)


@dataclass
class _Pending:
    seq_ns: dict[int, int] = field(default_factory=dict)


_Item = tuple[McapTick, EncodedPair | RawPair | None]

# Every logger not closed yet: closed at interpreter exit (atexit, registered with the first
# logger, so it runs before the exit handlers registered earlier). foxglove-sdk's native
# threads (its writer and WebSocket server) must be finished while Python can still answer
# them: a logger left open until finalization aborted the interpreter (a Fatal Python error
# after a whole test session had passed).
_OPEN: weakref.WeakSet[FoxgloveLogger] = weakref.WeakSet()
_exit_hook: list[bool] = []


def close_open_loggers() -> None:
    """Close every logger still open (the atexit hook; also for tests and shutdowns)."""
    for logger in list(_OPEN):
        try:
            logger.close()
        except Exception:  # pragma: no cover - at exit nothing can act on it
            log.exception("closing %s at exit failed", logger.stats.path)


class FoxgloveLogger:
    """The channels of :mod:`app.streams.mcap_log.channels` on one foxglove ``Context``, fed ticks and pairs.

    ``threaded``: logged by a thread of its own behind a bounded queue (``write_*`` never
    block; an item that does not fit is dropped and counted), else in the caller's thread.
    A pair is logged at the log time of the tick with the same ``seq`` (written before it),
    else at its own ``info.t_s`` through the same clock. Subclasses bind the context to a sink
    (an MCAP file, a WebSocket server) and finish it in :meth:`_finish`.
    """

    def __init__(
        self,
        ctx: Context,
        *,
        name: str,
        calibration: StereoCalibration | None,
        telemetry_schema: Mapping[str, object],
        mount: CameraMount | None = None,
        threaded: bool = True,
        queue_items: int = 64,
        image_format: ImageFormat = "png",
        jpeg_quality: int = 90,
    ) -> None:
        from foxglove import Channel, Schema
        from foxglove import channels as fc

        self.calibration = calibration
        self.mount = mount
        self.image_format: ImageFormat = image_format
        self.jpeg_quality = jpeg_quality
        self.stats = McapStats(name)
        self._clock = ExposureClock()
        self._pending = _Pending()
        self._ctx = ctx
        self._image = {
            s: fc.CompressedImageChannel(f"/camera/{s}/image", context=ctx) for s in SIDES
        }
        self._calib = {
            s: fc.CameraCalibrationChannel(f"/camera/{s}/calibration", context=ctx) for s in SIDES
        }
        self._ann = {
            s: fc.ImageAnnotationsChannel(f"/camera/{s}/annotations", context=ctx) for s in SIDES
        }
        self._tf = fc.FrameTransformsChannel(TOPIC_TF, context=ctx)
        self._pose = fc.PoseInFrameChannel(TOPIC_POSE, context=ctx)
        self._scene = fc.SceneUpdateChannel(TOPIC_SCENE, context=ctx)
        self._frame = Channel(
            TOPIC_FRAME,
            schema=Schema(
                name=FRAME_SCHEMA_NAME,
                encoding="jsonschema",
                data=json.dumps(FRAME_SCHEMA).encode(),
            ),
            message_encoding="json",
            context=ctx,
        )
        self._telemetry = Channel(
            TOPIC_TELEMETRY,
            schema=Schema(
                name=str(telemetry_schema.get("title") or TELEMETRY_SCHEMA_NAME),
                encoding="jsonschema",
                data=json.dumps(dict(telemetry_schema)).encode(),
            ),
            message_encoding="json",
            context=ctx,
        )
        self._lock = threading.Lock()
        self._closed = False
        _OPEN.add(self)
        if not _exit_hook:
            _exit_hook.append(True)
            atexit.register(close_open_loggers)
        self._queue: queue.Queue[_Item | None] | None = None
        self._thread: threading.Thread | None = None
        if threaded:
            self._queue = queue.Queue(queue_items)
            self._thread = threading.Thread(target=self._run, name=f"{name}-log", daemon=True)
            self._thread.start()

    # ---- public ------------------------------------------------------------------------
    def write_tick(self, tick: McapTick) -> bool:
        """Log a tick (telemetry, tf, pose, scene, annotations); ``False`` if dropped."""
        return self._submit((tick, None))

    def write_pair(self, pair: EncodedPair | RawPair, record_seq: int | None = None) -> bool:
        """Log a pair's images (+ calibration, frame times) at the time of tick ``record_seq``
        (a :class:`RawPair` is encoded as ``image_format`` by the logger's thread)."""
        seq = pair.info.seq if record_seq is None else record_seq
        return self._submit((McapTick(seq, pair.info.t_s, 0.0, b""), pair))

    def close(self) -> McapStats:
        """Log what is queued and finish the sink; returns the counts."""
        with self._lock:
            if self._closed:
                return self.stats
            self._closed = True
        _OPEN.discard(self)
        if self._queue is not None and self._thread is not None:
            self._queue.put(None)
            self._thread.join(timeout=120.0)
        self._finish()
        return self.stats

    def _finish(self) -> None:
        """Finish the sink (subclasses)."""

    def _after_item(self) -> None:
        """Called after each item (subclasses: a periodic flush)."""

    # ---- internals ---------------------------------------------------------------------
    def _submit(self, item: _Item) -> bool:
        if self._closed or self.stats.error is not None:
            return False
        if self._queue is None:
            with self._lock:
                return self._handle(item)
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.stats.dropped += 1
            return False
        return True

    def _run(self) -> None:
        assert self._queue is not None
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self.stats.error is None:
                self._handle(item)

    def _handle(self, item: _Item) -> bool:
        tick, pair = item
        try:
            if pair is not None:
                ns = self._pending.seq_ns.pop(tick.seq, None)
                if ns is None:
                    ns = self._clock.to_ns(pair.info.t_s, time.time())
                if isinstance(pair, RawPair):
                    pair = encode_pair(
                        pair.left, pair.right, pair.info, self.image_format, self.jpeg_quality
                    )
                self._log_pair(pair, ns)
                self.stats.pairs += 1
            else:
                ns = self._clock.to_ns(tick.t_s, tick.wall_time)
                self._pending.seq_ns[tick.seq] = ns
                if len(self._pending.seq_ns) > 256:  # pairs that never came: forget them
                    for old in sorted(self._pending.seq_ns)[:-128]:
                        del self._pending.seq_ns[old]
                self._log_tick(tick, ns)
                self.stats.ticks += 1
            self._after_item()
        except Exception as exc:
            log.error("%s: %s", self.stats.path, exc)
            self.stats.error = f"write failed: {exc}"
            return False
        return True

    def _log_pair(self, pair: EncodedPair, ns: int) -> None:
        from foxglove.messages import CompressedImage

        ts = timestamp(ns)
        # the pair's own times first: a replay has them when its second image arrives
        self._frame.log(json.dumps(pair.info.to_json()).encode(), log_time=ns)
        for side, data in zip(SIDES, (pair.left, pair.right), strict=True):
            self._image[side].log(
                CompressedImage(
                    timestamp=ts, frame_id=FRAME_IDS[side], data=data, format=pair.format
                ),
                log_time=ns,
            )
            if self.calibration is not None:
                msg = camera_calibration(self.calibration, side, ts)
                self._calib[side].log(msg, log_time=ns)

    def _log_tick(self, tick: McapTick, ns: int) -> None:
        self._telemetry.log(tick.telemetry_json, log_time=ns)
        ts = timestamp(ns)
        self._tf.log(frame_transforms(tick, ts, self.calibration, self.mount), log_time=ns)
        for side in SIDES:
            self._ann[side].log(image_annotations(tick, side, ts), log_time=ns)
        self._scene.log(scene_update(tick, ts), log_time=ns)
        pose = drogue_pose(tick, ts)
        if pose is not None:
            self._pose.log(pose, log_time=ns)


class McapLogWriter(FoxgloveLogger):
    """Writes ticks and pairs to one MCAP file (the channels of :mod:`app.streams.mcap_log.channels`): chunked,
    the current chunk finished every ``flush_period_s`` (a kill loses at most that much)."""

    def __init__(
        self,
        path: str | Path,
        *,
        calibration: StereoCalibration | None,
        telemetry_schema: Mapping[str, object],
        mount: CameraMount | None = None,
        threaded: bool = True,
        queue_items: int = 64,
        flush_period_s: float = 1.0,
        chunk_bytes: int = 1 << 20,
        overwrite: bool = False,
        image_format: ImageFormat = "png",
        jpeg_quality: int = 90,
        drogue: DrogueProfile | None = None,
    ) -> None:
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        self.path = Path(path)
        self.flush_period_s = flush_period_s
        ctx = Context()
        options = MCAPWriteOptions(
            compression=MCAPCompression.Zstd,
            chunk_size=chunk_bytes,
            compression_threads=0,  # compressed in the writer's thread: no extra threads
        )
        self._writer = foxglove.open_mcap(
            self.path, context=ctx, writer_options=options, allow_overwrite=overwrite
        )
        meta = {"format": FORMAT, "time": "log time = exposure time, ns since the UNIX epoch"}
        if calibration is not None:
            meta["calibration"] = json.dumps(calibration.to_dict())
        if drogue is not None:  # the drogue the navigation looked for (app.vision.drogue)
            meta["drogue"] = json.dumps(drogue.to_dict())
        self._writer.write_metadata(METADATA_NAME, meta)
        self._last_flush = time.monotonic()
        super().__init__(
            ctx,
            name=str(self.path),
            calibration=calibration,
            telemetry_schema=telemetry_schema,
            mount=mount,
            threaded=threaded,
            queue_items=queue_items,
            image_format=image_format,
            jpeg_quality=jpeg_quality,
        )

    def _after_item(self) -> None:
        now = time.monotonic()
        if now - self._last_flush >= self.flush_period_s:
            self._writer.flush()  # finish the chunk: a kill loses at most this period
            self._last_flush = now

    def _finish(self) -> None:
        try:
            self._writer.close()
        except Exception as exc:  # disk full, ...: the chunks already written stay readable
            self.stats.error = self.stats.error or f"close failed: {exc}"
        try:
            self.stats.bytes = self.path.stat().st_size
        except OSError:
            pass
