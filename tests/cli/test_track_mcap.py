"""Issue 33, cases 1–3 and 5: hostile MCAP logs replayed by ``aar-dock track`` in a child
process. Each ends with one line on stderr and exit 2, or a clean replay; never a traceback;
the child's peak RSS, read from outside (``os.wait4``), stays ≤ 1.5 GB and it ends within
60 s. The files are built here (``tests/support/hostile_mcap.py``) at a scale that made the
reader before the fix exceed the memory bound (unpaired 1 MiB images, three million tiny
messages, a chunk of 1 GiB of zeros) or fail with a traceback."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from mcap.opcode import Opcode

from app.calibration.plausibility import DEFAULT_MAX_PIXELS, validated
from app.geometry.calibration import CalibrationError
from app.resources import load_default_calibration
from app.streams.mcap_log import TOPIC_FRAME
from tests.support.hostile_mcap import (
    FRAME,
    LEFT,
    MAX_RSS_MB,
    MAX_WALL_S,
    RIGHT,
    LogWriter,
    Measured,
    chunk,
    compressed_image,
    finish,
    head_records,
    png,
    record,
    run_measured,
    tiny_messages,
    unpaired_images,
    valid_log,
    zstd_of_zeros,
)

MiB = 1 << 20


def _track(path: Path, tmp: Path) -> Measured:
    got = run_measured(["track", "--left", str(path), "--no-progress"], tmp, timeout_s=120)
    assert "Traceback" not in got.stderr, got.stderr[-2000:]
    assert got.peak_rss_mb <= MAX_RSS_MB, (path.name, got.peak_rss_mb)
    assert got.wall_s <= MAX_WALL_S, (path.name, got.wall_s)
    return got


def _error_lines(stderr: str) -> list[str]:
    """stderr without the line saying which drogue the replay looks for (it names the
    recording's profile, or the paper's ring, before any frame is read)."""
    return [ln for ln in stderr.splitlines() if not ln.startswith("aar-dock track: drogue: ")]


def _refused(path: Path, tmp: Path, *words: str) -> Measured:
    got = _track(path, tmp)
    assert got.returncode == 2, (got.returncode, got.stderr[-2000:])
    lines = _error_lines(got.stderr)
    assert len(lines) == 1 and lines[0].startswith("aar-dock track: "), got.stderr[-2000:]
    for w in words:
        assert w in lines[0], (w, lines[0])
    return got


def _bytes(tmp: Path, name: str, data: bytes) -> Path:
    p = tmp / name
    p.write_bytes(data)
    return p


def test_a_zstd_chunk_of_1_gib_zeros_and_one_declaring_1_pib_are_refused(tmp_path: Path) -> None:
    # one image message of 1 GiB of zeros: its record head, then the zeros (35 KB compressed)
    head = struct.pack("<BQHIQQ", Opcode.MESSAGE, (1 << 30) - 9, 1, 0, 10**9, 10**9)
    bomb = zstd_of_zeros((1 << 30) - len(head), prefix=head)
    honest = _bytes(
        tmp_path,
        "honest.mcap",
        finish(head_records() + chunk(b"", data=bomb, declared_size=1 << 30)),
    )
    lying = _bytes(
        tmp_path, "lying.mcap", finish(head_records() + chunk(b"", data=bomb, declared_size=MiB))
    )
    pib = _bytes(tmp_path, "pib.mcap", finish(head_records() + chunk(b"", declared_size=2**50)))
    # a chunk whose compressed data field declares 1 PiB (the record itself 50 bytes)
    body = struct.pack("<QQQI", 0, 0, 100, 0) + struct.pack("<I", 4) + b"zstd"
    body += struct.pack("<Q", 2**50) + bytes(10)
    field = _bytes(tmp_path, "field.mcap", finish(head_records() + record(Opcode.CHUNK, body)))
    assert honest.stat().st_size < 64 * 1024
    _refused(honest, tmp_path, "over the limit")
    _refused(lying, tmp_path, "holds more")
    _refused(pib, tmp_path, "1125899906842624 bytes uncompressed, over the limit")
    _refused(field, tmp_path, "a field of 1125899906842624 bytes runs past its record")


def test_a_chunk_of_200_mb_of_zero_records_is_refused(tmp_path: Path) -> None:
    zeros = zstd_of_zeros(200 * MiB)
    p = _bytes(
        tmp_path,
        "zeros.mcap",
        finish(head_records() + chunk(b"", data=zeros, declared_size=200 * MiB)),
    )
    assert p.stat().st_size < 32 * 1024
    _refused(p, tmp_path, "opcode 0x00 is not allowed in a chunk")


def test_images_that_never_pair_stay_bounded_and_end_cleanly(tmp_path: Path) -> None:
    p = unpaired_images(tmp_path / "unpaired.mcap", 1000, MiB)  # 2 GB of images, one side each
    assert p.stat().st_size < 8 * MiB
    _refused(p, tmp_path, "holds no stereo pair")


def test_three_million_tiny_messages_stay_bounded(tmp_path: Path) -> None:
    p = _bytes(tmp_path, "tiny.mcap", finish(head_records() + chunk(tiny_messages(3_000_000))))
    _refused(p, tmp_path, "holds no stereo pair")


HOSTILE_JSON: list[tuple[str, bytes, str]] = [
    ("list", b"[1, 2]", "not a JSON object (a list)"),
    ("string", b'"frame"', "not a JSON object (a str)"),
    ("inf", b'{"seq": 0, "t_s": 1e400}', "t_s is not a finite number"),
    ("utf8", b'{"seq": 0, "t_s": "\xff\xfe"}', "not a JSON object"),
    ("nested", b"[" * 100_000, "not a JSON object"),
]


@pytest.mark.parametrize(("name", "body", "words"), HOSTILE_JSON, ids=[h[0] for h in HOSTILE_JSON])
def test_frame_times_that_are_not_an_object_of_finite_numbers(
    tmp_path: Path, name: str, body: bytes, words: str
) -> None:
    p = tmp_path / f"{name}.mcap"
    with p.open("wb") as fh:
        log = LogWriter.open(fh)
        log.add(FRAME, 1_000_000_000, body)
        log.add(LEFT, 1_000_000_000, compressed_image(png()))
        log.add(RIGHT, 1_000_000_000, compressed_image(png(seed=1)))
        log.finish()
    _refused(p, tmp_path, TOPIC_FRAME, words)


def _garbage_message(p: Path) -> Path:
    with p.open("wb") as fh:
        log = LogWriter.open(fh)
        log.add(LEFT, 1_000_000_000, b"\xff" * 40)  # not a protobuf CompressedImage
        log.add(RIGHT, 1_000_000_000, compressed_image(png()))
        log.finish()
    return p


def test_garbage_schemas_and_messages(tmp_path: Path) -> None:
    # a garbage schema is never parsed: the images are read with Foxglove's own schema
    p = tmp_path / "schema.mcap"
    with p.open("wb") as fh:
        log = LogWriter.open(fh, schema_data=np.random.default_rng(0).bytes(400))
        log.pair(1_000_000_000, 0, png(), png(seed=1))
        log.finish()
    got = _track(p, tmp_path)
    assert got.returncode == 0 and got.stdout.count("\n") >= 2, got.stderr[-2000:]
    _refused(
        _garbage_message(tmp_path / "message.mcap"), tmp_path, "corrupt foxglove.CompressedImage"
    )
    renamed = _bytes(tmp_path, "renamed.mcap", finish(head_records(schema_name="x.Image")))
    _refused(renamed, tmp_path, "holds no stereo pair")


def test_files_cut_to_1_to_200_bytes(tmp_path: Path) -> None:
    whole = valid_log(tmp_path / "whole.mcap", 2).read_bytes()
    from app.cli.main import main as cli_main

    for n in (*range(1, 40, 3), *range(40, 201, 16)):
        p = _bytes(tmp_path, f"cut{n}.mcap", whole[:n])
        assert cli_main(["track", "--left", str(p), "--no-progress"]) == 2, n
    _refused(p, tmp_path, "not a readable MCAP")


def test_a_degenerate_calibration_is_refused_with_the_put_calibration_message(
    tmp_path: Path,
) -> None:
    data = load_default_calibration().to_dict()
    data["left"]["K"][0][0] = 1e-300
    with pytest.raises(CalibrationError) as put_says:  # what PUT /calibration answers
        validated(data, DEFAULT_MAX_PIXELS)
    w, h = data["image_size"]
    p = valid_log(tmp_path / "calib.mcap", 1, calibration=data, shape=(h, w))
    _refused(p, tmp_path, str(put_says.value), "fx = 1e-300")


def test_corrupt_message_after_good_data_is_reported_and_exit_2(tmp_path: Path) -> None:
    p = tmp_path / "late.mcap"
    with p.open("wb") as fh:
        log = LogWriter.open(fh)
        for i in range(2):
            log.pair(1_000_000_000 + i * 33_000_000, i, png(seed=i), png(seed=10 + i))
        log.add(LEFT, 2_000_000_000, b"\x0a\xff\xff\xff\xff\x0f")  # a truncated protobuf
        log.add(RIGHT, 2_000_000_000, compressed_image(png()))
        log.finish()
    got = run_measured(["track", "--left", str(p), "--jsonl", "-", "--no-progress"], tmp_path)
    assert got.returncode == 2 and "Traceback" not in got.stderr
    rows = [json.loads(line) for line in got.stdout.splitlines()]
    assert [r["frame"] for r in rows] == [0, 1]  # the good pairs, then the corruption
    lines = _error_lines(got.stderr)
    assert len(lines) == 1 and "corrupt foxglove.CompressedImage" in lines[0], got.stderr
    assert "at log time 2000000000" in lines[0]
