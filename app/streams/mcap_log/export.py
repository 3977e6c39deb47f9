"""Rebuilding a recording's MCAP log from its files — the telemetry JSONL and, if any, its frame
folder: an MCAP cut by a crash made complete again, or one made for a recording from before
MCAP existed (``aar-dock export-mcap``)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from app.geometry.calibration import StereoCalibration
from app.streams.mcap_log.channels import EncodedPair, McapStats, frame_info, tick_from_json
from app.streams.mcap_log.writer import McapLogWriter

if TYPE_CHECKING:
    from app.model.mount import CameraMount


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

    from app.streams.frame_log import read_index, recording_drogue

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
        drogue=None if frames_dir is None else recording_drogue(frames_dir),
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
                            "jpeg" if str(found["left"]).endswith(".jpg") else "png",
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
