"""Issue 33 item 1, in process: the bounds of an MCAP replay (app/streams/mcap_source.py and
app/streams/mcap_log/reader.py) — record and message caps, the pending-pair buffer, lz4
chunks, image headers checked before decoding, corruption after good data final — and a
Hypothesis fuzz of the record fields (opcodes, lengths, compression, declared sizes, frame
JSON): a replay either gives pairs or fails with one ``SourceError``, never anything else."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import lz4.frame
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.writer import CompressionType

from app.streams.frames import SourceCorrupt, SourceError
from app.streams.mcap_log import McapLogError, ReadLimits, iter_messages
from app.streams.mcap_source import McapRecordingSource, PendingPairs, ReplayLimits
from tests.support.hostile_mcap import (
    LEFT,
    RIGHT,
    LogWriter,
    chunk,
    compressed_image,
    finish,
    head_records,
    message,
    png,
    record,
    tiny_messages,
    valid_log,
)


def _pairs(src: McapRecordingSource) -> int:
    n = 0
    while src.read_next() is not None:
        n += 1
    return n


def test_records_and_messages_are_capped(tmp_path: Path) -> None:
    p = tmp_path / "tiny.mcap"
    p.write_bytes(finish(head_records() + chunk(tiny_messages(200_000))))
    assert sum(1 for _ in iter_messages(p)) == 200_000
    with pytest.raises(McapLogError, match="more than 100000 messages"):
        sum(1 for _ in iter_messages(p, limits=ReadLimits(max_messages=100_000)))
    with pytest.raises(McapLogError, match="more than 150000 records"):
        sum(1 for _ in iter_messages(p, limits=ReadLimits(max_records=150_000)))
    with pytest.raises(McapLogError, match="a message record of 24 bytes"):
        sum(1 for _ in iter_messages(p, limits=ReadLimits(max_message_bytes=1)))


def test_pending_pairs_drop_the_oldest_within_count_and_bytes() -> None:
    pend = PendingPairs(max_pending=3, max_bytes=1000)
    for t in range(5):
        assert pend.add(t, "left", b"x" * 100) is None
    assert len(pend) == 3 and pend.dropped == 2 and pend.bytes == 300
    assert pend.add(4, "right", b"y" * 10) == (b"x" * 100, b"y" * 10)
    assert len(pend) == 2 and pend.bytes == 200
    assert pend.add(10, "left", b"z" * 950) is None  # over the bytes: the oldest two go
    assert len(pend) == 1 and pend.dropped == 4 and pend.bytes == 950


def test_unpaired_images_are_dropped_and_counted(tmp_path: Path) -> None:
    p = tmp_path / "unpaired.mcap"
    with p.open("wb") as fh:
        log = LogWriter.open(fh)
        log.pair(1_000_000_000, 0, png(), png(seed=1))
        for i in range(40):
            log.add(LEFT if i % 2 else RIGHT, 2_000_000_000 + i, compressed_image(png(seed=i)))
        log.pair(3_000_000_000, 1, png(), png(seed=1))
        log.finish()
    src = McapRecordingSource(p, ReplayLimits(max_pending=4))
    assert _pairs(src) == 2
    # all but the newest three: the second pair's left image is the fourth waiting
    assert src.stats.dropped_skew == 40 - 3


def test_an_lz4_log_replays_and_an_lz4_chunk_that_holds_more_is_refused(tmp_path: Path) -> None:
    p = valid_log(tmp_path / "lz4.mcap", 3, compression=CompressionType.LZ4)
    assert _pairs(McapRecordingSource(p)) == 3
    records = message(1, 10**9, compressed_image(bytes(1 << 20)))
    lying = chunk(records, "lz4", declared_size=1000, data=lz4.frame.compress(records))
    (tmp_path / "bomb.mcap").write_bytes(finish(head_records() + lying))
    with pytest.raises(SourceError, match="declares 1000 bytes uncompressed but holds more"):
        McapRecordingSource(tmp_path / "bomb.mcap")


def _huge_png() -> bytes:
    """A small PNG whose IHDR declares 30000 × 30000 px (CRC fixed: a decoder would try)."""
    data = bytearray(png())
    data[16:24] = struct.pack(">II", 30000, 30000)
    data[29:33] = struct.pack(">I", zlib.crc32(bytes(data[12:29])))
    return bytes(data)


def test_image_size_is_checked_on_the_header_before_decoding(tmp_path: Path) -> None:
    p = tmp_path / "huge.mcap"
    with p.open("wb") as fh:
        log = LogWriter.open(fh)
        log.pair(1_000_000_000, 0, _huge_png(), png())
        log.finish()
    with pytest.raises(SourceError, match=r"30000x30000 px PNG exceeds the limit of 40 Mpx"):
        McapRecordingSource(p)
    with pytest.raises(SourceError, match="exceeds the limit of 0.001 Mpx"):
        McapRecordingSource(valid_log(tmp_path / "v.mcap", 1), ReplayLimits(max_image_pixels=1000))


def test_corruption_after_good_pairs_is_final(tmp_path: Path) -> None:
    p = tmp_path / "late.mcap"
    with p.open("wb") as fh:
        log = LogWriter.open(fh)
        log.pair(1_000_000_000, 0, png(), png(seed=1))
        log.add("/camera/stereo_frame", 2_000_000_000, b'{"seq": 1, "t_s": 1e400}')
        log.add(LEFT, 2_000_000_000, compressed_image(png()))
        log.add(RIGHT, 2_000_000_000, compressed_image(png()))
        log.pair(3_000_000_000, 2, png(), png(seed=1))
        log.finish()
    src = McapRecordingSource(p)
    assert src.read_next() is not None
    for _ in range(2):  # again on the next call: never a normal end
        with pytest.raises(SourceCorrupt, match="t_s is not a finite number"):
            src.read_next()


def test_a_restart_stops_the_reader_it_replaces(tmp_path: Path) -> None:
    """A stalled stream is restarted while its old reader may still run in another thread:
    the old reader stops at its next message instead of reading on to the end."""
    p = tmp_path / "long.mcap"
    with p.open("wb") as fh:
        log = LogWriter.open(fh)
        log.pair(1_000_000_000, 0, png(), png(seed=1))
        for i in range(50):
            log.add(LEFT, 2_000_000_000 + 2 * i, compressed_image(png()))
        log.pair(3_000_000_000, 1, png(), png(seed=1))
        log.finish()
    src = McapRecordingSource(p)
    old = src._it  # noqa: SLF001 - the reader a stalled stream thread holds
    assert old is not None
    src.restart()
    assert next(old, None) is None  # it would have read on to the second pair
    assert _pairs(src) == 2  # the new reader starts from the beginning
    src.close()


# ---- fuzz ------------------------------------------------------------------------------------
json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda kids: (
        st.lists(kids, max_size=3) | st.dictionaries(st.text(max_size=6), kids, max_size=3)
    ),
    max_leaves=8,
)
frame_bodies = st.one_of(
    json_values.map(lambda v: json.dumps(v).encode()),
    st.fixed_dictionaries(
        {"seq": st.integers(-2, 2**64), "t_s": st.floats() | st.integers() | st.text(max_size=3)}
    ).map(lambda v: json.dumps(v).encode()),
    st.sampled_from([b'{"t_s": 1e400}', b"\xff\xfe", b"[" * 5000, b""]),
    st.binary(max_size=32),
)
payloads = st.one_of(
    st.just(compressed_image(png())),
    st.binary(max_size=64),
    st.sampled_from(
        [compressed_image(b""), compressed_image(_huge_png()), compressed_image(b"\x89PNG")]
    ),
)
messages = st.one_of(
    st.tuples(st.sampled_from([1, 2]), st.integers(0, 3), payloads).map(
        lambda m: message(m[0], 10**9 + m[1], m[2])
    ),
    st.tuples(st.integers(0, 3), frame_bodies).map(lambda m: message(3, 10**9 + m[0], m[1])),
    st.tuples(st.integers(0, 9), st.integers(0, 2**16), st.integers(0, 5)).map(
        lambda m: message(m[0], 10**9 + m[2], b"x" * (m[1] % 40))
    ),
    st.tuples(st.integers(0, 255), st.binary(max_size=24)).map(lambda r: record(r[0], r[1])),
    st.tuples(st.integers(0, 255), st.integers(0, 2**64 - 1), st.binary(max_size=24)).map(
        lambda r: struct.pack("<BQ", r[0], r[1]) + r[2]
    ),
)


@st.composite
def hostile_files(draw: st.DrawFn) -> bytes:
    out = head_records()
    for _ in range(draw(st.integers(0, 4))):
        records = b"".join(draw(st.lists(messages, max_size=6)))
        kind = draw(st.sampled_from(["top", "zstd", "lz4", "", "bogus"]))
        if kind == "top":
            out += records
            continue
        declared = draw(st.sampled_from([None, 0, 1, 2**50, 2**64 - 1]) | st.integers(0, 4096))
        out += chunk(records, kind if kind != "bogus" else "brotli", declared_size=declared)
    out = finish(out)
    cut = draw(st.none() | st.integers(0, len(out)))
    return out if cut is None else out[:cut]


@settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(data=hostile_files())
def test_fuzzed_record_fields_give_pairs_or_one_source_error(
    tmp_path_factory: pytest.TempPathFactory, data: bytes
) -> None:
    p = tmp_path_factory.mktemp("fuzz") / "f.mcap"
    p.write_bytes(data)
    try:
        for _ in iter_messages(p):
            pass
    except McapLogError as exc:
        assert "\n" not in str(exc)
    try:
        src = McapRecordingSource(p)
    except SourceError as exc:
        assert "\n" not in str(exc)
        return
    try:
        for _ in range(50):
            if src.read_next() is None:
                break
    except SourceCorrupt as exc:
        assert "\n" not in str(exc)
    finally:
        src.close()
