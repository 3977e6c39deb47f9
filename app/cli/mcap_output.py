"""``aar-dock track --mcap``: the per-pair results of an offline run as an MCAP log.

The telemetry of each pair is the row ``track`` writes to its JSONL (PoseResult + frame +
t_s + mode); log time = the run's start (UNIX time) + the pair's time since the first pair.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Literal

from app.geometry.calibration import StereoCalibration
from app.model.pose import PoseResult
from app.streams.mcap_log import FrameInfo, McapLogWriter, McapTick, encode_pair
from app.streams.processor import StreamTick
from app.vision.drogue import DrogueProfile


def row_schema() -> dict[str, object]:
    """JSON schema of a ``track`` row: the PoseResult plus frame, t_s (s) and mode."""
    schema: dict[str, Any] = PoseResult.model_json_schema()
    schema["title"] = "aar_dock.TrackRow"
    schema.setdefault("properties", {}).update(
        {
            "frame": {"type": "integer", "description": "the source's frame number"},
            "t_s": {"type": "number", "description": "the pair's time (s, source clock)"},
            "mode": {"type": "string", "description": "acquired / tracked / lost / error"},
        }
    )
    return schema


class TrackMcap:
    """Writes each pair of a ``track`` run (images, calibration, annotations, pose, row)."""

    def __init__(
        self,
        path: str | Path,
        calibration: StereoCalibration,
        jpeg_quality: int | None = None,
        drogue: DrogueProfile | None = None,
    ) -> None:
        if jpeg_quality is not None and not 1 <= jpeg_quality <= 100:
            raise ValueError(f"--mcap-jpeg must be 1..100, got {jpeg_quality}")
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        self.jpeg_quality = jpeg_quality
        self.start_wall = time.time()
        self.writer = McapLogWriter(
            path,
            calibration=calibration,
            telemetry_schema=row_schema(),
            threaded=False,
            overwrite=True,  # as track's JSONL
            drogue=drogue,
        )

    def write(self, row: dict[str, Any], tick: StreamTick) -> None:
        f = tick.frame
        self.writer.write_tick(
            McapTick(
                seq=f.seq,
                t_s=f.t_s,
                wall_time=self.start_wall,
                telemetry_json=json.dumps(row).encode(),
                pose=tick.pose,
            )
        )
        info = FrameInfo(f.seq, f.t_s, f.t_left_s, f.t_right_s, f.exposure_ms)
        fmt: Literal["png", "jpeg"] = "png" if self.jpeg_quality is None else "jpeg"
        pair = encode_pair(f.left, f.right, info, fmt, self.jpeg_quality or 90)
        self.writer.write_pair(pair, f.seq)

    def close(self) -> str | None:
        """Finish the file; the write error, if there was one."""
        return self.writer.close().error
