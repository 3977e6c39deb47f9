"""Exposure → ``LANDING_TARGET`` on the wire: the transport delay an autopilot sees.

A real ``python -m app serve --mavlink udpout:127.0.0.1:PORT`` process (as deployed: the
simulation in its worker process, the upload workers started) and a ``pymavlink`` listener on
UDP loopback in this process, which notes the monotonic time each ``LANDING_TARGET`` arrives
(both processes read the same ``CLOCK_MONOTONIC``). Per case, ``--rounds`` rounds of
``--seconds`` each; per round the p50 and p99 of the latency; the table gives the median of
the rounds' figures.

* **pushed pairs at 30 Hz** (``--source push``, the ``aar-dock push`` protocol on the push
  WebSocket): the stream tests' rendered 1280×1024 sequence, encoded once as PNG with
  Huffman coding only (``--format png``, the push default until 2026-12-07), as PNG at
  deflate level 1 with adaptive filters (the default before that, the baseline), as JPEG
  (``--format jpg``, quality 95) and as uncompressed BMP (what ``aar-dock push`` sends by
  default); the camera computer's encoding is not counted. Each
  pair's ``t_s`` is this process's monotonic time when it is sent: its exposure, so the
  latency is ``arrival − time_usec`` (the service's work: receive, decode, track, filter,
  publish, send).
* **the simulated stream at 30 and 60 Hz** (``--mavlink-sim --tick-hz F``): a tick's exposure
  is the deadline it serves (the worker renders the frame due then); it is the record's
  publication time ``clock_s`` less its ``relay`` (deadline → record built), read back from
  ``GET /api/v1/history`` and matched to the target by ``time_usec`` = the tick's ``t_s``.

Then where a pushed pair's time goes, in this process (the profile behind the cuts): the two
images decoded one after the other (the baseline) against ``PushSource.read`` (the right one on
a helper thread meanwhile), the tracker (``StreamProcessor.process``) and the publication with
the MAVLink send (``TelemetryBus.publish`` → ``MavlinkOutput``), per encoding.

    .venv/bin/python benchmarks/bench_mavlink_latency.py [--rounds 3] [--seconds 10]
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402

from app.cli.push import push_encoder  # noqa: E402
from app.streams.processor import StreamProcessor  # noqa: E402
from app.streams.protocol import encode_message  # noqa: E402
from tests.support.streams_sequence import Sequence, cached_sequence  # noqa: E402


def _free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Listener:
    """``LANDING_TARGET`` arrivals: ``time_usec`` → (monotonic arrival s, position_valid)."""

    port: int
    arrivals: dict[int, tuple[float, int]] = field(default_factory=dict)
    stop: threading.Event = field(default_factory=threading.Event)
    ready: threading.Event = field(default_factory=threading.Event)

    def run(self) -> None:
        rx = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}", dialect="common")
        self.ready.set()
        try:
            while not self.stop.is_set():
                m = rx.recv_match(type="LANDING_TARGET", blocking=True, timeout=0.1)
                if m is not None:
                    self.arrivals[m.time_usec] = (time.monotonic(), m.position_valid)
        finally:
            rx.close()


@contextmanager
def service(*args: str) -> Iterator[tuple[Listener, str]]:
    """The listener, then the service; yields it with its API's base URL."""
    listener = Listener(_free_port(socket.SOCK_DGRAM))
    thread = threading.Thread(target=listener.run, daemon=True)
    thread.start()
    listener.ready.wait(10)
    port = _free_port(socket.SOCK_STREAM)
    tmp = tempfile.mkdtemp(prefix="bench-mavlink-")
    env = {k: v for k, v in os.environ.items() if not k.startswith("AAR_")}
    env.update(AAR_RECORDINGS_DIR=str(Path(tmp) / "rec"), PYTHONPATH=str(ROOT))
    cmd = [sys.executable, "-m", "app", "serve", "--no-viser", "--port", str(port)]
    cmd += ["--mavlink", f"udpout:127.0.0.1:{listener.port}", *args]
    log = (Path(tmp) / "serve.log").open("wb")
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=log)
    base = f"http://127.0.0.1:{port}/api/v1"
    try:
        deadline = time.monotonic() + 300
        while True:
            if proc.poll() is not None:
                raise SystemExit((Path(tmp) / "serve.log").read_text()[-2000:])
            try:
                if httpx.get(f"{base}/healthz", timeout=1).is_success:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                raise SystemExit("the service did not start")
            time.sleep(0.2)
        yield listener, base
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()
        listener.stop.set()
        thread.join(5)


def quantiles_ms(latencies_s: list[float]) -> tuple[float, float, int]:
    a = np.asarray(latencies_s) * 1e3
    return float(np.percentile(a, 50)), float(np.percentile(a, 99)), len(a)


def pushed_round(
    listener: Listener, base: str, pairs: list[tuple[bytes, bytes]], seconds: float, hz: float
) -> list[float]:
    """Push for ``seconds`` at ``hz``, t_s = the monotonic send time; the latencies (s)."""
    from websockets.sync.client import connect

    url = base.replace("http://", "ws://") + "/stream/push"
    sent: list[int] = []
    with connect(url, max_size=None, compression=None) as ws:
        t_next = time.monotonic()
        t_end = t_next + seconds
        i = 0
        while t_next < t_end:
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            left, right = pairs[i % len(pairs)]
            t_s = time.monotonic()
            ws.send(encode_message(left, right, t_s=t_s, seq=i))
            sent.append(round(t_s * 1e6))
            i += 1
            t_next += 1.0 / hz
    time.sleep(0.5)
    lat = [listener.arrivals[u][0] - u / 1e6 for u in sent if u in listener.arrivals]
    print(f"  pushed round: {len(sent)} sent, {len(lat)} received", file=sys.stderr)
    return lat


def sim_round(listener: Listener, base: str, seconds: float) -> list[float]:
    """The simulated stream's latencies (s) over ``seconds``: deadline → arrival."""
    time.sleep(seconds)
    hist = httpx.get(f"{base}/history", params={"seconds": seconds}, timeout=30).json()
    lat = []
    for rec in hist:
        relay = rec["timings_ms"].get("relay")
        hit = listener.arrivals.get(round(rec["t_s"] * 1e6))
        if relay is None or hit is None:
            continue
        lat.append(hit[0] - (rec["clock_s"] - relay / 1e3))
    print(f"  sim round: {len(hist)} ticks, {len(lat)} matched", file=sys.stderr)
    return lat


def profile_push_path(encoded: dict[str, list[tuple[bytes, bytes]]], seq: Sequence) -> None:
    """Median ms per pair of each service-side stage of a pushed pair (module docstring)."""
    from app.model.tick import StreamInfo
    from app.service import records
    from app.service.clock import MonotonicClock
    from app.service.mavlink_output import MavlinkOutput
    from app.service.telemetry_bus import TelemetryBus
    from app.sim.rig_mount import default_mount
    from app.streams.landing_target import RigMount
    from app.streams.protocol import decode_message
    from app.streams.sources import PushSource, decode_image_bytes

    print(
        "\n| encoding | decode L then R (ms) | PushSource.read (ms) | track (ms) | publish + send (ms) |"
    )
    print("|---|---|---|---|---|")
    for name, pairs in encoded.items():
        source, proc = PushSource(), StreamProcessor(seq.calib)
        bus = TelemetryBus(MonotonicClock(), 64)
        out = MavlinkOutput(
            f"udpout:127.0.0.1:{_free_port(socket.SOCK_DGRAM)}",
            RigMount.on_airframe(default_mount("jsbsim")),
            bus.sources,
        )
        bus.subscribe(out.on_tick)
        epoch = bus.sources.begin("push")
        t: dict[str, list[float]] = {"seq": [], "read": [], "track": [], "publish": []}
        for k in range(3 * len(pairs)):
            left, right = pairs[k % len(pairs)]
            t0 = time.perf_counter()
            decode_image_bytes(left), decode_image_bytes(right)
            t1 = time.perf_counter()
            source.put(decode_message(encode_message(left, right, t_s=k / 30, seq=k)))
            t2 = time.perf_counter()
            frame = source.read(1.0)
            t3 = time.perf_counter()
            assert frame is not None
            tick = proc.process(frame, "push")
            t4 = time.perf_counter()
            info = StreamInfo(
                spec="push",
                frame=k,
                frame_t_s=frame.t_s,
                mode=tick.mode,
                fps=30.0,
                pairs=k,
                dropped_skew=0,
                dropped_backpressure=0,
            )
            bus.publish(records.from_stream(tick, info, step_ms=0.0), run=0, epoch=epoch)
            t5 = time.perf_counter()
            for key, dt in (
                ("seq", t1 - t0),
                ("read", t3 - t2),
                ("track", t4 - t3),
                ("publish", t5 - t4),
            ):
                t[key].append(dt * 1e3)
        out.close()
        source.close()
        med = {key: float(np.median(v)) for key, v in t.items()}
        print(
            f"| {name} | {med['seq']:.1f} | {med['read']:.1f} | {med['track']:.1f} | "
            f"{med['publish']:.2f} |"
        )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    seq = cached_sequence(40)
    encoders: dict[str, Callable[[np.ndarray], bytes]] = {
        "PNG deflate 1 (push's default until 6 Dec 2026, the baseline)": lambda im: cv2.imencode(
            ".png", im, [cv2.IMWRITE_PNG_COMPRESSION, 1]
        )[1].tobytes(),
        "PNG Huffman (`--format png`)": push_encoder("png", 95),
        "JPEG 95": push_encoder("jpg", 95),
        "BMP (uncompressed, push's default)": push_encoder("bmp", 95),
    }
    encoded = {}
    for name, encode in encoders.items():
        images = [encode(im) for im in seq.lefts + seq.rights]
        encoded[name] = list(zip(images[:40], images[40:], strict=True))
    rows: list[tuple[str, list[tuple[float, float, int]]]] = []
    with service("--source", "push", "--no-sim") as (listener, base):
        for name, pairs in encoded.items():
            pushed_round(listener, base, pairs, 2.0, 30.0)  # warm-up (acquisition, caches)
            rounds = [
                quantiles_ms(pushed_round(listener, base, pairs, args.seconds, 30.0))
                for _ in range(args.rounds)
            ]
            rows.append((f"pushed pairs, {name}, 30 Hz", rounds))
    for hz in (30.0, 60.0):
        with service("--mavlink-sim", "--tick-hz", str(hz)) as (listener, base):
            time.sleep(2.0)
            rows.append(
                (
                    f"simulated stream, {hz:.0f} Hz",
                    [
                        quantiles_ms(sim_round(listener, base, args.seconds))
                        for _ in range(args.rounds)
                    ],
                )
            )
    print(f"\n{args.rounds} rounds of {args.seconds:g} s; the median of the rounds' figures\n")
    print("| case | p50 (ms) | p99 (ms) | targets per round | rounds' p99 (ms) |")
    print("|---|---|---|---|---|")
    for name, qs in rows:
        p50 = float(np.median([q[0] for q in qs]))
        p99 = float(np.median([q[1] for q in qs]))
        n = int(np.median([q[2] for q in qs]))
        each = ", ".join(f"{q[1]:.1f}" for q in qs)
        print(f"| {name} | {p50:.1f} | {p99:.1f} | {n} | {each} |")
    profile_push_path(encoded, seq)


if __name__ == "__main__":
    main()
