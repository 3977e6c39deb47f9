"""Replay the stereo pairs of an MCAP log (:mod:`app.streams.mcap_log`) as a frame source.

``aar-dock track --left REC.mcap`` and ``serve --source mcap:REC.mcap``: the images of
``/camera/left/image`` and ``/camera/right/image`` paired by log time, with the pair's own
frame number and times from ``/camera/stereo_frame`` (else the log time, s), and the exact
calibration of the run (the ``aar-dock`` metadata record), so a replay gives the live poses.
A file cut by a crash is read up to its last complete chunk.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from app.geometry.calibration import CalibrationError, StereoCalibration
from app.streams.frames import (
    RecordedPairs,
    SourceError,
    SourceStats,
    StereoFrame,
)
from app.streams.mcap_log import TOPIC_FRAME, McapLogError, iter_messages, read_metadata
from app.vision.drogue import DrogueProfile, DrogueProfileError
from app.vision.io import decode_image
from app.vision.preprocess import ImageError

IMAGE_TOPICS = {"/camera/left/image": "left", "/camera/right/image": "right"}


def is_mcap(path: str | Path) -> bool:
    """A file named ``*.mcap`` (what the sources treat as an MCAP log)."""
    return str(path).lower().endswith(".mcap")


def mcap_calibration(path: str | Path) -> StereoCalibration | None:
    """The exact calibration stored in an MCAP log's metadata, or ``None``."""
    from app.streams.recording import exact_calibration

    try:
        meta = read_metadata(path)
    except McapLogError as exc:
        raise SourceError(str(exc)) from None
    text = meta.get("calibration")
    if not text:
        return None
    try:
        data = json.loads(text)
        StereoCalibration.from_dict(data)  # CalibrationError if not a valid calibration
    except (ValueError, CalibrationError) as exc:
        raise SourceError(f"{str(path)!r}: bad calibration in its metadata ({exc})") from None
    return exact_calibration(data)  # type: ignore[no-any-return]


def _decode(data: bytes, what: str) -> np.ndarray:
    try:
        return decode_image(data, what)
    except ImageError as exc:
        raise SourceError(f"cannot decode {what} ({exc})") from None


def mcap_drogue(path: str | Path) -> DrogueProfile | None:
    """The drogue profile in an MCAP log's metadata (``drogue``), or ``None``."""
    try:
        text = read_metadata(path).get("drogue")
    except McapLogError as exc:
        raise SourceError(str(exc)) from None
    if not text:
        return None
    try:
        return DrogueProfile.from_json(text, f"{str(path)!r}: its drogue metadata")
    except DrogueProfileError as exc:
        raise SourceError(str(exc)) from None


class McapRecordingSource(RecordedPairs):
    """The pairs of an MCAP log in order (``read_next``/``restart``/``close``, as
    :class:`~app.streams.recording.FrameRecordingSource`)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.spec = f"video:{self.path}"
        if not self.path.is_file():
            raise SourceError(f"no such MCAP file: {str(path)!r}")
        self.calibration = mcap_calibration(self.path)
        self.stats = SourceStats()
        self._it: Iterator[StereoFrame] | None = None
        first = self._pairs()
        try:
            self._first: StereoFrame | None = next(first)
        except StopIteration:
            raise SourceError(f"MCAP {str(path)!r} holds no stereo pair") from None
        self._it = first

    def _pairs(self) -> Iterator[StereoFrame]:
        topics = [*IMAGE_TOPICS, TOPIC_FRAME]
        pending: dict[int, dict[str, bytes]] = {}
        info: dict[int, dict[str, object]] = {}
        n = 0
        try:
            for msg in iter_messages(self.path, topics, decode=True):
                if msg.topic == TOPIC_FRAME:
                    info[msg.log_time_ns] = json.loads(msg.data)
                    continue
                part = pending.setdefault(msg.log_time_ns, {})
                data = getattr(msg.decoded, "data", None)  # foxglove.CompressedImage.data
                if not isinstance(data, bytes):
                    raise SourceError(f"{msg.topic} at log time {msg.log_time_ns}: no image")
                part[IMAGE_TOPICS[msg.topic]] = data
                if len(part) < 2:
                    continue
                del pending[msg.log_time_ns]
                i = info.pop(msg.log_time_ns, {})
                left = _decode(part["left"], f"the left image at log time {msg.log_time_ns}")
                right = _decode(part["right"], f"the right image at log time {msg.log_time_ns}")
                yield _frame(left, right, i, msg.log_time_ns, n)
                n += 1
        except McapLogError as exc:
            raise SourceError(str(exc)) from None

    def read_next(self) -> StereoFrame | None:
        if self._first is not None:
            frame, self._first = self._first, None
            return frame
        if self._it is None:
            return None
        try:
            return next(self._it)
        except StopIteration:
            self._it = None
            return None

    def restart(self) -> None:
        self._it = self._pairs()
        self._first = None

    def close(self) -> None:
        self._it = None
        self._first = None


def _frame(
    left: np.ndarray, right: np.ndarray, info: dict[str, object], log_ns: int, n: int
) -> StereoFrame:
    def opt(key: str) -> float | None:
        v = info.get(key)
        return None if v is None else float(v)  # type: ignore[arg-type]

    t = info.get("t_s")
    seq = info.get("seq")
    return StereoFrame(
        left=left,
        right=right,
        t_s=float(t) if t is not None else log_ns / 1e9,  # type: ignore[arg-type]
        seq=int(seq) if seq is not None else n,  # type: ignore[call-overload]
        t_left_s=opt("t_left_s"),
        t_right_s=opt("t_right_s"),
        exposure_ms=opt("exposure_ms"),
    )
