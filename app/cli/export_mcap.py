"""``aar-dock export-mcap RECORDING``: the MCAP log of a recording already on disk.

``RECORDING``: its telemetry (``rec-….jsonl``), its metadata (``rec-….json``) or its path
without the suffix. The frames of ``rec-….frames`` (if any) go in as they are (PNG bytes:
bit-exact), with that folder's calibration; the file is ``rec-….mcap`` unless ``-o`` says.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "export-mcap",
        help="write the MCAP log (Foxglove) of a recording on disk",
        description="Rebuild a recording's MCAP log from its telemetry JSONL and its frame "
        "folder (docs/ecosystem.md).",
    )
    p.add_argument("recording", help="rec-….jsonl, rec-….json or the recording's path stem")
    p.add_argument("-o", "--out", help="the MCAP file (default: next to the recording)")
    p.add_argument("--calib", help="stereo calibration JSON (default: the frame folder's)")
    p.add_argument("--force", action="store_true", help="replace an existing MCAP file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.geometry.calibration import CalibrationError, StereoCalibration
    from app.service.recording.mcap import telemetry_schema
    from app.sim.rig_mount import default_mount
    from app.streams.frame_log import recording_calibration
    from app.streams.mcap_log import export_recording

    given = Path(args.recording)
    stem = given.with_suffix("") if given.suffix in (".jsonl", ".json", ".mcap") else given
    tele = stem.with_name(stem.name + ".jsonl")
    if not tele.is_file():
        print(f"aar-dock export-mcap: no telemetry {str(tele)!r}", file=sys.stderr)
        return 2
    frames = stem.with_name(stem.name + ".frames")
    out = Path(args.out) if args.out else stem.with_name(stem.name + ".mcap")
    if out.exists() and not args.force:
        print(f"aar-dock export-mcap: {out} exists (--force replaces it)", file=sys.stderr)
        return 2
    try:
        calib: StereoCalibration | None
        if args.calib:
            calib = StereoCalibration.load(args.calib)
        else:
            calib = recording_calibration(frames) if frames.is_dir() else None
        stats = export_recording(
            tele,
            out,
            telemetry_schema=telemetry_schema(),
            frames_dir=frames if frames.is_dir() else None,
            calibration=calib,
            mount=default_mount(),
        )
    except (CalibrationError, OSError, ValueError) as exc:
        print(f"aar-dock export-mcap: {exc}", file=sys.stderr)
        return 2
    print(f"{out}: {stats.ticks} records, {stats.pairs} stereo pairs, {stats.bytes / 1e6:.2f} MB")
    return 0
