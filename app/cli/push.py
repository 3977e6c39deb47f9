"""``aar-dock push``: read a stereo source on the camera computer and push its pairs to a
running service (WebSocket ``/api/v1/stream/push``, protocol in :mod:`app.streams.protocol`)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Callable

    import numpy as np


# the wire encoding by default: uncompressed, as a camera link carries pixels — exposure →
# LANDING_TARGET p99 ≈ 12 ms at 30 Hz against ≈ 17–20 ms for PNG, whose decoding alone is
# ≈ 5 ms a pair (docs/ecosystem.md; benchmarks/bench_mavlink_latency.py); png or jpg where
# the link's bandwidth is short
PUSH_FORMAT = "bmp"


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "push",
        help="push stereo pairs (videos, folders, cameras) to a service started with --source push",
        description=(
            "Read stereo pairs (two videos, folders or globs; a frame recording; two camera "
            "indices, or one side-by-side camera) and send them to the service's push "
            "WebSocket. The service keeps the newest pair; its drops are in GET /api/v1/stream."
        ),
    )
    p.add_argument(
        "--left",
        required=True,
        help="left video/folder/glob, camera index, or a *.frames recording",
    )
    p.add_argument("--right", default="", help="right input (omit: recording or side-by-side)")
    p.add_argument(
        "--url",
        required=True,
        help="ws://HOST:PORT/api/v1/stream/push, or the service's base URL "
        "(http://HOST:PORT: the push path is added)",
    )
    p.add_argument("--token", help="bearer token (AAR_TOKEN of the service)")
    p.add_argument("--fps", type=float, help="send at this rate (default: the source's times)")
    p.add_argument("--as-fast-as-possible", action="store_true", help="no pacing at all")
    p.add_argument(
        "--format",
        choices=("bmp", "png", "jpg"),
        default=PUSH_FORMAT,
        help="image encoding (bmp: uncompressed, the default: the lowest latency, as camera "
        "links (GigE Vision's Mono8) carry pixels; 79 MB/s for mono 1280x1024 pairs at 30 Hz, "
        "3x that in colour; png: lossless, no row filter and Huffman coding only, 2.5x "
        "smaller on dark frames, +5 ms of decoding; jpg: smaller still, lossy)",
    )
    p.add_argument("--jpeg-quality", type=int, default=95)
    p.add_argument("--count", type=int, help="stop after this many pairs")
    p.add_argument("--loop", action="store_true", help="restart file sources at their end")
    p.add_argument("--max-skew-ms", type=float, default=10.0)
    p.set_defaults(func=run)


PUSH_PATH = "/api/v1/stream/push"
RECONNECTS = 5  # a service that closes with 1013 (its stream restarts): reconnect this often


class UsageError(ValueError):
    """A bad argument: one line, exit code 2."""


def push_url(url: str) -> str:
    """The push WebSocket's URL: ``ws(s)://`` as given; ``http(s)://HOST:PORT[/]`` → the
    service's push route on ``ws(s)://``."""
    from urllib.parse import urlsplit, urlunsplit

    try:
        parts = urlsplit(url.strip())
        parts.port  # noqa: B018 - raises on a bad port
    except ValueError as exc:
        raise UsageError(f"--url {url!r}: {exc}") from None
    scheme = {"http": "ws", "https": "wss", "ws": "ws", "wss": "wss"}.get(parts.scheme.lower())
    if scheme is None or not parts.hostname:
        raise UsageError(
            f"--url {url!r}: give ws://HOST:PORT{PUSH_PATH} or the service's http://HOST:PORT"
        )
    path = parts.path
    if parts.scheme.lower() in ("http", "https") and path.rstrip("/") in ("", "/api/v1"):
        path = PUSH_PATH
    return urlunsplit((scheme, parts.netloc, path or PUSH_PATH, parts.query, ""))


def check_args(args: argparse.Namespace) -> None:
    if args.fps is not None and not args.fps > 0:
        raise UsageError(f"--fps must be a positive number, got {args.fps}")
    if args.count is not None and args.count < 1:
        raise UsageError(f"--count must be >= 1, got {args.count}")
    if not 1 <= args.jpeg_quality <= 100:
        raise UsageError(f"--jpeg-quality must be in 1..100, got {args.jpeg_quality}")
    if not args.max_skew_ms >= 0:
        raise UsageError(f"--max-skew-ms must be >= 0, got {args.max_skew_ms}")


def open_push_source(args: argparse.Namespace) -> Any:
    """Camera indices → :class:`CameraSource`; anything else → :class:`VideoSource`."""
    from app.streams.sources import CameraSource, SourceOptions, VideoSource

    paced = args.fps is None and not args.as_fast_as_possible
    options = SourceOptions(
        realtime=paced, loop=args.loop, fps=args.fps or 30.0, max_skew_s=args.max_skew_ms / 1e3
    )
    left, right = args.left.strip(), args.right.strip()
    if left.isdigit() and (not right or right.isdigit()):
        return CameraSource(left, right, options)
    return VideoSource(left, right, options)


def push_encoder(fmt: str, jpeg_quality: int) -> Callable[[np.ndarray], bytes]:
    """One image → its bytes on the wire (``--format``). ``png`` and ``jpg`` are the frame
    recordings' own codecs (``png`` is their ``png-huffman``: 4.9 ms to decode a noisy
    1280×1024 frame against 9.7 ms for deflate level 1 with adaptive row filters, and 23 %
    smaller); ``bmp`` is uncompressed (0.6 ms to decode, 1.3 MB a mono frame). Exposure →
    ``LANDING_TARGET`` per format: ``benchmarks/bench_mavlink_latency.py``."""
    from app.streams.frame_encoding import FrameEncoding

    if fmt == "png":
        return FrameEncoding("png-huffman").encode
    if fmt == "jpg":
        return FrameEncoding("jpeg", jpeg_quality=jpeg_quality).encode
    if fmt == "bmp":
        return encode_bmp
    raise UsageError(f"--format must be png, jpg or bmp, not {fmt!r}")


def encode_bmp(image: np.ndarray) -> bytes:
    """An uncompressed BMP (OpenCV's writer: 8-bit palette for mono, 24-bit for colour)."""
    import cv2

    ok, buf = cv2.imencode(".bmp", image)
    if not ok:
        raise OSError("bmp encoding failed")
    return bytes(buf.tobytes())


def run(args: argparse.Namespace) -> int:
    from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI
    from websockets.sync.client import connect

    from app.streams.frames import EndOfStream, SourceError
    from app.streams.protocol import encode_message

    try:
        check_args(args)
        url = push_url(args.url)
        source = open_push_source(args)
        encode = push_encoder(args.format, args.jpeg_quality)
    except (UsageError, SourceError) as exc:
        print(f"aar-dock push: {exc}", file=sys.stderr)
        return 2
    headers = {"Authorization": f"Bearer {args.token}"} if args.token else None
    sent = 0
    nbytes = 0
    t0 = time.monotonic()
    period = 1.0 / args.fps if args.fps else 0.0
    next_t = time.monotonic()
    stats: Any = None
    reconnects = 0
    try:
        while True:
            try:
                with connect(
                    url,
                    additional_headers=headers,
                    max_size=None,
                    compression=None,
                    open_timeout=10,
                    proxy=None,
                ) as ws:
                    while args.count is None or sent < args.count:
                        try:
                            frame = source.read(timeout_s=1.0)
                        except EndOfStream:
                            break
                        if frame is None:
                            continue
                        if period:
                            delay = next_t - time.monotonic()
                            if delay > 0:
                                time.sleep(delay)
                            next_t = max(next_t + period, time.monotonic() - period)
                        msg = encode_message(
                            encode(frame.left),
                            encode(frame.right),
                            t_s=frame.t_s,
                            seq=frame.seq,
                            exposure_ms=frame.exposure_ms,
                            t_left_s=frame.t_left_s,
                            t_right_s=frame.t_right_s,
                        )
                        ws.send(msg)
                        sent += 1
                        nbytes += len(msg)
                        try:  # the service answers only problems (at most one a second)
                            while True:
                                reply = ws.recv(timeout=0)
                                text = (
                                    reply.decode(errors="replace")
                                    if isinstance(reply, bytes)
                                    else reply
                                )
                                print(f"aar-dock push: service: {text}", file=sys.stderr)
                        except TimeoutError:
                            pass
                    stats = _final_stats(ws)
                break
            except ConnectionClosed as exc:
                rcvd = exc.rcvd
                if rcvd is None or rcvd.code != 1013 or reconnects >= RECONNECTS:
                    raise
                reconnects += 1  # the service's stream restarts: reconnect and go on
                print(f"aar-dock push: service: {rcvd.reason} (reconnecting)", file=sys.stderr)
                time.sleep(1.0)
    except InvalidURI as exc:
        print(f"aar-dock push: --url: {exc}", file=sys.stderr)
        return 2
    except ConnectionClosed as exc:
        rcvd = exc.rcvd
        why = f"{rcvd.code} {rcvd.reason}" if rcvd is not None else str(exc)
        print(f"aar-dock push: the service closed the connection: {why}", file=sys.stderr)
        return 1
    except (OSError, InvalidHandshake) as exc:
        print(f"aar-dock push: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    finally:
        source.close()
    wall = time.monotonic() - t0
    print(
        f"pushed {sent} pairs ({nbytes / 1e6:.1f} MB) in {wall:.1f} s "
        f"({sent / wall if wall > 0 else 0:.1f} pairs/s)"
    )
    if stats is not None:
        print("service " + json.dumps(stats))
    return 0 if sent else 1


def _final_stats(ws: Any) -> Any:
    """Ask the service for its counters (``stats``); None if it does not answer in 5 s."""
    ws.send("stats")
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        try:
            reply = json.loads(ws.recv(timeout=max(0.1, deadline - time.monotonic())))
        except TimeoutError:
            return None
        if isinstance(reply, dict) and "error" in reply:
            print(f"aar-dock push: service: {reply['error']}", file=sys.stderr)
            continue
        return reply
    return None
