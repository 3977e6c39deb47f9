"""Frame recordings: MB per minute of each codec at 30 Hz, and that what they record replays.

Renders the default simulated stream (the service's ``SimConfig()``: 1280×1024 grey frames,
sensor noise σ = 2 DN, the 24-inch basket's LEDs), takes ``--pairs`` stereo pairs spread over
its first ``--ticks`` ticks, and encodes them with each codec of
:mod:`app.streams.frame_encoding`. Prints a table of medians: bytes of a pair, milliseconds to
encode one image, MB a minute of frames at ``--hz``, the same with the MCAP log's copy of the
frames, and the minutes the default frames budget (``AAR_RECORDING_FRAMES_MAX_MB``) holds.

Then the replay check: ``--replay`` pairs recorded with each codec (the frame writer of the
service, with the MCAP log fed by it) and replayed by ``aar-dock track --left REC.frames`` and
``--left REC.mcap``: the lossless codecs must give the very same poses as each other through
both paths; the lossy one is reported (locks and the largest centre difference).

    .venv/bin/python benchmarks/bench_recording.py [--pairs 12] [--ticks 240] [--replay 24]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from app.cli.main import main as cli_main
from app.model.frames import StereoFrame
from app.server.schemas import SimConfig
from app.service.recording.mcap import RecordingMcap, default_mount
from app.service.settings import Settings
from app.service.sim_source import docking_config
from app.sim.docking import DockingSimulation
from app.streams.frame_encoding import FrameEncoding
from app.streams.frame_log import FrameRecordingWriter

OPTIONS = (
    FrameEncoding(),
    FrameEncoding("png", png_level=1),
    FrameEncoding("png", png_level=6),
    FrameEncoding("png", png_level=9),
    FrameEncoding("jpeg", jpeg_quality=95),
    FrameEncoding("jpeg", jpeg_quality=90),
    FrameEncoding("jpeg", jpeg_quality=80),
)


def render(ticks: int, pairs: int) -> tuple[list[StereoFrame], Any]:
    """``pairs`` stereo pairs of the default simulated stream spread over ``ticks`` ticks."""
    config = SimConfig()
    sim = DockingSimulation(docking_config(config))
    every = max(1, ticks // pairs)
    out: list[StereoFrame] = []
    for i in range(ticks):
        tick = sim.step()
        if i % every == 0 and tick.left_image is not None and tick.right_image is not None:
            out.append(
                StereoFrame(
                    left=tick.left_image.copy(),
                    right=tick.right_image.copy(),
                    t_s=i / config.tick_hz,
                    seq=len(out),
                )
            )
        if len(out) >= pairs:
            break
    return out, config


def size_table(frames: list[StereoFrame], hz: float, budget_mb: float) -> None:
    h, w = frames[0].left.shape[:2]
    print(f"{len(frames)} pairs of {w}×{h} px from the default simulated stream, at {hz:g} Hz")
    print(
        f"{'codec':<22}{'lossless':>9}{'pair KB':>10}{'ms/image':>10}"
        f"{'MB/min':>9}{'+MCAP':>9}{'min in budget':>15}"
    )
    for enc in OPTIONS:
        sizes, times = [], []
        for f in frames:
            pair = 0
            for img in (f.left, f.right):
                t0 = time.perf_counter()
                pair += len(enc.encode(img))
                times.append((time.perf_counter() - t0) * 1e3)
            sizes.append(pair)
        pair_b = statistics.median(sizes)
        mb_min = pair_b * hz * 60 / 1e6
        print(
            f"{enc.label:<22}{'yes' if enc.lossless else 'no':>9}{pair_b / 1e3:>10.0f}"
            f"{statistics.median(times):>10.1f}{mb_min:>9.0f}{2 * mb_min:>9.0f}"
            f"{budget_mb / mb_min:>15.1f}"
        )


def record(frames: list[StereoFrame], enc: FrameEncoding, where: Path, config: Any) -> Path:
    """The pairs written as a frame recording with ``enc`` (and its MCAP log); the folder."""
    from app.resources import load_default_calibration

    calib = load_default_calibration()
    mcap = RecordingMcap(
        where / "rec.mcap", calib, default_mount(), config.drogue, enc.image_format
    )
    writer = FrameRecordingWriter(
        where / "rec.frames",
        calib,
        max_s=1e9,
        max_bytes=10**12,
        queue_pairs=len(frames) + 1,
        on_pair=mcap.on_pair,
        drogue=config.drogue,
        encoding=enc,
    )
    for f in frames:
        writer.submit(f, f.seq)
    meta = writer.close()
    mcap.close()
    assert meta["pairs"] == len(frames) and meta["dropped"] == 0, meta
    return where


def pose_key(row: dict[str, Any]) -> tuple[Any, ...]:
    """What a replay must reproduce of a pair (not its timings): lock, reason, tracker mode,
    LED ids and pixel centroids, the centre."""
    leds = tuple((d["id"], tuple(d["left_px"]), tuple(d["right_px"])) for d in row["leds"])
    drogue = row.get("drogue") or {}
    return (row["frame"], row["lock"], row["reason"], row["mode"], leds, drogue.get("center_mm"))


def track(path: Path, out: Path) -> list[dict[str, Any]]:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        code = cli_main(["track", "--left", str(path), "--jsonl", str(out), "--no-progress"])
    assert code == 0, (path, code)
    return [json.loads(x) for x in out.open()]


def centre(row: dict[str, Any]) -> np.ndarray | None:
    drogue = row.get("drogue")
    if not row.get("lock") or not drogue:
        return None
    return np.asarray(drogue["center_mm"], float)


def replay_check(frames: list[StereoFrame], config: Any) -> None:
    print(f"\nreplay: {len(frames)} pairs recorded with each codec, then track --left …")
    reference: list[dict[str, Any]] | None = None
    for enc in (
        o for o in OPTIONS if o.label in ("png-huffman", "png level 6", "jpeg q90 (lossy)")
    ):
        with tempfile.TemporaryDirectory() as tmp:
            d = record(frames, enc, Path(tmp), config)
            rows = {k: track(d / f"rec.{k}", d / f"{k}.jsonl") for k in ("frames", "mcap")}
        locks = {k: sum(bool(r["lock"]) for r in v) for k, v in rows.items()}
        keys = {k: [pose_key(r) for r in v] for k, v in rows.items()}
        if reference is None:
            reference = rows["frames"]
        if enc.lossless:
            ref_keys = [pose_key(r) for r in reference]
            identical = keys["frames"] == keys["mcap"] == ref_keys
            print(
                f"  {enc.label:<18} locks frames {locks['frames']}/{len(frames)}, mcap "
                f"{locks['mcap']}/{len(frames)}; identical to png-huffman through both: "
                f"{'yes' if identical else 'NO'}"
            )
            assert identical, enc.label
        else:
            diffs = [
                float(np.max(np.abs(a - b)))
                for r, ref in zip(rows["frames"], reference, strict=True)
                if (a := centre(r)) is not None and (b := centre(ref)) is not None
            ]
            worst = max(diffs) if diffs else float("nan")
            print(
                f"  {enc.label:<18} locks frames {locks['frames']}/{len(frames)}, mcap "
                f"{locks['mcap']}/{len(frames)}; largest centre difference to lossless "
                f"{worst:.2f} mm over {len(diffs)} pairs locked in both"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=12, help="pairs for the size table")
    ap.add_argument("--ticks", type=int, default=240, help="ticks of the run they are taken from")
    ap.add_argument("--replay", type=int, default=24, help="consecutive pairs for the replay")
    ap.add_argument("--hz", type=float, default=30.0)
    args = ap.parse_args()
    budget = Settings().recording_frames_max_mb
    spread, config = render(args.ticks, args.pairs)
    size_table(spread, args.hz, budget)
    run, _ = render(args.replay, args.replay)
    replay_check(run, config)


if __name__ == "__main__":
    main()
