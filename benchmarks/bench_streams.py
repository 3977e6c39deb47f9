"""Cost of a stream source per stereo pair: decoding vs tracking, and the whole stream loop.

Over a rendered 1280×1024 sequence (the stream tests' sequence, ``tests/support/streams_sequence.py``)
written as MJPG videos and as PNG folders, per pair, in the same run:

* ``tracker (in memory)`` — :class:`StereoTracker` on pairs already in memory (the baseline);
* ``read MJPG`` / ``read PNG`` — the source alone (``VideoSource``: decode + pairing);
* ``read + track + guidance`` — :class:`StreamProcessor` behind the source, i.e. what
  ``aar-dock track`` and the service's stream thread do per pair;
* ``push encode (PNG)`` — what ``aar-dock push`` spends encoding one pair.

Prints a Markdown table: median and p90 ms per pair and the ratio to the baseline. Then the
service's responsiveness: ``GET /api/v1/healthz`` latency (in process, 300 requests) with no
source running (the baseline) and while the stream thread runs the MJPG video as fast as
possible (its frame rate alongside).

    .venv/bin/python benchmarks/bench_streams.py [--frames 40] [--repeats 3]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from app.cli.push import push_encoder  # noqa: E402
from app.resources import load_default_calibration  # noqa: E402
from app.streams.frames import EndOfStream  # noqa: E402
from app.streams.processor import StreamProcessor  # noqa: E402
from app.streams.sources import SourceOptions, VideoSource  # noqa: E402
from app.vision.tracking import StereoTracker  # noqa: E402
from tests.support.streams_sequence import render_sequence, write_avi, write_png_folders  # noqa: E402


def per_pair(run: Callable[[], int], repeats: int) -> list[float]:
    out: list[float] = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        n = run()
        out.append((time.perf_counter() - t0) * 1e3 / n)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    calib = load_default_calibration()
    seq = render_sequence(calib, args.frames)
    d = Path(tempfile.mkdtemp(prefix="bench-streams-"))
    la, ra = write_avi(seq, d)
    lp, rp = write_png_folders(seq, d)
    fast = SourceOptions(realtime=False)

    def tracker_in_memory() -> int:
        tr = StereoTracker(calib)
        for left, right in zip(seq.lefts, seq.rights, strict=True):
            tr.update(left, right)
        return len(seq.lefts)

    def read(left: Path, right: Path, process: bool) -> Callable[[], int]:
        def run() -> int:
            src = VideoSource(str(left), str(right), fast)
            proc = StreamProcessor(calib) if process else None
            n = 0
            while True:
                try:
                    frame = src.read()
                except EndOfStream:
                    return n
                if frame is not None:
                    n += 1
                    if proc is not None:
                        proc.process(frame)

        return run

    def encode(fmt: str) -> Callable[[], int]:
        encode_image = push_encoder(fmt, 95)

        def run() -> int:
            for left, right in zip(seq.lefts, seq.rights, strict=True):
                encode_image(left), encode_image(right)
            return len(seq.lefts)

        return run

    rows = [
        ("tracker (in memory, baseline)", tracker_in_memory),
        ("read MJPG .avi pair", read(la, ra, False)),
        ("read PNG folders pair", read(lp, rp, False)),
        ("read MJPG + track + guidance", read(la, ra, True)),
        ("read PNG + track + guidance", read(lp, rp, True)),
        ("push: encode a pair as PNG (Huffman only)", encode("png")),
        ("push: encode a pair as JPEG 95", encode("jpg")),
        ("push: encode a pair as BMP", encode("bmp")),
    ]
    results = [(name, per_pair(fn, args.repeats)) for name, fn in rows]
    base = float(np.median(results[0][1]))
    w, h = calib.image_size
    print(f"{args.frames} pairs of {w}×{h}, {args.repeats} repeats; ms per stereo pair\n")
    print("| stage | median ms | p90 ms | × tracker |")
    print("|---|---|---|---|")
    for name, vals in results:
        med = float(np.median(vals))
        print(f"| {name} | {med:.2f} | {np.quantile(vals, 0.9):.2f} | {med / base:.2f} |")
    service_latency(la, ra, d)


def service_latency(left: Path, right: Path, tmp: Path) -> None:
    from fastapi.testclient import TestClient

    from app.server.main import create_app
    from app.service.settings import Settings

    settings = Settings(
        viser_enabled=False,
        sim_autostart=False,
        recordings_dir=tmp / "rec",
        stream_realtime=False,
        stream_loop=True,
    )
    with TestClient(create_app(settings)) as c:

        def latency() -> tuple[float, float]:
            out = []
            for _ in range(300):
                t0 = time.perf_counter()
                c.get("/api/v1/healthz")
                out.append((time.perf_counter() - t0) * 1e3)
            return float(np.median(out)), float(np.quantile(out, 0.99))

        idle = latency()
        c.app.state.aar.streams.switch(f"video:{left},{right}")  # type: ignore[attr-defined]
        time.sleep(1.0)
        f0, t0 = c.get("/api/v1/stream").json()["frames"], time.monotonic()
        busy = latency()
        fps = (c.get("/api/v1/stream").json()["frames"] - f0) / (time.monotonic() - t0)
    print("\n| GET /healthz (in process) | median ms | p99 ms | × idle (median) |")
    print("|---|---|---|---|")
    print(f"| no source (baseline) | {idle[0]:.2f} | {idle[1]:.2f} | 1.00 |")
    print(
        f"| MJPG stream as fast as possible ({fps:.0f} pairs/s) | {busy[0]:.2f} | "
        f"{busy[1]:.2f} | {busy[0] / idle[0]:.2f} |"
    )


if __name__ == "__main__":
    main()
