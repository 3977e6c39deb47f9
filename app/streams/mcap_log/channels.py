"""The MCAP log's channels and what is written on them: one tick (:class:`McapTick`), one
stereo pair (:class:`EncodedPair`, :class:`RawPair`) and the clock that times them.

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
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from app.model.pose import PoseResult
from app.streams.annotations import Side
from app.types import Rect

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


@dataclass
class McapStats:
    """What a writer wrote (and dropped: its queue full)."""

    path: str
    ticks: int = 0
    pairs: int = 0
    dropped: int = 0
    bytes: int = 0
    error: str | None = None


@dataclass(frozen=True)
class RawPair:
    """A stereo pair's images as arrays, encoded by the logger's thread (live: JPEG)."""

    left: NDArray[np.uint8]
    right: NDArray[np.uint8]
    info: FrameInfo


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
