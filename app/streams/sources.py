"""Frame sources behind one interface (:class:`~app.streams.frames.FrameSource`).

Spec strings (``aar-dock serve --source``, ``AAR_SOURCE``, ``PUT /api/v1/stream/source``):

* ``video:LEFT,RIGHT`` — two video files, folders or globs; ``video:DIR`` — a raw-frame
  recording (``DIR/frames.jsonl``); ``mcap:FILE`` (or ``video:FILE.mcap``) — the stereo pairs
  of an MCAP log (:mod:`app.streams.mcap_source`);
* ``camera:I,J`` — two capture devices (``VideoCapture(I)``; a path works too, for tests);
  ``camera:I`` — one side-by-side stereo device, split in halves;
* ``push`` — pairs pushed over the WebSocket (:mod:`app.streams.protocol`).
"""

from __future__ import annotations

import re
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from app.model.frames import StereoFrame
from app.streams.frame_log import (
    FrameRecordingSource,
    is_frame_recording,
    recording_calibration,
    recording_drogue,
)
from app.streams.frames import EndOfStream, SourceError, SourceKind, SourceStats
from app.streams.mcap_source import McapRecordingSource, is_mcap, mcap_drogue
from app.streams.pairing import TimestampPairer
from app.streams.protocol import PushMessage
from app.streams.readers import CaptureReader, open_reader
from app.types import UInt8Array
from app.vision.drogue import DrogueProfile
from app.vision.io import decode_image
from app.vision.preprocess import ImageError

DEFAULT_MAX_SKEW_S = 0.010
CAMERA_DEVICE = re.compile(r"\d{1,3}|/dev/video\d{1,3}")  # an index or a V4L2 device
PutResult = Literal["queued", "duplicate", "out_of_order"]


@dataclass(frozen=True)
class SourceOptions:
    """How a source is read. ``realtime``: pace file sources at their own times (False: as
    fast as possible); ``loop``: restart finite sources at their end; ``fps``: frame rate of
    image folders without ``timestamps.txt``; ``max_skew_s``: left/right pairing tolerance."""

    realtime: bool = True
    loop: bool = False
    fps: float = 30.0
    max_skew_s: float = DEFAULT_MAX_SKEW_S


@dataclass(frozen=True)
class SourceSpec:
    kind: SourceKind | None  # None: the simulation
    left: str = ""
    right: str = ""

    @property
    def text(self) -> str:
        if self.kind is None:
            return "sim"
        if self.kind == "push":
            return "push"
        return f"{self.kind}:{self.left}" + (f",{self.right}" if self.right else "")


def parse_source(text: str) -> SourceSpec:
    """``sim`` | ``push`` | ``video:L,R`` | ``video:DIR`` | ``camera:I,J`` | ``camera:I``."""
    t = text.strip()
    if t in ("", "sim"):
        return SourceSpec(None)
    if t == "push":
        return SourceSpec("push")
    kind, sep, rest = t.partition(":")
    if kind == "mcap" and sep:
        if not rest.strip() or "," in rest:
            raise SourceError(f"mcap source needs one MCAP file, got {rest!r}")
        return SourceSpec("video", rest.strip())
    if not sep or kind not in ("video", "camera"):
        raise SourceError(
            f"unknown source {text!r}: use sim, push, video:LEFT,RIGHT, video:DIR, "
            "mcap:FILE, camera:I,J or camera:I"
        )
    parts = [p.strip() for p in rest.split(",")]
    if len(parts) > 2 or not parts[0] or (len(parts) == 2 and not parts[1]):
        raise SourceError(f"{kind} source needs one or two comma-separated inputs, got {rest!r}")
    if kind == "camera":
        # a camera is a device: OpenCV's VideoCapture would open an ordinary file too, which
        # would bypass the folders a file source may be read from (AAR_STREAM_ROOTS)
        bad = [p for p in parts if not CAMERA_DEVICE.fullmatch(p)]
        if bad:
            raise SourceError(
                f"camera source takes a device index or a /dev/video* path, got {bad[0]!r} "
                "(files and folders: video:…)"
            )
    return SourceSpec(kind, parts[0], parts[1] if len(parts) == 2 else "")  # type: ignore[arg-type]


class _Pacer:
    """Sleep so that frames come out at their own times (never faster than real time)."""

    def __init__(self) -> None:
        self.origin: tuple[float, float] | None = None  # (frame time, wall time)

    def wait(self, t_s: float) -> None:
        now = time.monotonic()
        if self.origin is None:
            self.origin = (t_s, now)
            return
        due = self.origin[1] + (t_s - self.origin[0])
        if due - now > 2.0 or now - due > 1.0:  # a jump (loop, gap) or far behind: resync
            self.origin = (t_s, now)
            return
        if due > now:
            time.sleep(due - now)


class VideoSource:
    """Two files/folders/globs paired by time, or a raw-frame recording."""

    kind: SourceKind = "video"

    def __init__(self, left: str, right: str = "", options: SourceOptions | None = None) -> None:
        self.options = options or SourceOptions()
        self.left_spec, self.right_spec = left, right
        self.spec = SourceSpec("video", left, right).text
        self.stats = SourceStats()
        self._pacer = _Pacer()
        self._offset = 0.0  # added to the times after each loop
        self._last_t: float | None = None
        self._first_t: float | None = None
        self._seq_offset = 0
        self._last_seq = -1
        self._recording: FrameRecordingSource | McapRecordingSource | None = None
        self._pairer: TimestampPairer | None = None
        self.calibration: Any = None  # a frame recording's own calibration, if it has one
        self.drogue: DrogueProfile | None = None  # and its own drogue profile
        if not right and is_mcap(left):
            self._recording = McapRecordingSource(left)
            self.calibration = self._recording.calibration
            self.drogue = mcap_drogue(left)
        elif not right:
            if not is_frame_recording(left):
                raise SourceError(
                    f"video:{left} — a single input must be a frame recording "
                    "(a folder with frames.jsonl); otherwise give LEFT,RIGHT"
                )
            self._recording = FrameRecordingSource(left)
            self.calibration = recording_calibration(left)
            self.drogue = recording_drogue(left)
        else:
            self._open_pair()

    @property
    def pair_count(self) -> int | None:
        """The number of pairs of a frame recording (``None``: videos, folders, MCAP logs)."""
        if isinstance(self._recording, FrameRecordingSource):
            return len(self._recording.entries)
        return None

    def _open_pair(self) -> None:
        o = self.options
        left = open_reader(self.left_spec, o.fps)
        try:
            right = open_reader(self.right_spec, o.fps)
        except Exception:
            left.close()
            raise
        self._pairer = TimestampPairer(left, right, o.max_skew_s)

    def _next(self) -> StereoFrame | None:
        if self._recording is not None:
            return self._recording.read_next()
        assert self._pairer is not None
        before = self._pairer.dropped
        frame = self._pairer.next_pair()
        if self._pairer.dropped > before:
            self.stats.add("dropped_skew", self._pairer.dropped - before)
        return frame

    def _restart(self) -> None:
        if self._recording is not None:
            self._recording.restart()
        else:
            assert self._pairer is not None
            self._pairer.left.close()
            self._pairer.right.close()
            self._open_pair()

    def read(self, timeout_s: float | None = None) -> StereoFrame | None:
        frame = self._next()
        if frame is None:
            if not self.options.loop or self._last_t is None or self._first_t is None:
                raise EndOfStream(self.spec)
            period = 1.0 / self.options.fps
            self._offset += (self._last_t - self._first_t) + period
            self._seq_offset = self._last_seq + 1
            self._first_t = None
            self._restart()
            frame = self._next()
            if frame is None:
                raise EndOfStream(self.spec)
        if self._first_t is None:
            self._first_t = frame.t_s
        self._last_t = frame.t_s
        if self._offset:
            frame.t_s += self._offset
            if frame.t_left_s is not None:
                frame.t_left_s += self._offset
            if frame.t_right_s is not None:
                frame.t_right_s += self._offset
        frame.seq += self._seq_offset
        self._last_seq = frame.seq
        if self.options.realtime:
            self._pacer.wait(frame.t_s)
        self.stats.delivered(frame)
        return frame

    def close(self) -> None:
        if self._recording is not None:
            self._recording.close()
        if self._pairer is not None:
            self._pairer.left.close()
            self._pairer.right.close()


class CameraSource:
    """Two capture devices grabbed together, or one side-by-side device split in halves.

    Both devices are *grabbed* first (fast), then retrieved, so that their grab times are as
    close as the drivers allow; a pair whose grab times differ by more than the skew is
    dropped and counted. A file path instead of a device index reads a video file the same
    way (tests without cameras).
    """

    kind: SourceKind = "camera"

    def __init__(self, left: str, right: str = "", options: SourceOptions | None = None) -> None:
        self.options = options or SourceOptions()
        self.spec = SourceSpec("camera", left, right).text
        self.stats = SourceStats()
        self.split = not right
        self.left = CaptureReader(left, self.options.fps)
        try:
            self.right = None if self.split else CaptureReader(right, self.options.fps)
        except Exception:
            self.left.close()
            raise
        self.seq = 0
        self.failures = 0

    def read(self, timeout_s: float | None = None) -> StereoFrame | None:
        ok_l = self.left.grab()
        ok_r = self.right.grab() if self.right is not None else ok_l
        got_l = self.left.retrieve() if ok_l else None
        got_r = self.right.retrieve() if self.right is not None and ok_r else None
        if got_l is None or (self.right is not None and got_r is None):
            self.failures += 1
            if not self.left.device:  # a file: its end
                raise EndOfStream(self.spec)
            if self.failures > 100:
                raise EndOfStream(f"{self.spec}: the device stopped delivering frames")
            return None
        self.failures = 0
        seq = self.seq
        self.seq += 1
        if self.right is None:
            t, img = got_l
            w = img.shape[1] // 2
            frame = StereoFrame(
                left=np.ascontiguousarray(img[:, :w]),
                right=np.ascontiguousarray(img[:, w : 2 * w]),
                t_s=t,
                seq=seq,
                t_left_s=t,
                t_right_s=t,
            )
        else:
            assert got_r is not None
            (tl, il), (tr, ir) = got_l, got_r
            if abs(tl - tr) > self.options.max_skew_s:
                self.stats.add("dropped_skew")
                return None
            frame = StereoFrame(il, ir, 0.5 * (tl + tr), seq, tl, tr)
        self.stats.delivered(frame)
        return frame

    def close(self) -> None:
        self.left.close()
        if self.right is not None:
            self.right.close()


def decode_image_bytes(data: bytes, name: str = "image") -> UInt8Array:
    """A pushed image (:func:`app.vision.io.decode_image`); ``SourceError`` if undecodable."""
    try:
        return decode_image(data, name)
    except ImageError as exc:
        raise SourceError(f"undecodable image ({exc})") from None


class PushSource:
    """Pairs pushed by the server's WebSocket handler: keeps only the newest (a pair not
    yet read when the next arrives is dropped and counted); decoding happens in ``read``
    (the stream thread, the right image on a helper thread meanwhile: OpenCV's decoder
    releases the GIL, so a pair costs one image's decoding time, not two), never in the
    handler."""

    kind: SourceKind = "push"

    def __init__(self, options: SourceOptions | None = None) -> None:
        self.options = options or SourceOptions()
        self.spec = "push"
        self.stats = SourceStats()
        self._cond = threading.Condition()
        self._pending: PushMessage | None = None
        self._closed = False
        self._last_seq: int | None = None
        self._pending_since = 0.0
        self.received = 0
        self.last_error: str | None = None
        self._decoder = ThreadPoolExecutor(1, thread_name_prefix="aar-push-decode")

    def begin_session(self) -> None:
        """A pusher (re)connected: its ``seq`` may start again from anywhere."""
        with self._cond:
            self._last_seq = None

    def put(self, message: PushMessage) -> PutResult:
        """Keep ``message`` as the newest pair; a pair whose ``seq`` repeats the previous
        one (``duplicate``) or goes back (``out_of_order``) within one pusher's session is
        counted and dropped (the filter's time must not run backwards)."""
        with self._cond:
            self.received += 1
            last = self._last_seq
            if last is not None and message.seq <= last:
                result: PutResult = "duplicate" if message.seq == last else "out_of_order"
                self.stats.add("seq_duplicate" if result == "duplicate" else "seq_out_of_order")
                return result
            self._last_seq = message.seq
            if self._pending is not None:
                self.stats.add("dropped_backpressure")
            else:
                self._pending_since = time.monotonic()
            self._pending = message
            self._cond.notify()
            return "queued"

    def pending_age_s(self) -> float | None:
        """How long the oldest unread pair has waited (None: nothing waits)."""
        with self._cond:
            if self._pending is None:
                return None
            return time.monotonic() - self._pending_since

    def read(self, timeout_s: float | None = None) -> StereoFrame | None:
        with self._cond:
            if self._pending is None and not self._closed:
                self._cond.wait(timeout_s)
            if self._closed:
                raise EndOfStream("push source closed")
            msg, self._pending = self._pending, None
        if msg is None:
            return None
        try:
            right_job = self._decoder.submit(decode_image_bytes, msg.right, "right")
        except RuntimeError:  # closed since the check above: its decoder is shut down
            raise EndOfStream("push source closed") from None
        try:
            try:
                left = decode_image_bytes(msg.left, "left")
            finally:
                right = right_job.result()
        except SourceError as exc:
            self.stats.add("rejected")
            self.last_error = f"pair {msg.seq}: {exc}"
            return None
        frame = StereoFrame(
            left, right, msg.t_s, msg.seq, msg.t_left_s, msg.t_right_s, msg.exposure_ms
        )
        if frame.skew_s > self.options.max_skew_s:
            self.stats.add("dropped_skew")
            return None
        self.stats.delivered(frame)
        return frame

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._decoder.shutdown(wait=False)


FrameSourceT = VideoSource | CameraSource | PushSource


def open_source(spec: str | SourceSpec, options: SourceOptions | None = None) -> FrameSourceT:
    """Open a (non-sim) source; :class:`SourceError` if it cannot be opened."""
    s = parse_source(spec) if isinstance(spec, str) else spec
    if s.kind is None:
        raise SourceError("'sim' is not a frame source (the simulation runs in the tick loop)")
    if s.kind == "push":
        return PushSource(options)
    if s.kind == "camera":
        return CameraSource(s.left, s.right, options)
    return VideoSource(s.left, s.right, options)
