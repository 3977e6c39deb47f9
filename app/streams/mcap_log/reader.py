"""Reading an MCAP log, complete or cut by a crash (up to its last complete record), with
bounded memory and time whatever the file holds: its messages in file order
(:func:`iter_messages`), its ``aar-dock`` metadata record (:func:`read_metadata`) and whether
it was finished (:func:`is_complete`).

The records are framed here (opcode, length) and parsed by the ``mcap`` library's record
classes (``Chunk.read``, ``Message.read``, …), each from exactly the bytes its length
declares. The ``mcap`` stream reader is not used: it decompresses a whole chunk with no limit
(lz4 unbounded, zstd to the size the frame claims) and reads a field's declared length from
the file before checking it. Here, before anything is allocated or decompressed:

* a record longer than :attr:`ReadLimits.max_record_bytes` is refused (a cut file's last
  record, longer than what is left of the file, ends the reading: the crash case);
* a chunk whose declared uncompressed size exceeds :attr:`ReadLimits.max_chunk_bytes` is
  refused; it is decompressed into at most that many bytes (zstd's stream reader, lz4 frame's
  ``max_length``) and must give exactly its declared size and CRC;
* the records of a chunk are read one at a time (never all in a list), and the whole file
  may hold at most :attr:`ReadLimits.max_records` records and
  :attr:`ReadLimits.max_messages` messages.

Everything a file can be wrong in (a field, a length, a compression, a string that is not
UTF-8) is one :class:`~app.streams.mcap_log.channels.McapLogError` naming the byte offset;
only the end of the file in the middle of a record is a normal end (logged).
"""

from __future__ import annotations

import io
import logging
import struct
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, McapRecord, Message, Metadata, Schema

from app.streams.mcap_log.channels import METADATA_NAME, McapLogError

log = logging.getLogger(__name__)

MAGIC = b"\x89MCAP0\r\n"
MiB = 1 << 20
MESSAGE_HEAD = 22  # channel id (2), sequence (4), log time (8), publish time (8)


@dataclass(frozen=True)
class ReadLimits:
    """What one MCAP file may make the reader hold or do. ``max_record_bytes``: one
    top-level record (a chunk as stored, a message outside chunks); ``max_chunk_bytes``: a
    chunk's uncompressed size; ``max_message_bytes``: one message's payload;
    ``max_records`` / ``max_messages``: in the whole file (records inside chunks included).

    The defaults hold any log this project writes (1 MiB chunks, a pair's PNG of a 16 Mpx
    camera fits a chunk) with room, and bound a reader to about 0.5 GB."""

    max_record_bytes: int = 256 * MiB
    max_chunk_bytes: int = 256 * MiB
    max_message_bytes: int = 128 * MiB
    max_records: int = 50_000_000
    max_messages: int = 20_000_000


DEFAULT_LIMITS = ReadLimits()


@dataclass(frozen=True)
class McapMessage:
    """One message: its topic, log time (ns since the UNIX epoch), raw bytes, and its
    channel's message encoding and schema name (what it claims to be; nothing is decoded)."""

    topic: str
    log_time_ns: int
    data: bytes
    encoding: str = ""
    schema_name: str = ""


class _Cut(Exception):
    """The file ends in the middle of a record (a writer killed mid-run)."""


class _Body(ReadDataStream):
    """Exactly one record's bytes: a field that reads past them is a corrupt record."""

    def __init__(self, data: bytes) -> None:
        super().__init__(io.BytesIO(data))
        self._size = len(data)

    def read(self, length: int) -> bytes:
        if length < 0 or length > self._size - self.count:
            raise McapLogError(
                f"a field of {length} bytes runs past its record ({self._size - self.count} left)"
            )
        return super().read(length)


_PARSERS: dict[int, Callable[[ReadDataStream], McapRecord]] = {
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.CHUNK: Chunk.read,
    Opcode.METADATA: Metadata.read,
}


def _parse(opcode: int, body: bytes, where: str) -> McapRecord:
    """One record from exactly its bytes, by the ``mcap`` library's record class (a message's
    fixed head is read by :func:`_message`: the hot path)."""
    try:
        return _PARSERS[opcode](_Body(body))
    except McapLogError as exc:
        raise McapLogError(f"{where}: corrupt {Opcode(opcode).name} record ({exc})") from None
    except (ValueError, struct.error, OverflowError) as exc:  # UnicodeDecodeError among them
        raise McapLogError(f"{where}: corrupt {Opcode(opcode).name} record ({exc})") from None


def _decompress(chunk: Chunk, limits: ReadLimits, where: str) -> bytes:
    """A chunk's records, decompressed into at most its declared (and allowed) size."""
    size = chunk.uncompressed_size
    if size > limits.max_chunk_bytes:
        raise McapLogError(
            f"{where}: a chunk declares {size} bytes uncompressed, over the limit of "
            f"{limits.max_chunk_bytes} bytes"
        )
    try:
        if chunk.compression == "":
            data = chunk.data
        elif chunk.compression == "zstd":
            import zstandard

            reader = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data))
            data = reader.read(size + 1) if size else b""
        elif chunk.compression == "lz4":
            import lz4.frame

            data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=size + 1)
        else:
            raise McapLogError(f"{where}: unsupported chunk compression {chunk.compression!r}")
    except McapLogError:
        raise
    except Exception as exc:  # zstd.ZstdError, lz4's RuntimeError: corrupt compressed data
        raise McapLogError(f"{where}: corrupt {chunk.compression} chunk ({exc})") from None
    if len(data) != size:
        raise McapLogError(
            f"{where}: a chunk declares {size} bytes uncompressed but holds "
            f"{'more' if len(data) > size else len(data)}"
        )
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise McapLogError(f"{where}: a chunk fails its CRC check")
    return bytes(data)


class _Counter:
    """Records and messages read so far, against the limits."""

    def __init__(self, limits: ReadLimits) -> None:
        self.limits = limits
        self.records = 0
        self.messages = 0

    def add(self, records: int, messages: int, where: Callable[[], str]) -> None:
        self.records += records
        self.messages += messages
        if self.records > self.limits.max_records:
            raise McapLogError(f"{where()}: more than {self.limits.max_records} records")
        if self.messages > self.limits.max_messages:
            raise McapLogError(f"{where()}: more than {self.limits.max_messages} messages")


_MESSAGE_HEAD = struct.Struct("<HIQQ")
_RECORD_HEAD = struct.Struct("<BQ")
Accept = Callable[[int], bool]


def _message(view: memoryview, pos: int, length: int, accept: Accept) -> Message | None:
    """A message record's fixed head (channel id, sequence, log and publish time; the layout
    of ``mcap.records.Message``) and, if ``accept`` takes its channel, its payload."""
    channel_id, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(view, pos)
    if not accept(channel_id):
        return None
    data = bytes(view[pos + MESSAGE_HEAD : pos + length])
    return Message(channel_id, log_time, data, publish_time, sequence)


def _chunk_records(
    data: bytes, offset: int, count: _Counter, accept: Accept
) -> Iterator[McapRecord]:
    """The schemas, channels and accepted messages of a decompressed chunk, one at a time
    (the hot loop: a chunk may hold millions of tiny records)."""
    view = memoryview(data)
    pos, end, n, msgs = 0, len(data), 0, 0
    max_message = count.limits.max_message_bytes + MESSAGE_HEAD
    unpack, head = _RECORD_HEAD.unpack_from, _MESSAGE_HEAD.unpack_from
    where = lambda: f"chunk at byte {offset}, record at byte {pos} of its data"  # noqa: E731
    try:
        while pos < end:
            if end - pos < 9:
                raise McapLogError(f"{where()}: {end - pos} stray bytes at the end of a chunk")
            opcode, length = unpack(view, pos)
            body = pos + 9
            if length > end - body:
                raise McapLogError(f"{where()}: a record of {length} bytes runs past its chunk")
            n += 1
            if opcode == Opcode.MESSAGE:
                msgs += 1
                if not MESSAGE_HEAD <= length <= max_message:
                    raise McapLogError(f"{where()}: a message record of {length} bytes")
                channel_id, sequence, log_time, publish_time = head(view, body)
                if accept(channel_id):  # inlined _message: the hot path
                    data = bytes(view[body + MESSAGE_HEAD : body + length])
                    yield Message(channel_id, log_time, data, publish_time, sequence)
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                yield _parse(opcode, bytes(view[body : body + length]), where())
            elif opcode <= Opcode.DATA_END:  # reserved 0x00, or a record not of a chunk
                raise McapLogError(f"{where()}: opcode {opcode:#04x} is not allowed in a chunk")
            pos = body + length
            if n >= 65536:  # checked in batches (the limits are in millions)
                count.add(n, msgs, where)
                n = msgs = 0
    finally:
        view.release()
    count.add(n, msgs, where)


def _records(
    fh: BinaryIO, limits: ReadLimits, *, chunks: bool, accept: Accept = lambda _: True
) -> Iterator[McapRecord]:
    """The file's schemas, channels, accepted messages and metadata in order (``chunks``:
    the records inside chunks too; else chunks are skipped unread), up to its data end.
    Raises :class:`_Cut` at the end of a cut file, :class:`McapLogError` for anything
    corrupt."""
    size = fh.seek(0, io.SEEK_END)
    fh.seek(0)
    magic = fh.read(len(MAGIC))
    if magic != MAGIC:
        if MAGIC.startswith(magic):
            raise _Cut("the file ends inside its magic")
        raise McapLogError("it does not start with the MCAP magic")
    count = _Counter(limits)
    while True:
        offset = fh.tell()
        head = fh.read(9)
        if len(head) < 9:
            raise _Cut(f"the file ends at byte {offset + len(head)} with no footer")
        opcode, length = _RECORD_HEAD.unpack(head)
        where = f"record at byte {offset}"
        if length > limits.max_record_bytes:
            raise McapLogError(
                f"{where}: declares {length} bytes, over the limit of "
                f"{limits.max_record_bytes} bytes"
            )
        if length > size - offset - 9:
            raise _Cut(f"the file ends inside the {where} ({length} bytes declared)")
        count.add(1, int(opcode == Opcode.MESSAGE), lambda: where)  # noqa: B023
        if opcode in (Opcode.FOOTER, Opcode.DATA_END):
            return
        if opcode == Opcode.MESSAGE:
            if not MESSAGE_HEAD <= length <= limits.max_message_bytes + MESSAGE_HEAD:
                raise McapLogError(f"{where}: a message record of {length} bytes")
            msg = _message(memoryview(fh.read(length)), 0, length, accept)
            if msg is not None:
                yield msg
            continue
        if opcode not in _PARSERS or (opcode == Opcode.CHUNK and not chunks):
            fh.seek(length, io.SEEK_CUR)  # indexes, statistics, attachments, unknown: skipped
            continue
        record = _parse(opcode, fh.read(length), where)
        if isinstance(record, Chunk):
            yield from _chunk_records(_decompress(record, limits, where), offset, count, accept)
        else:
            yield record


def _open(path: str | Path) -> BinaryIO:
    try:
        return open(path, "rb")  # noqa: SIM115 - closed by the callers
    except OSError as exc:
        raise McapLogError(f"cannot open {str(path)!r}: {exc.strerror or exc}") from None


def iter_messages(
    path: str | Path, topics: Sequence[str] | None = None, limits: ReadLimits = DEFAULT_LIMITS
) -> Iterator[McapMessage]:
    """The messages of an MCAP log in file order (complete, or cut by a crash: up to its last
    complete record). :class:`McapLogError` (one line: where and what) if it is not an MCAP
    file, or anything in it is corrupt or over ``limits``."""
    wanted = None if topics is None else set(topics)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    taken: set[int] = set()  # the ids of the channels read

    def accept(channel_id: int) -> bool:
        if channel_id in taken:
            return True
        if channel_id not in channels:
            raise McapLogError(f"a message on channel {channel_id}, never defined before it")
        return False

    fh = _open(path)
    try:
        for rec in _records(fh, limits, chunks=True, accept=accept):
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
                if wanted is None or rec.topic in wanted:
                    taken.add(rec.id)
                else:
                    taken.discard(rec.id)
            elif isinstance(rec, Message):
                ch = channels[rec.channel_id]
                schema = schemas.get(ch.schema_id)
                name = "" if schema is None else schema.name
                yield McapMessage(ch.topic, rec.log_time, rec.data, ch.message_encoding, name)
    except _Cut as exc:
        if not channels:
            raise McapLogError(f"{str(path)!r} is not a readable MCAP file ({exc})") from None
        log.warning("MCAP %s ends early (%s): read up to its last complete record", path, exc)
    except McapLogError as exc:
        raise McapLogError(f"{str(path)!r} is not a readable MCAP file ({exc})") from None
    finally:
        fh.close()


def read_metadata(path: str | Path, limits: ReadLimits = DEFAULT_LIMITS) -> dict[str, str]:
    """The ``aar-dock`` metadata record (format, exact calibration), ``{}`` if it has none
    (chunks are skipped unread)."""
    fh = _open(path)
    try:
        for rec in _records(fh, limits, chunks=False):
            if isinstance(rec, Metadata) and rec.name == METADATA_NAME:
                return dict(rec.metadata)
    except _Cut:
        pass  # a cut file: what it holds is read by iter_messages, which says if it is none
    except McapLogError as exc:
        raise McapLogError(f"{str(path)!r} is not a readable MCAP file ({exc})") from None
    finally:
        fh.close()
    return {}


def is_complete(path: str | Path) -> bool:
    """Whether an MCAP file was finished (ends with its footer and magic)."""
    try:
        with open(path, "rb") as fh:
            size = fh.seek(0, 2)
            if size < 8 + 9 + 20 + 8:
                return False
            fh.seek(size - 8 - 29)
            tail = fh.read()
    except OSError:
        return False
    return tail[-8:] == MAGIC and tail[0] == Opcode.FOOTER
