"""One MCAP file per run (the field's log format, opened by Foxglove without configuration).

Channels (Foxglove's built-in schemas, protobuf-encoded, written with ``foxglove-sdk``):

==============================  ============================  ==========================================
topic                           schema                        content
==============================  ============================  ==========================================
``/camera/left/image``          ``foxglove.CompressedImage``  the stereo pair's images (PNG: lossless,
``/camera/right/image``                                       bit-exact; JPEG when asked), frame ids
                                                              ``camera_left`` / ``camera_right``
``/camera/left/calibration``    ``foxglove.CameraCalibration`` K, D (plumb_bob), R = I, P = [K | 0]
``/camera/right/calibration``                                 (raw, unrectified images), one per pair
``/camera/left/annotations``    ``foxglove.ImageAnnotations``  matched LED centroids (px) + their ids;
``/camera/right/annotations``                                 the tracker's windows when the tick has them
``/camera/stereo_frame``        JSON (jsonschema)             the pair's own times (``seq``, ``t_s``, …)
``/tf``                         ``foxglove.FrameTransforms``  tanker → drogue, tanker → receiver →
                                                              camera_left → camera_right (m)
``/drogue/pose``                ``foxglove.PoseInFrame``      the measured drogue centre (m) in
                                                              ``camera_left``, +z along the ring's normal
``/scene``                      ``foxglove.SceneUpdate``      measured ring, LEDs, probe tip
``/telemetry``                  JSON (jsonschema)             the tick record, exactly the JSONL line
==============================  ============================  ==========================================

Log time (ns since the UNIX epoch) of everything a tick produced = its exposure time: the
first tick's ``wall_time`` plus the tick's ``t_s`` elapsed since the first tick's ``t_s`` (the
source's capture clock, or the simulation's clock); a ``t_s`` that does not advance (a reset
simulation, uploads) re-anchors on that tick's ``wall_time`` (kept increasing).
:class:`ExposureClock` is that mapping.

Crash safety: chunked writing (1 MB chunks, zstd), the current chunk finished every
``flush_period_s``; a writer killed mid-run leaves a file readable, up to its last complete chunk,
by a streaming reader (:func:`iter_messages`), and the recording's JSONL rebuilds a complete one
(:func:`export_recording`). The exact calibration (``StereoCalibration.to_dict()``) is the
``aar-dock`` metadata record written first (a replay uses the very numbers of the live run).
"""

from __future__ import annotations

import atexit
import json
import logging
import queue
import threading
import time
import weakref
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import cv2
import numpy as np
from foxglove import Context
from foxglove import messages as fm
from numpy.typing import NDArray

from app.geometry.calibration import StereoCalibration
from app.sim.frames import euler_to_matrix
from app.streams.annotations import (
    REJECTED_RGB,
    WINDOW_RGB,
    Rect,
    Side,
    image_marks,
    led_color,
)
from app.vision.result import PoseResult

if TYPE_CHECKING:
    from app.sim.rig_mount import CameraMount

log = logging.getLogger(__name__)

FORMAT = "aar-dock-mcap/1"
METADATA_NAME = "aar-dock"
TELEMETRY_SCHEMA_NAME = "aar_dock.TickRecord"
FRAME_SCHEMA_NAME = "aar_dock.StereoFrame"
SIDES: tuple[Side, Side] = ("left", "right")
FRAME_IDS = {"left": "camera_left", "right": "camera_right"}
TOPICS = {
    "image": "/camera/{side}/image",
    "calibration": "/camera/{side}/calibration",
    "annotations": "/camera/{side}/annotations",
}
TOPIC_FRAME = "/camera/stereo_frame"
TOPIC_TF = "/tf"
TOPIC_POSE = "/drogue/pose"
TOPIC_SCENE = "/scene"
TOPIC_TELEMETRY = "/telemetry"
PNG_LEVEL = 1  # fast lossless compression
LED_SPHERE_M = 0.03  # diameter of an LED in the 3-D scene (m)
PROBE_SPHERE_M = 0.08

ImageFormat = Literal["png", "jpeg"]
Vec3 = tuple[float, float, float]
VecLike = Sequence[float] | NDArray[np.float64]
FRAME_SCHEMA: dict[str, object] = {
    "type": "object",
    "title": FRAME_SCHEMA_NAME,
    "description": "the stereo pair's own times (s, the source's clock) and frame number",
    "properties": {
        "seq": {"type": "integer"},
        "t_s": {"type": "number"},
        "t_left_s": {"type": ["number", "null"]},
        "t_right_s": {"type": ["number", "null"]},
        "exposure_ms": {"type": ["number", "null"]},
    },
}


class McapLogError(ValueError):
    """A file that is not a readable MCAP log (one line: what is wrong)."""


@dataclass(frozen=True)
class FrameInfo:
    """A pair's own frame number and times (s, on the source's clock)."""

    seq: int
    t_s: float
    t_left_s: float | None = None
    t_right_s: float | None = None
    exposure_ms: float | None = None

    def to_json(self) -> dict[str, float | int | None]:
        return {
            "seq": self.seq,
            "t_s": self.t_s,
            "t_left_s": self.t_left_s,
            "t_right_s": self.t_right_s,
            "exposure_ms": self.exposure_ms,
        }


@dataclass(frozen=True)
class EncodedPair:
    """A stereo pair's encoded images (PNG or JPEG bytes) and times."""

    left: bytes
    right: bytes
    format: ImageFormat
    info: FrameInfo


@dataclass(frozen=True)
class McapTick:
    """What one tick record contributes besides its images (tanker frame m, camera frame mm
    for ``pose``). ``telemetry_json``: the record exactly as its JSONL line (no newline)."""

    seq: int
    t_s: float
    wall_time: float
    telemetry_json: bytes
    pose: PoseResult | None = None
    uav_state: tuple[float, ...] | None = None  # u v w p q r φ θ ψ x y z (absolute)
    drogue_truth_m: Vec3 | None = None
    drogue_normal: Vec3 | None = None
    probe_tip_m: Vec3 | None = None
    image_windows_px: tuple[Sequence[Rect], Sequence[Rect]] | None = None


def _vec3(value: object) -> Vec3 | None:
    if not isinstance(value, list | tuple) or len(value) != 3:
        return None
    return (float(value[0]), float(value[1]), float(value[2]))


def tick_from_json(
    line: bytes, image_windows_px: tuple[Sequence[Rect], Sequence[Rect]] | None = None
) -> McapTick:
    """A :class:`McapTick` from a tick record's JSON (a JSONL line; ``ValueError`` if bad)."""
    data = json.loads(line)
    if not isinstance(data, dict):
        raise ValueError("a tick record must be a JSON object")
    pose = data.get("pose")
    state = data.get("uav_state")
    return McapTick(
        seq=int(data["seq"]),
        t_s=float(data["t_s"]),
        wall_time=float(data["wall_time"]),
        telemetry_json=line.rstrip(b"\n"),
        pose=None if pose is None else PoseResult.model_validate(pose),
        uav_state=None if not isinstance(state, list) else tuple(float(v) for v in state),
        drogue_truth_m=_vec3(data.get("drogue_truth_m")),
        drogue_normal=_vec3(data.get("drogue_normal")),
        probe_tip_m=_vec3(data.get("probe_tip_m")),
        image_windows_px=image_windows_px,
    )


class ExposureClock:
    """Tick time ``t_s`` (s, source clock) → log time (ns since the UNIX epoch), increasing."""

    def __init__(self) -> None:
        self._anchor: tuple[float, int] | None = None  # (t_s, ns)
        self._last_t: float | None = None
        self._last_ns = -1

    def to_ns(self, t_s: float, wall_time: float) -> int:
        if self._anchor is None or self._last_t is None or t_s <= self._last_t:
            self._anchor = (t_s, max(round(wall_time * 1e9), self._last_ns + 1))
        ns = self._anchor[1] + round((t_s - self._anchor[0]) * 1e9)
        ns = max(ns, self._last_ns + 1)
        self._last_t, self._last_ns = t_s, ns
        return ns


def encode_image(img: NDArray[np.uint8], fmt: ImageFormat, jpeg_quality: int = 90) -> bytes:
    """PNG (lossless) or JPEG bytes of a grey or BGR image."""
    if fmt == "png":
        ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, PNG_LEVEL])
    else:
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    if not ok:
        raise OSError(f"{fmt} encoding failed")
    return bytes(buf.tobytes())


def encode_pair(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    info: FrameInfo,
    fmt: ImageFormat = "png",
    jpeg_quality: int = 90,
) -> EncodedPair:
    return EncodedPair(
        encode_image(left, fmt, jpeg_quality), encode_image(right, fmt, jpeg_quality), fmt, info
    )


# ---- geometry --------------------------------------------------------------------------
def _quat(r: NDArray[np.float64]) -> tuple[float, float, float, float]:
    from scipy.spatial.transform import Rotation  # imported on first use (≈ 0.5 s)

    x, y, z, w = Rotation.from_matrix(np.asarray(r, float)).as_quat()
    return float(x), float(y), float(z), float(w)


def z_to(normal: VecLike) -> NDArray[np.float64]:
    """The smallest rotation taking +z onto ``normal`` (a ring's axis)."""
    from scipy.spatial.transform import Rotation

    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, n)
    s, c = float(np.linalg.norm(axis)), float(z @ n)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return np.asarray(Rotation.from_rotvec(axis / s * np.arctan2(s, c)).as_matrix(), float)


def right_in_left(
    calibration: StereoCalibration,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The right camera's axes and origin (m) in the left camera's frame
    (``X_right = R · X_left + T`` ⇒ ``X_left = Rᵀ · X_right − Rᵀ · T``)."""
    r = np.asarray(calibration.R, float)
    return r.T, -(r.T @ np.asarray(calibration.T, float)) / 1e3


def ring_points(center_m: VecLike, normal: VecLike, radius_m: float, n: int = 36) -> list[Vec3]:
    """``n`` points (m) on the circle of ``radius_m`` about ``center_m`` normal to ``normal``."""
    r = z_to(normal)
    a = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    local = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=1) * radius_m
    pts = local @ r.T + np.asarray(center_m, float)
    return [(float(p[0]), float(p[1]), float(p[2])) for p in pts]


# ---- writer ----------------------------------------------------------------------------
@dataclass
class McapStats:
    """What a writer wrote (and dropped: its queue full)."""

    path: str
    ticks: int = 0
    pairs: int = 0
    dropped: int = 0
    bytes: int = 0
    error: str | None = None


@dataclass
class _Pending:
    seq_ns: dict[int, int] = field(default_factory=dict)


@dataclass(frozen=True)
class RawPair:
    """A stereo pair's images as arrays, encoded by the logger's thread (live: JPEG)."""

    left: NDArray[np.uint8]
    right: NDArray[np.uint8]
    info: FrameInfo


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
    """The channels of the module's table on one foxglove ``Context``, fed ticks and pairs.

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

        ts = _timestamp(ns)
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
        ts = _timestamp(ns)
        self._tf.log(self._transforms(tick, ts), log_time=ns)
        for side in SIDES:
            self._ann[side].log(_annotations(tick, side, ts), log_time=ns)
        self._scene.log(_scene(tick, ts), log_time=ns)
        drogue = None if tick.pose is None or not tick.pose.lock else tick.pose.drogue
        if drogue is not None:
            from foxglove.messages import Pose, PoseInFrame

            c = drogue.center_mm
            self._pose.log(
                PoseInFrame(
                    timestamp=ts,
                    frame_id=FRAME_IDS["left"],
                    pose=Pose(
                        position=_v3((c[0] / 1e3, c[1] / 1e3, c[2] / 1e3)),
                        orientation=_q(z_to(drogue.normal)),
                    ),
                ),
                log_time=ns,
            )

    def _transforms(self, tick: McapTick, ts: fm.Timestamp) -> fm.FrameTransforms:
        from foxglove.messages import FrameTransform, FrameTransforms

        out = []

        def add(parent: str, child: str, r: NDArray[np.float64], t: VecLike) -> None:
            out.append(
                FrameTransform(
                    timestamp=ts,
                    parent_frame_id=parent,
                    child_frame_id=child,
                    translation=_v3(t),
                    rotation=_q(r),
                )
            )

        if tick.drogue_truth_m is not None:
            normal = tick.drogue_normal if tick.drogue_normal is not None else (1.0, 0.0, 0.0)
            add("tanker", "drogue", z_to(normal), tick.drogue_truth_m)
        if tick.uav_state is not None and len(tick.uav_state) >= 12:
            s = tick.uav_state
            add("tanker", "receiver", euler_to_matrix(s[6], s[7], s[8]), s[9:12])
            if self.mount is not None:
                add("receiver", FRAME_IDS["left"], self.mount.r_bc, self.mount.camera_b)
        if self.calibration is not None:
            r, t = right_in_left(self.calibration)
            add(FRAME_IDS["left"], FRAME_IDS["right"], r, t)
        return FrameTransforms(transforms=out)


class McapLogWriter(FoxgloveLogger):
    """Writes ticks and pairs to one MCAP file (see the module's channel table): chunked,
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


def camera_calibration(
    calibration: StereoCalibration, side: str, ts: fm.Timestamp | None = None
) -> fm.CameraCalibration:
    """One side's ``foxglove.CameraCalibration``: K (px), D (plumb_bob: k1 k2 p1 p2 k3) and, for
    the raw (unrectified) images, R = I and P = [K | 0] in that camera's own frame."""
    cam = calibration.left if side == "left" else calibration.right
    k = np.asarray(cam.K, float)
    w, h = calibration.image_size
    return fm.CameraCalibration(
        timestamp=ts,
        frame_id=FRAME_IDS[side],
        width=int(w),
        height=int(h),
        distortion_model="plumb_bob",
        D=[float(v) for v in cam.dist],
        K=[float(v) for v in k.ravel()],
        R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        P=[float(v) for v in np.hstack([k, np.zeros((3, 1))]).ravel()],
    )


def _timestamp(ns: int) -> fm.Timestamp:
    return fm.Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def _v3(t: VecLike) -> fm.Vector3:
    return fm.Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2]))


def _q(r: NDArray[np.float64]) -> fm.Quaternion:
    x, y, z, w = _quat(r)
    return fm.Quaternion(x=x, y=y, z=z, w=w)


def _annotations(tick: McapTick, side: Side, ts: fm.Timestamp) -> fm.ImageAnnotations:
    """The marks the page and the 3-D view draw (:func:`app.streams.annotations.image_marks`)
    as Foxglove annotations: each LED a point and its id in its colour, the windows outlined."""
    from foxglove.messages import (
        Color,
        ImageAnnotations,
        Point2,
        PointsAnnotation,
        PointsAnnotationType,
        TextAnnotation,
    )

    def colour(rgb: tuple[int, int, int]) -> Color:
        return Color(r=rgb[0] / 255, g=rgb[1] / 255, b=rgb[2] / 255, a=1.0)

    windows = None if tick.image_windows_px is None else tick.image_windows_px[side == "right"]
    marks = image_marks(
        tick.pose, side, windows_px=[(w[0], w[1], w[2], w[3]) for w in windows or ()]
    )
    points, texts = [], []
    for m in marks.leds:
        c = colour(led_color(m.led_id))
        points.append(
            PointsAnnotation(
                timestamp=ts,
                type=PointsAnnotationType.Points,
                points=[Point2(x=float(m.u_px), y=float(m.v_px))],
                outline_color=c,
                fill_color=c,
                thickness=6.0,
            )
        )
        texts.append(
            TextAnnotation(
                timestamp=ts,
                position=Point2(x=float(m.u_px) + 6.0, y=float(m.v_px) - 6.0),
                text=str(m.led_id),
                font_size=14.0,
                text_color=c,
                background_color=Color(r=0.0, g=0.0, b=0.0, a=0.5),
            )
        )
    if marks.rejected_px:
        grey = colour(REJECTED_RGB)
        points.append(
            PointsAnnotation(
                timestamp=ts,
                type=PointsAnnotationType.Points,
                points=[Point2(x=float(u), y=float(v)) for u, v in marks.rejected_px],
                outline_color=grey,
                fill_color=grey,
                thickness=3.0,
            )
        )
    for x0, y0, x1, y1 in marks.windows_px:
        points.append(
            PointsAnnotation(
                timestamp=ts,
                type=PointsAnnotationType.LineLoop,
                points=[
                    Point2(x=float(x0), y=float(y0)),
                    Point2(x=float(x1), y=float(y0)),
                    Point2(x=float(x1), y=float(y1)),
                    Point2(x=float(x0), y=float(y1)),
                ],
                outline_color=colour(WINDOW_RGB),
                thickness=1.5,
            )
        )
    return ImageAnnotations(points=points, texts=texts)


def _scene(tick: McapTick, ts: fm.Timestamp) -> fm.SceneUpdate:
    from foxglove.messages import (
        Color,
        LinePrimitive,
        LinePrimitiveLineType,
        Point3,
        Pose,
        SceneEntity,
        SceneEntityDeletion,
        SceneUpdate,
        SpherePrimitive,
    )

    identity = _q(np.eye(3))
    entities, deletions = [], []
    drogue = None if tick.pose is None or not tick.pose.lock else tick.pose.drogue
    if drogue is not None and tick.pose is not None:
        c = np.asarray(drogue.center_mm, float) / 1e3
        ring = ring_points(c, drogue.normal, drogue.radius_mm / 1e3)
        leds = [
            SpherePrimitive(
                pose=Pose(position=_v3(np.asarray(led.xyz_mm) / 1e3), orientation=identity),
                size=_v3((LED_SPHERE_M,) * 3),
                color=Color(r=0.1, g=1.0, b=0.2, a=1.0),
            )
            for led in tick.pose.leds
        ]
        entities.append(
            SceneEntity(
                timestamp=ts,
                frame_id=FRAME_IDS["left"],
                id="drogue_measured",
                lines=[
                    LinePrimitive(
                        type=LinePrimitiveLineType.LineLoop,
                        pose=Pose(position=_v3((0, 0, 0)), orientation=identity),
                        thickness=0.02,
                        points=[Point3(x=p[0], y=p[1], z=p[2]) for p in ring],
                        color=Color(r=0.2, g=0.6, b=1.0, a=1.0),
                    )
                ],
                spheres=leds,
            )
        )
    else:
        deletions.append(SceneEntityDeletion(timestamp=ts, id="drogue_measured"))
    if tick.probe_tip_m is not None:
        entities.append(
            SceneEntity(
                timestamp=ts,
                frame_id="tanker",
                id="probe_tip",
                spheres=[
                    SpherePrimitive(
                        pose=Pose(position=_v3(tick.probe_tip_m), orientation=identity),
                        size=_v3((PROBE_SPHERE_M,) * 3),
                        color=Color(r=1.0, g=0.3, b=0.2, a=1.0),
                    )
                ],
            )
        )
    return SceneUpdate(deletions=deletions, entities=entities)


# ---- reading ---------------------------------------------------------------------------
@dataclass(frozen=True)
class McapMessage:
    """One message: its topic, log time (ns since the UNIX epoch), raw bytes and, for a
    protobuf channel read with ``decode``, the message decoded with its own schema."""

    topic: str
    log_time_ns: int
    data: bytes
    decoded: object = None


def iter_messages(
    path: str | Path, topics: Sequence[str] | None = None, *, decode: bool = False
) -> Iterator[McapMessage]:
    """The messages of an MCAP log in file order (complete or cut by a crash: up to its last
    complete chunk). :class:`McapLogError` if it is not an MCAP file."""
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    from mcap_protobuf.decoder import DecoderFactory

    wanted = None if topics is None else set(topics)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    decoders: dict[int, object] = {}
    factory = DecoderFactory()
    try:
        fh = open(path, "rb")  # noqa: SIM115 - closed in finally, the generator may stop early
    except OSError as exc:
        raise McapLogError(f"cannot open {str(path)!r}: {exc.strerror or exc}") from None
    try:
        records = StreamReader(fh, skip_magic=False).records
        try:
            for rec in records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                elif isinstance(rec, Message):
                    ch = channels.get(rec.channel_id)
                    topic = "" if ch is None else ch.topic
                    if wanted is not None and topic not in wanted:
                        continue
                    decoded: object = None
                    if decode and ch is not None:
                        if ch.id not in decoders:
                            decoders[ch.id] = factory.decoder_for(
                                ch.message_encoding, schemas.get(ch.schema_id)
                            )
                        fn = decoders[ch.id]
                        if callable(fn):
                            decoded = fn(rec.data)
                    yield McapMessage(topic, rec.log_time, rec.data, decoded)
        except (McapError, EOFError, ValueError, OSError) as exc:
            if not channels:
                raise McapLogError(f"{str(path)!r} is not a readable MCAP file ({exc})") from None
            log.warning("MCAP %s ends early (%s): read up to its last complete chunk", path, exc)
    finally:
        fh.close()


def read_metadata(path: str | Path) -> dict[str, str]:
    """The ``aar-dock`` metadata record (format, exact calibration), ``{}`` if it has none."""
    from mcap.exceptions import McapError
    from mcap.records import Message, Metadata
    from mcap.stream_reader import StreamReader

    try:
        with open(path, "rb") as fh:
            for rec in StreamReader(fh, skip_magic=False).records:
                if isinstance(rec, Metadata) and rec.name == METADATA_NAME:
                    return dict(rec.metadata)
                if isinstance(rec, Message):
                    return {}
    except OSError as exc:
        raise McapLogError(f"cannot open {str(path)!r}: {exc.strerror or exc}") from None
    except (McapError, EOFError, ValueError) as exc:
        raise McapLogError(f"{str(path)!r} is not a readable MCAP file ({exc})") from None
    return {}


def is_complete(path: str | Path) -> bool:
    """Whether an MCAP file was finished (ends with its footer and magic)."""
    from mcap.opcode import Opcode

    try:
        with open(path, "rb") as fh:
            size = fh.seek(0, 2)
            if size < 8 + 9 + 20 + 8:
                return False
            fh.seek(size - 8 - 29)
            tail = fh.read()
    except OSError:
        return False
    return tail[-8:] == b"\x89MCAP0\r\n" and tail[0] == Opcode.FOOTER


# ---- export ----------------------------------------------------------------------------
def export_recording(
    telemetry_jsonl: str | Path,
    out: str | Path,
    *,
    telemetry_schema: Mapping[str, object],
    frames_dir: str | Path | None = None,
    calibration: StereoCalibration | None = None,
    mount: CameraMount | None = None,
) -> McapStats:
    """Rebuild a recording's MCAP from its files: the JSONL (complete lines) and, if any, its
    frame folder (PNG bytes copied as they are: bit-exact). Written to a temporary name, then
    renamed onto ``out``."""
    import os

    from app.streams.recording import read_index

    out = Path(out)
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.unlink(missing_ok=True)
    pairs: dict[int, dict[str, Any]] = {}
    if frames_dir is not None and (Path(frames_dir) / "frames.jsonl").is_file():
        for entry in read_index(frames_dir):
            rs = entry.get("record_seq")
            pairs[int(rs if rs is not None else entry["seq"])] = entry
    writer = McapLogWriter(
        tmp,
        calibration=calibration,
        telemetry_schema=telemetry_schema,
        mount=mount,
        threaded=False,
        flush_period_s=1e9,
    )
    try:
        with open(telemetry_jsonl, "rb") as fh:
            for line in fh:
                if not line.endswith(b"\n"):
                    break  # a torn last record
                try:
                    tick = tick_from_json(line)
                except (ValueError, KeyError, TypeError):
                    break
                writer.write_tick(tick)
                found = pairs.pop(tick.seq, None)
                if found is not None and frames_dir is not None:
                    d = Path(frames_dir)
                    writer.write_pair(
                        EncodedPair(
                            (d / str(found["left"])).read_bytes(),
                            (d / str(found["right"])).read_bytes(),
                            "png",
                            frame_info(found),
                        ),
                        tick.seq,
                    )
    finally:
        stats = writer.close()
    if stats.error is not None:
        tmp.unlink(missing_ok=True)
        raise OSError(stats.error)
    os.replace(tmp, out)
    stats.path = str(out)
    return stats


def frame_info(entry: Mapping[str, Any]) -> FrameInfo:
    """A frame recording's index line (``frames.jsonl``) as a :class:`FrameInfo`."""

    def opt(key: str) -> float | None:
        v = entry.get(key)
        return None if v is None else float(v)

    return FrameInfo(
        seq=int(entry["seq"]),  # type: ignore[call-overload]
        t_s=float(entry["t_s"]),
        t_left_s=opt("t_left_s"),
        t_right_s=opt("t_right_s"),
        exposure_ms=opt("exposure_ms"),
    )
