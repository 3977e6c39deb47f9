"""The service's recordings as MCAP logs (``<id>.mcap``, :mod:`app.streams.mcap_log`).

Adapter between the tick loop's records (:class:`~app.model.tick.TickRecord` + the raw
tick) and the MCAP writer: one :class:`~app.streams.mcap_log.McapTick` per record (the
telemetry exactly as its JSONL line), the frame recording's own image bytes (PNG, or JPEG with
the lossy codec) for the images.
"""

from __future__ import annotations

from pathlib import Path

from app.geometry.calibration import StereoCalibration
from app.model.frames import RawFrame
from app.model.mount import CameraMount
from app.model.tick import TickRecord
from app.streams.mcap_log import (
    EncodedPair,
    ImageFormat,
    McapLogWriter,
    McapStats,
    McapTick,
    frame_info,
)
from app.types import JsonObject
from app.vision.drogue import DrogueProfile


def telemetry_schema() -> JsonObject:
    """The JSON schema of a tick record (``/telemetry``), titled ``aar_dock.TickRecord``."""
    schema: JsonObject = TickRecord.model_json_schema()
    schema["title"] = "aar_dock.TickRecord"
    return schema


def mcap_tick(record: TickRecord, line: bytes, raw: RawFrame | None = None) -> McapTick:
    """The MCAP view of one record (``line``: its JSONL line) and its raw tick's windows."""
    windows = None if raw is None else raw.image_windows_px
    return McapTick(
        seq=record.seq,
        t_s=record.t_s,
        wall_time=record.wall_time,
        telemetry_json=line.rstrip(b"\n"),
        pose=record.pose,
        uav_state=None if record.uav_state is None else tuple(record.uav_state),
        drogue_truth_m=record.drogue_truth_m,
        drogue_normal=record.drogue_normal,
        probe_tip_m=record.probe_tip_m,
        image_windows_px=None if windows is None else (list(windows[0]), list(windows[1])),
    )


class RecordingMcap:
    """The MCAP log of one recording (written by its own thread, never blocking a tick)."""

    def __init__(
        self,
        path: Path,
        calibration: StereoCalibration | None,
        mount: CameraMount | None,
        drogue: DrogueProfile | None = None,
        image_format: ImageFormat = "png",
    ) -> None:
        self.path = path
        self.image_format: ImageFormat = image_format
        self.writer = McapLogWriter(
            path,
            calibration=calibration,
            telemetry_schema=telemetry_schema(),
            mount=mount,
            drogue=drogue,
        )

    def on_record(self, record: TickRecord, line: bytes, raw: RawFrame | None = None) -> None:
        self.writer.write_tick(mcap_tick(record, line, raw))

    def on_pair(self, entry: JsonObject, left: bytes, right: bytes) -> None:
        """The frame writer's hook (``entry``: the pair's index line): the pair's encoded
        bytes, at its record's log time (``record_seq``; none: the pair's own)."""
        pair = EncodedPair(left, right, self.image_format, frame_info(entry))
        seq = entry.get("record_seq")
        self.writer.write_pair(pair, seq if isinstance(seq, int) else None)

    @property
    def bytes_on_disk(self) -> int:
        """The log's size so far (its finished chunks; 0 if it cannot be read)."""
        try:
            return self.path.stat().st_size
        except OSError:
            return 0

    def close(self) -> McapStats:
        return self.writer.close()
