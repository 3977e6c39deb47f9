"""Raw-frame recordings: image pairs (lossless PNG by default, :mod:`app.streams.frame_encoding`)
+ per-pair times + the calibration used.

Layout of a frame recording directory (``<recording id>.frames`` next to the telemetry)::

    meta.json        {"format": "aar-dock-frames/1", "status": "recording"|"complete"|"failed", ...}
    calibration.json the StereoCalibration the live pipeline used
    drogue.json      the DrogueProfile it looked for (app.vision.drogue)
    frames.jsonl     one line per pair: {"i", "seq", "t_s", "t_left_s", "t_right_s",
                     "exposure_ms", "left", "right", "record_seq"}
    left/000000.png, right/000000.png, ... (``.jpg`` with the lossy ``jpeg`` codec)

Crash safety: each PNG is written to a temporary name and renamed; the pair's line is
appended (and flushed) only after both files are in place, and ``fsync``-ed every
``FSYNC_PERIOD_S``. A reader uses only complete lines whose two files exist, so a killed
writer leaves a readable recording up to its last flushed pair. Bounds: ``max_s`` seconds and
``max_bytes`` bytes of images; beyond them the writer stops accepting (``stop_reason``).
The writer runs in its own thread (the two PNGs of a pair encoded in parallel) behind a bounded queue: a pair that does not fit is
dropped and counted (``dropped``), never blocking the caller (the stream loop).
"""

from __future__ import annotations

import json
import os
import queue
import threading
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from app.model.frames import StereoFrame
from app.streams.frame_encoding import FrameEncoding
from app.streams.frames import RecordedPairs, SourceError, SourceStats
from app.vision.drogue import DrogueProfile, DrogueProfileError
from app.vision.io import read_image
from app.vision.preprocess import ImageError

if TYPE_CHECKING:
    from app.geometry.calibration import StereoCalibration

FORMAT = "aar-dock-frames/1"
FSYNC_PERIOD_S = 0.5


def is_frame_recording(path: str | Path) -> bool:
    p = Path(path)
    return p.is_dir() and (p / "frames.jsonl").is_file()


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)  # a torn temp file (disk full) must not keep its space
        raise


class FrameRecordingWriter:
    def __init__(
        self,
        directory: str | Path,
        calibration: Any,
        *,
        max_s: float = 300.0,
        max_bytes: int = 2_000_000_000,
        queue_pairs: int = 16,
        source: str | None = None,
        on_pair: Callable[[dict[str, Any], bytes, bytes], None] | None = None,
        drogue: DrogueProfile | None = None,
        encoding: FrameEncoding | None = None,
    ) -> None:
        """``on_pair(index line, left, right)``: called (in the writer's thread) once a pair is
        on disk, with the very bytes written (the MCAP log takes them from here); ``encoding``:
        the images' codec (default: lossless ``png-huffman``)."""
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=False)
        (self.directory / "left").mkdir()
        (self.directory / "right").mkdir()
        self.max_s, self.max_bytes = max_s, max_bytes
        self.pairs = 0
        self.bytes = 0
        self.dropped = 0
        self.stop_reason: str | None = None
        self.source = source
        self.on_pair = on_pair
        self.encoding = FrameEncoding() if encoding is None else encoding
        self._t0 = time.monotonic()
        self._queue: queue.Queue[tuple[StereoFrame, int | None] | None] = queue.Queue(queue_pairs)
        self._lines = open(self.directory / "frames.jsonl", "ab")
        self._last_sync = time.monotonic()
        self._closed = False
        # both images of a pair are encoded at once (OpenCV releases the GIL while encoding)
        self._pool = ThreadPoolExecutor(2, thread_name_prefix="frame-png")
        if calibration is not None:
            _atomic_write(
                self.directory / "calibration.json",
                json.dumps(calibration.to_dict(), indent=2).encode(),
            )
        if drogue is not None:
            _atomic_write(self.directory / "drogue.json", drogue.to_json().encode())
        self._write_meta("recording")
        self._thread = threading.Thread(target=self._run, name="frame-recorder", daemon=True)
        self._thread.start()

    @property
    def accepting(self) -> bool:
        return not self._closed and self.stop_reason is None

    def _meta(self, status: str) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "status": status,
            "pairs": self.pairs,
            "bytes": self.bytes,
            "dropped": self.dropped,
            "max_s": self.max_s,
            "max_bytes": self.max_bytes,
            "stop_reason": self.stop_reason,
            "source": self.source,
            "encoding": self.encoding.to_json(),
        }

    def _write_meta(self, status: str) -> None:
        _atomic_write(
            self.directory / "meta.json", json.dumps(self._meta(status), indent=2).encode()
        )

    def submit(self, frame: StereoFrame, record_seq: int | None = None) -> bool:
        """Queue a pair (never blocks); ``False`` if dropped (queue full, bound reached)."""
        if not self.accepting:
            return False
        if time.monotonic() - self._t0 >= self.max_s:
            self.stop_reason = f"reached {self.max_s:g} s"
            return False
        try:
            self._queue.put_nowait((frame, record_seq))
        except queue.Full:
            self.dropped += 1
            return False
        return True

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self.stop_reason is not None:
                continue
            try:
                self._write(*item)
            except Exception as exc:  # disk full, ...: stop, keep what is on disk
                self.stop_reason = f"write failed: {exc}"

    def _write(self, frame: StereoFrame, record_seq: int | None) -> None:
        i = self.pairs
        ext = self.encoding.extension
        names = (f"left/{i:06d}{ext}", f"right/{i:06d}{ext}")
        blobs = list(self._pool.map(self.encoding.encode, (frame.left, frame.right)))
        size = sum(len(b) for b in blobs)
        if self.bytes + size > self.max_bytes:
            self.stop_reason = f"reached {self.max_bytes / 1e6:g} MB"
            return
        for name, blob in zip(names, blobs, strict=True):
            _atomic_write(self.directory / name, blob)
        line = {
            "i": i,
            "seq": frame.seq,
            "t_s": frame.t_s,
            "t_left_s": frame.t_left_s,
            "t_right_s": frame.t_right_s,
            "exposure_ms": frame.exposure_ms,
            "left": names[0],
            "right": names[1],
            "record_seq": record_seq,
        }
        self._lines.write(json.dumps(line).encode() + b"\n")
        self._lines.flush()
        self.pairs += 1
        self.bytes += size
        if self.on_pair is not None:
            self.on_pair(line, blobs[0], blobs[1])
        now = time.monotonic()
        if now - self._last_sync >= FSYNC_PERIOD_S:
            os.fsync(self._lines.fileno())
            self._last_sync = now

    def close(self, reason: str = "stopped") -> dict[str, Any]:
        """Write what is queued, then the final metadata; returns it. A write error here
        (disk full, directory removed) does not raise: ``stop_reason`` says it and the
        returned metadata is the one that could not be written."""
        if not self._closed:
            self._closed = True
            self._queue.put(None)
            self._thread.join(timeout=60.0)
            self._pool.shutdown(wait=True)
            try:
                try:
                    self._lines.flush()
                    os.fsync(self._lines.fileno())
                finally:
                    self._lines.close()
            except OSError as exc:
                self.stop_reason = self.stop_reason or f"write failed: {exc}"
            if self.stop_reason is None:
                self.stop_reason = reason
            try:
                self._write_meta(self._final_status())
            except OSError as exc:
                if self._final_status() != "failed":
                    self.stop_reason = f"write failed: {exc}"
        return self._meta(self._final_status())

    def _final_status(self) -> str:
        return "failed" if (self.stop_reason or "").startswith("write failed") else "complete"


def read_index(directory: str | Path) -> list[dict[str, Any]]:
    """The complete pairs of a frame recording (a torn last line or missing file: skipped)."""
    d = Path(directory)
    out: list[dict[str, Any]] = []
    with open(d / "frames.jsonl", "rb") as f:
        for line in f:
            if not line.endswith(b"\n"):
                break
            try:
                entry = json.loads(line)
            except ValueError:
                break
            if (d / entry["left"]).is_file() and (d / entry["right"]).is_file():
                out.append(entry)
    return out


def exact_calibration(data: Mapping[str, Any]) -> StereoCalibration:
    """A :class:`StereoCalibration` from its ``to_dict()`` bit for bit (no re-validation:
    ``StereoCalibration.from_dict`` re-orthonormalises R and may move it by an ulp, and a
    replay must use the very numbers the live pipeline used)."""
    from app.geometry.calibration import CameraIntrinsics, StereoCalibration

    def cam(d: dict[str, Any]) -> CameraIntrinsics:
        return CameraIntrinsics(K=np.asarray(d["K"], float), dist=np.asarray(d["dist"], float))

    w, h = data["image_size"]
    return StereoCalibration(
        image_size=(int(w), int(h)),
        left=cam(data["left"]),
        right=cam(data["right"]),
        R=np.asarray(data["R"], float),
        T=np.asarray(data["T"], float),
    )


def recording_calibration(directory: str | Path) -> StereoCalibration | None:
    """The calibration stored with a frame recording (checked, then exact), or ``None``."""
    from app.geometry.calibration import StereoCalibration

    path = Path(directory) / "calibration.json"
    if not path.is_file():
        return None
    data = json.loads(path.read_text())
    StereoCalibration.from_dict(data)  # CalibrationError if it is not a valid calibration
    return exact_calibration(data)


def recording_drogue(directory: str | Path) -> DrogueProfile | None:
    """The drogue profile stored with a frame recording, or ``None`` (an older recording);
    ``SourceError`` for a bad one."""
    path = Path(directory) / "drogue.json"
    if not path.is_file():
        return None
    try:
        return DrogueProfile.load(path)
    except DrogueProfileError as exc:
        raise SourceError(str(exc)) from None


class FrameRecordingSource(RecordedPairs):
    """A frame recording as a source (``video:DIR``): the stored pairs with their times."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        if not is_frame_recording(self.directory):
            raise SourceError(f"{str(directory)!r} is not a frame recording (no frames.jsonl)")
        self.spec = f"video:{self.directory}"
        self.entries = read_index(self.directory)
        if not self.entries:
            raise SourceError(f"frame recording {str(directory)!r} holds no complete pair")
        self.index = 0
        self.stats = SourceStats()

    def read_next(self) -> StereoFrame | None:
        if self.index >= len(self.entries):
            return None
        e = self.entries[self.index]
        self.index += 1
        imgs = []
        for side in ("left", "right"):
            try:
                imgs.append(read_image(self.directory / e[side]))
            except ImageError as exc:
                raise SourceError(f"cannot decode {e[side]} ({exc})") from None
        frame = StereoFrame(
            left=imgs[0],
            right=imgs[1],
            t_s=float(e["t_s"]),
            seq=int(e["seq"]),
            t_left_s=e.get("t_left_s"),
            t_right_s=e.get("t_right_s"),
            exposure_ms=e.get("exposure_ms"),
        )
        return frame

    def restart(self) -> None:
        self.index = 0

    def close(self) -> None:
        self.index = len(self.entries)
