"""One MCAP file per run (the field's log format, opened by Foxglove without configuration).

* :mod:`~app.streams.mcap_log.channels` — the channels (topics, schemas), what a tick and a pair
  contribute, the exposure clock that times them;
* :mod:`~app.streams.mcap_log.messages` — the Foxglove messages of one tick (transforms, pose,
  annotations, scene, calibration);
* :mod:`~app.streams.mcap_log.writer` — the logger (its own thread, bounded queue) and the MCAP
  file sink (chunked, flushed periodically: a kill leaves it readable up to its last chunk);
* :mod:`~app.streams.mcap_log.reader` — reading a log, complete or cut by a crash;
* :mod:`~app.streams.mcap_log.export` — rebuilding a recording's log from its JSONL and frames.
"""

from app.streams.mcap_log.channels import (
    FORMAT,
    METADATA_NAME,
    TOPIC_FRAME,
    TOPIC_POSE,
    TOPIC_SCENE,
    TOPIC_TELEMETRY,
    TOPIC_TF,
    TOPICS,
    EncodedPair,
    ExposureClock,
    FrameInfo,
    ImageFormat,
    McapLogError,
    McapStats,
    McapTick,
    RawPair,
    encode_image,
    encode_pair,
    frame_info,
    tick_from_json,
)
from app.streams.mcap_log.export import export_recording
from app.streams.mcap_log.messages import camera_calibration, right_in_left, z_to
from app.streams.mcap_log.reader import (
    DEFAULT_LIMITS,
    McapMessage,
    ReadLimits,
    is_complete,
    iter_messages,
    read_metadata,
)
from app.streams.mcap_log.writer import FoxgloveLogger, McapLogWriter, close_open_loggers

__all__ = [
    "DEFAULT_LIMITS",
    "FORMAT",
    "METADATA_NAME",
    "TOPICS",
    "TOPIC_FRAME",
    "TOPIC_POSE",
    "TOPIC_SCENE",
    "TOPIC_TELEMETRY",
    "TOPIC_TF",
    "EncodedPair",
    "ExposureClock",
    "FoxgloveLogger",
    "FrameInfo",
    "ImageFormat",
    "McapLogError",
    "McapLogWriter",
    "McapMessage",
    "McapStats",
    "McapTick",
    "RawPair",
    "ReadLimits",
    "camera_calibration",
    "close_open_loggers",
    "encode_image",
    "encode_pair",
    "export_recording",
    "frame_info",
    "is_complete",
    "iter_messages",
    "read_metadata",
    "right_in_left",
    "tick_from_json",
    "z_to",
]
