"""MCAP files for the hardening tests (issue 33, cases 1–5), built with the ``mcap`` library's
own writer and records (independent of the reader under test) or byte by byte where the
file must lie: cut files, garbage schemas and messages, bad frame-time JSON, chunks that
declare or hold far more than they should, images that never pair, many tiny messages.

:func:`run_measured` runs a command as a child and reads its peak RSS from the outside
(``os.wait4``: the child's own ``ru_maxrss``)."""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import sys
import time
import zlib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import cv2
import lz4.frame
import numpy as np
import zstandard
from foxglove.messages import CompressedImage
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Header, Message, Schema
from mcap.writer import CompressionType, Writer

MAGIC = b"\x89MCAP0\r\n"
LEFT, RIGHT, FRAME = "/camera/left/image", "/camera/right/image", "/camera/stereo_frame"
REPO = Path(__file__).resolve().parents[2]


def image_schema() -> tuple[str, bytes]:
    s = CompressedImage.get_schema()
    return s.name, bytes(s.data)


def compressed_image(data: bytes, fmt: str = "png") -> bytes:
    return bytes(CompressedImage(format=fmt, data=data, frame_id="camera_left").encode())


def png(shape: tuple[int, int] = (48, 64), seed: int = 0) -> bytes:
    img = np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8)
    ok, buf = cv2.imencode(".png", img)
    assert ok
    return bytes(buf.tobytes())


@dataclass
class LogWriter:
    """A log on the replay's channels, written by the ``mcap`` library's writer."""

    writer: Writer
    channels: dict[str, int]

    @classmethod
    def open(
        cls,
        fh: Any,
        *,
        calibration: dict[str, Any] | None = None,
        compression: CompressionType = CompressionType.ZSTD,
        chunk_size: int = 1 << 20,
        schema_data: bytes | None = None,
    ) -> LogWriter:
        w = Writer(fh, chunk_size=chunk_size, compression=compression)
        w.start("aar-dock-test", "hostile")
        if calibration is not None:
            w.add_metadata("aar-dock", {"calibration": json.dumps(calibration)})
        name, data = image_schema()
        img = w.register_schema(name, "protobuf", data if schema_data is None else schema_data)
        frame = w.register_schema("aar_dock.StereoFrame", "jsonschema", b"{}")
        channels = {
            LEFT: w.register_channel(LEFT, "protobuf", img),
            RIGHT: w.register_channel(RIGHT, "protobuf", img),
            FRAME: w.register_channel(FRAME, "json", frame),
        }
        return cls(w, channels)

    def add(self, topic: str, log_ns: int, data: bytes) -> None:
        self.writer.add_message(self.channels[topic], log_ns, data, log_ns)

    def pair(self, log_ns: int, seq: int, left: bytes, right: bytes) -> None:
        t = log_ns / 1e9
        self.add(FRAME, log_ns, json.dumps({"seq": seq, "t_s": t}).encode())
        self.add(LEFT, log_ns, compressed_image(left))
        self.add(RIGHT, log_ns, compressed_image(right))

    def finish(self) -> None:
        self.writer.finish()


def valid_log(
    path: Path,
    pairs: int = 3,
    *,
    calibration: dict[str, Any] | None = None,
    shape: tuple[int, int] = (48, 64),
    compression: CompressionType = CompressionType.ZSTD,
) -> Path:
    with path.open("wb") as fh:
        log = LogWriter.open(fh, calibration=calibration, compression=compression)
        for i in range(pairs):
            log.pair(1_000_000_000 + i * 33_000_000, i, png(shape, i), png(shape, 100 + i))
        log.finish()
    return path


# ---- records written by hand -----------------------------------------------------------------
def record(opcode: int, body: bytes) -> bytes:
    return struct.pack("<BQ", opcode, len(body)) + body


def body_of(rec: Any) -> bytes:
    """A record's body as the ``mcap`` library writes it (without opcode and length)."""
    b = RecordBuilder()
    rec.write(b)
    return bytes(b.end()[9:])


def head_records(schema_name: str | None = None, schema_data: bytes | None = None) -> bytes:
    """Magic, header, the image schema and the three channels."""
    name, data = image_schema()
    out = MAGIC + record(Opcode.HEADER, body_of(Header("aar-dock-test", "hostile")))
    out += record(
        Opcode.SCHEMA,
        body_of(
            Schema(
                id=1,
                name=schema_name or name,
                encoding="protobuf",
                data=data if schema_data is None else schema_data,
            )
        ),
    )
    out += record(
        Opcode.SCHEMA,
        body_of(Schema(id=2, name="aar_dock.StereoFrame", encoding="jsonschema", data=b"{}")),
    )
    for cid, topic, enc, sid in ((1, LEFT, "protobuf", 1), (2, RIGHT, "protobuf", 1)):
        out += record(Opcode.CHANNEL, body_of(Channel(cid, topic, enc, {}, sid)))
    out += record(Opcode.CHANNEL, body_of(Channel(3, FRAME, "json", {}, 2)))
    return out


def message(channel_id: int, log_ns: int, data: bytes) -> bytes:
    return record(Opcode.MESSAGE, body_of(Message(channel_id, log_ns, data, log_ns, 0)))


def chunk(
    records: bytes,
    compression: str = "zstd",
    *,
    declared_size: int | None = None,
    data: bytes | None = None,
) -> bytes:
    """A chunk record holding ``records`` (or the compressed ``data`` given), declaring
    ``declared_size`` bytes uncompressed (default: the true size)."""
    if data is None:
        if compression == "zstd":
            data = zstandard.ZstdCompressor().compress(records)
        elif compression == "lz4":
            data = lz4.frame.compress(records)
        else:
            data = records
    size = len(records) if declared_size is None else declared_size
    crc = zlib.crc32(records) if declared_size is None else 0
    body = body_of(Chunk(compression, data, 2_000_000_000, 1_000_000_000, crc, size))
    return record(Opcode.CHUNK, body)


def finish(data: bytes) -> bytes:
    return data + record(Opcode.FOOTER, body_of(Footer(0, 0, 0))) + MAGIC


@lru_cache(maxsize=4)
def zstd_of_zeros(n_bytes: int, prefix: bytes = b"") -> bytes:
    """``prefix`` then ``n_bytes`` zeros, zstd-compressed as it streams (never in memory).
    Cached: the same bomb is replayed by ``track`` and by ``serve`` (immutable bytes)."""
    out = io.BytesIO()
    cctx = zstandard.ZstdCompressor(level=1)
    with cctx.stream_writer(out, size=len(prefix) + n_bytes, closefd=False) as w:
        w.write(prefix)
        block = bytes(1 << 20)
        left = n_bytes
        while left > 0:
            w.write(block[: min(left, len(block))])
            left -= len(block)
    return out.getvalue()


def tiny_messages(n: int, channel_id: int = 3) -> bytes:
    """``n`` message records of ``{}`` on ``channel_id``, each at its own log time."""
    rec = np.zeros(
        n,
        dtype=np.dtype(
            [
                ("op", "u1"),
                ("len", "<u8"),
                ("ch", "<u2"),
                ("seq", "<u4"),
                ("log", "<u8"),
                ("pub", "<u8"),
                ("data", "S2"),
            ]
        ),
    )
    rec["op"] = Opcode.MESSAGE
    rec["len"] = 22 + 2
    rec["ch"] = channel_id
    rec["log"] = 1_000_000_000 + np.arange(n, dtype=np.uint64)
    rec["pub"] = rec["log"]
    rec["data"] = b"{}"
    return rec.tobytes()


# ---- running a child and measuring it -----------------------------------------------------------
@dataclass(frozen=True)
class Measured:
    returncode: int
    stdout: str
    stderr: str
    peak_rss_mb: float
    wall_s: float


def run_measured(args: list[str], tmp: Path, timeout_s: float = 120.0) -> Measured:
    """Run ``python -m app ARGS`` from the repository and read the child's peak RSS (MB)
    from its own resource usage (``os.wait4`` on its pid: measured outside the child)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    out_path, err_path = tmp / "child.out", tmp / "child.err"
    t0 = time.monotonic()
    with out_path.open("wb") as out, err_path.open("wb") as err, open(os.devnull, "rb") as nul:
        proc = subprocess.Popen(
            [sys.executable, "-m", "app", *args],
            stdin=nul,
            stdout=out,
            stderr=err,
            cwd=REPO,
            env=env,
        )
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid == proc.pid:
                break
            if time.monotonic() - t0 > timeout_s:
                proc.kill()
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.02)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return Measured(
        proc.returncode,
        out_path.read_text(errors="replace"),
        err_path.read_text(errors="replace"),
        usage.ru_maxrss / 1024,  # KiB on Linux
        time.monotonic() - t0,
    )


MAX_RSS_MB = 1500.0  # the bound on a replay's peak RSS
MAX_WALL_S = 60.0  # and on its time


def unpaired_images(path: Path, n: int, size: int) -> Path:
    """``n`` left and ``n`` right images of ``size`` bytes, never at the same log time
    (8 messages a chunk, zstd: the file stays small)."""
    path.write_bytes(_unpaired_images_bytes(n, size))
    return path


@lru_cache(maxsize=2)
def _unpaired_images_bytes(n: int, size: int) -> bytes:
    """The file of :func:`unpaired_images`, built once per (n, size) in a test session (the
    same 2 GB-of-images log is replayed by ``track`` and by ``serve``; ≈ 2.5 s to build)."""
    cctx = zstandard.ZstdCompressor(level=1)
    blob = bytes(size)
    parts = [head_records()]
    for k in range(0, 2 * n, 8):
        records = b"".join(
            message(1 if i % 2 == 0 else 2, 1_000_000_000 + i * 1000, compressed_image(blob))
            for i in range(k, min(k + 8, 2 * n))
        )
        parts.append(chunk(records, data=cctx.compress(records)))
    return finish(b"".join(parts))
