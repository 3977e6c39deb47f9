"""``aar-dock track``: the navigation pipeline with tracking over a recorded stereo sequence.

One JSON line per pair: the :class:`~app.model.pose.PoseResult` contract plus ``frame``
(the source's frame number), ``t_s`` (its time) and ``mode`` (acquired / tracked / lost).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any, TextIO

from app.cli.drogue_options import add_drogue_options, drogue_from_args


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "track",
        help="run the pipeline with tracking over recorded stereo video or image folders",
        description=(
            "Track the drogue through a recorded sequence: two video files, two image folders "
            "or globs (--left/--right), a raw-frame recording folder (--left DIR) or an MCAP log "
            "(--left REC.mcap). Writes one JSON line per pair (PoseResult + frame + t_s), a "
            "summary, optional plots and an optional MCAP log for Foxglove."
        ),
    )
    p.add_argument(
        "--left", required=True, help="left video/folder/glob, a *.frames folder or a *.mcap log"
    )
    p.add_argument("--right", help="right video/folder/glob (omit for a frame recording)")
    p.add_argument(
        "--calib",
        help="stereo calibration JSON (default: the recording's, else "
        "sample_data/calibration.json)",
    )
    p.add_argument("--jsonl", help="write the per-pair results here ('-' = stdout)")
    p.add_argument("--plot", help="write plots of the drogue track into this folder")
    p.add_argument(
        "--fps",
        type=float,
        default=30.0,
        help="frame rate of image folders without timestamps.txt (default 30)",
    )
    p.add_argument(
        "--max-skew-ms",
        type=float,
        default=10.0,
        help="left/right pairing tolerance (default 10 ms)",
    )
    p.add_argument("--matcher", choices=("epipolar", "paper"), default="epipolar")
    add_drogue_options(p, "the recording's, else the paper's 75 mm ring")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument(
        "--mavlink",
        metavar="udpout:HOST:PORT",
        help="send each result as MAVLink 2 LANDING_TARGET (docs/ecosystem.md)",
    )
    p.add_argument(
        "--mount",
        choices=("jsbsim", "linear", "camera"),
        default=None,
        help="the rig's mount for MAVLink's body-frame position: an airframe's (default: the "
        "simulation's default plant) or 'camera' (relative to the left camera, looking forward)",
    )
    p.add_argument(
        "--mcap",
        metavar="OUT.mcap",
        help="also write an MCAP log (images, calibration, annotations, pose, telemetry; "
        "docs/ecosystem.md) for Foxglove",
    )
    p.add_argument(
        "--mcap-jpeg",
        type=int,
        metavar="QUALITY",
        help="JPEG images of this quality (1-100) in the MCAP log instead of lossless PNG",
    )
    p.set_defaults(func=run)


def _calibration(args: argparse.Namespace) -> Any:
    from app.geometry.calibration import StereoCalibration
    from app.resources import load_default_calibration
    from app.streams.frame_log import is_frame_recording, recording_calibration
    from app.streams.mcap_source import is_mcap, mcap_calibration

    if args.calib:
        return StereoCalibration.load(args.calib)
    if not args.right and is_mcap(args.left) and Path(args.left).is_file():
        calib = mcap_calibration(args.left)  # SourceError: not a readable MCAP
        if calib is not None:
            return calib
    if not args.right and is_frame_recording(args.left):
        calib = recording_calibration(args.left)
        if calib is not None:
            return calib
    return load_default_calibration()


def _mavlink(url: str, mount_name: str | None) -> tuple[Any, Any]:
    """The MAVLink link and the rig mount its positions are given in."""
    from app.sim.plant import DEFAULT_PLANT
    from app.streams.landing_target import RigMount
    from app.streams.mavlink_link import MavlinkLink, check_url

    check_url(url)
    if mount_name == "camera":
        mount = RigMount.forward_looking()
    else:
        from app.sim.rig_mount import default_mount

        mount = RigMount.on_airframe(default_mount(mount_name or DEFAULT_PLANT))
    return MavlinkLink(url), mount


def track_rows(source: Any, processor: Any, progress: bool = True) -> Any:
    """Yield ``(row dict, StreamTick)`` per pair until the source ends."""
    from tqdm import tqdm

    from app.streams.frames import EndOfStream
    from app.streams.sources import VideoSource

    total = source.pair_count if isinstance(source, VideoSource) else None
    with tqdm(total=total, unit="pair", disable=not progress, file=sys.stderr) as bar:
        while True:
            try:
                frame = source.read()
            except EndOfStream:
                return
            if frame is None:
                continue
            tick = processor.process(frame, source.kind)
            row = tick.pose.model_dump()
            row["frame"] = frame.seq
            row["t_s"] = frame.t_s
            row["mode"] = tick.mode
            bar.update(1)
            yield row, tick


def _plot(directory: Path, rows: list[dict[str, Any]], est: list[Any]) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    directory.mkdir(parents=True, exist_ok=True)
    t = np.array([r["t_s"] for r in rows])
    c = np.array(
        [r["drogue"]["center_mm"] if r["lock"] and r["drogue"] else [np.nan] * 3 for r in rows]
    )
    e = np.array([v if v is not None else [np.nan] * 3 for v in est]) * 1e3  # approach, mm
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 7))
    labels = ("X right (mm)", "Y down (mm)", "Z forward (mm)")
    est_index = (1, 2, 0)  # approach frame (x fwd, y right, z down) → camera axes
    for k, ax in enumerate(axes):
        ax.plot(t, c[:, k], ".", ms=3, label="measured (pipeline)")
        ax.plot(t, e[:, est_index[k]], "-", lw=1, label="filter estimate")
        ax.set_ylabel(labels[k])
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    axes[-1].set_xlabel("t (s)")
    fig.suptitle("Drogue centre, left-camera frame")
    fig.tight_layout()
    out1 = directory / "drogue_track.png"
    fig.savefig(out1, dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.plot(c[:, 0], c[:, 1], ".-", ms=3, lw=0.5)
    ax.invert_yaxis()
    ax.set_xlabel("X right (mm)")
    ax.set_ylabel("Y down (mm)")
    ax.set_title("Drogue centre seen from the camera")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    out2 = directory / "drogue_xy.png"
    fig.savefig(out2, dpi=110)
    plt.close(fig)
    return [out1, out2]


def run(args: argparse.Namespace) -> int:
    from app.geometry.calibration import CalibrationError
    from app.streams.frames import SourceError
    from app.streams.processor import StreamProcessor
    from app.streams.sources import SourceOptions, VideoSource
    from app.vision.drogue import PAPER_DROGUE, DrogueProfileError
    from app.vision.pipeline import PipelineConfig

    try:
        calib = _calibration(args)
    except (CalibrationError, OSError, SourceError) as exc:
        print(f"aar-dock track: {exc}", file=sys.stderr)
        return 2
    options = SourceOptions(
        realtime=False, loop=False, fps=args.fps, max_skew_s=args.max_skew_ms / 1e3
    )
    try:
        source = VideoSource(args.left, args.right or "", options)
    except SourceError as exc:
        print(f"aar-dock track: {exc}", file=sys.stderr)
        return 2
    try:  # --drogue, else the recording's own, else the paper's ring; --ring-radius-mm on top
        drogue = drogue_from_args(args, source.drogue or PAPER_DROGUE)
    except DrogueProfileError as exc:
        source.close()
        print(f"aar-dock track: {exc}", file=sys.stderr)
        return 2
    print(f"aar-dock track: drogue: {drogue.label}", file=sys.stderr)
    processor = StreamProcessor(calib, drogue.pipeline_config(PipelineConfig(matcher=args.matcher)))
    mavlink = None
    if args.mavlink:
        try:
            mavlink = _mavlink(args.mavlink, args.mount)
        except ValueError as exc:
            source.close()
            print(f"aar-dock track: {exc}", file=sys.stderr)
            return 2
    mcap = None
    if args.mcap:
        from app.cli.mcap_output import TrackMcap

        try:
            mcap = TrackMcap(args.mcap, calib, args.mcap_jpeg, drogue)
        except (OSError, ValueError) as exc:
            source.close()
            print(f"aar-dock track: cannot write {args.mcap}: {exc}", file=sys.stderr)
            return 2
    out: TextIO | None = None
    if args.jsonl == "-":
        out = sys.stdout
    elif args.jsonl:
        Path(args.jsonl).parent.mkdir(parents=True, exist_ok=True)
        out = open(args.jsonl, "w")  # noqa: SIM115
    rows: list[dict[str, Any]] = []
    est: list[Any] = []
    t0 = time.perf_counter()
    try:
        for row, tick in track_rows(source, processor, progress=not args.no_progress):
            if out is not None:
                out.write(json.dumps(row) + "\n")
            rows.append(row)
            est.append(tick.guidance.drogue_estimate_m)
            if mcap is not None:
                mcap.write(row, tick)
            if mavlink is not None:
                from app.streams.landing_target import landing_target

                link, mount = mavlink
                link.send(landing_target(tick.pose, max(0.0, float(row["t_s"])), mount))
    except SourceError as exc:
        print(f"aar-dock track: {exc}", file=sys.stderr)
        return 2
    finally:
        source.close()
        if mavlink is not None:
            mavlink[0].close()
        if out is not None and out is not sys.stdout:
            out.close()
        if mcap is not None and (error := mcap.close()) is not None:
            print(f"aar-dock track: MCAP {args.mcap}: {error}", file=sys.stderr)
    wall = time.perf_counter() - t0
    n = len(rows)
    locked = sum(1 for r in rows if r["lock"])
    summary = {
        "frames": n,
        "locked": locked,
        "lock_rate": locked / n if n else 0.0,
        "frames_per_s": n / wall if wall > 0 else 0.0,
        "dropped_unpaired": source.stats.dropped_skew,
        "tracked": sum(1 for r in rows if r["mode"] == "tracked"),
    }
    stream = sys.stderr if args.jsonl == "-" else sys.stdout
    print(
        f"frames {n} · locked {locked} ({100 * summary['lock_rate']:.1f} %) · "
        f"{summary['frames_per_s']:.1f} frames/s · tracked {summary['tracked']} · "
        f"unpaired frames dropped {summary['dropped_unpaired']}",
        file=stream,
    )
    print("summary " + json.dumps(summary), file=stream)
    if args.plot and rows:
        for path in _plot(Path(args.plot), rows, est):
            print(f"plot: {path}", file=stream)
    return 0 if n else 1
