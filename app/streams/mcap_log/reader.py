"""Reading an MCAP log, complete or cut by a crash (up to its last complete chunk): its
messages in file order (:func:`iter_messages`), its ``aar-dock`` metadata record
(:func:`read_metadata`) and whether it was finished (:func:`is_complete`)."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

from app.streams.mcap_log.channels import METADATA_NAME, McapLogError

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class McapMessage:
    """One message: its topic, log time (ns since the UNIX epoch), raw bytes and, for a
    protobuf channel read with ``decode``, the message decoded with its own schema."""

    topic: str
    log_time_ns: int
    data: bytes
    decoded: object = None


def iter_messages(
    path: str | Path, topics: Sequence[str] | None = None, *, decode: bool = False
) -> Iterator[McapMessage]:
    """The messages of an MCAP log in file order (complete or cut by a crash: up to its last
    complete chunk). :class:`McapLogError` if it is not an MCAP file."""
    from mcap.exceptions import McapError
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    from mcap_protobuf.decoder import DecoderFactory

    wanted = None if topics is None else set(topics)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    decoders: dict[int, object] = {}
    factory = DecoderFactory()
    try:
        fh = open(path, "rb")  # noqa: SIM115 - closed in finally, the generator may stop early
    except OSError as exc:
        raise McapLogError(f"cannot open {str(path)!r}: {exc.strerror or exc}") from None
    try:
        records = StreamReader(fh, skip_magic=False).records
        try:
            for rec in records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                elif isinstance(rec, Message):
                    ch = channels.get(rec.channel_id)
                    topic = "" if ch is None else ch.topic
                    if wanted is not None and topic not in wanted:
                        continue
                    decoded: object = None
                    if decode and ch is not None:
                        if ch.id not in decoders:
                            decoders[ch.id] = factory.decoder_for(
                                ch.message_encoding, schemas.get(ch.schema_id)
                            )
                        fn = decoders[ch.id]
                        if callable(fn):
                            decoded = fn(rec.data)
                    yield McapMessage(topic, rec.log_time, rec.data, decoded)
        except (McapError, EOFError, ValueError, OSError) as exc:
            if not channels:
                raise McapLogError(f"{str(path)!r} is not a readable MCAP file ({exc})") from None
            log.warning("MCAP %s ends early (%s): read up to its last complete chunk", path, exc)
    finally:
        fh.close()


def read_metadata(path: str | Path) -> dict[str, str]:
    """The ``aar-dock`` metadata record (format, exact calibration), ``{}`` if it has none."""
    from mcap.exceptions import McapError
    from mcap.records import Message, Metadata
    from mcap.stream_reader import StreamReader

    try:
        with open(path, "rb") as fh:
            for rec in StreamReader(fh, skip_magic=False).records:
                if isinstance(rec, Metadata) and rec.name == METADATA_NAME:
                    return dict(rec.metadata)
                if isinstance(rec, Message):
                    return {}
    except OSError as exc:
        raise McapLogError(f"cannot open {str(path)!r}: {exc.strerror or exc}") from None
    except (McapError, EOFError, ValueError) as exc:
        raise McapLogError(f"{str(path)!r} is not a readable MCAP file ({exc})") from None
    return {}


def is_complete(path: str | Path) -> bool:
    """Whether an MCAP file was finished (ends with its footer and magic)."""
    from mcap.opcode import Opcode

    try:
        with open(path, "rb") as fh:
            size = fh.seek(0, 2)
            if size < 8 + 9 + 20 + 8:
                return False
            fh.seek(size - 8 - 29)
            tail = fh.read()
    except OSError:
        return False
    return tail[-8:] == b"\x89MCAP0\r\n" and tail[0] == Opcode.FOOTER
