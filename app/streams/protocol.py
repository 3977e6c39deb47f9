"""The push protocol: one stereo pair per binary WebSocket message.

Layout (little-endian)::

    0   4 bytes   magic  b"AARP"
    4   uint16    version (1)
    6   uint32    H = length of the JSON header
    10  H bytes   header, UTF-8 JSON object:
                    t_s          float, required   capture time of the pair (s, pusher's clock)
                    seq          int ≥ 0, required the pusher's sequence number
                    left_bytes   int > 0, required length of the left image
                    right_bytes  int > 0, required length of the right image
                    exposure_ms  float, optional
                    t_left_s, t_right_s  float, optional: per-side times (skew check)
    10+H          left image  (PNG, JPEG, BMP or TIFF file bytes)
    10+H+L        right image

The message length must be exactly ``10 + H + left_bytes + right_bytes``. The header is at
most ``MAX_HEADER_BYTES``. Anything else is refused with a :class:`ProtocolError` naming the
problem (the server answers it as a text message and keeps the connection), except a header
that cannot be parsed at all (:class:`HeaderSyntaxError`: the server closes with 1007).
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass
from typing import Any

MAGIC = b"AARP"
VERSION = 1
_PREFIX = struct.Struct("<4sHI")
MAX_HEADER_BYTES = 4096


class ProtocolError(ValueError):
    pass


class HeaderSyntaxError(ProtocolError):
    """The JSON header cannot be parsed at all (not JSON, not UTF-8, nested too deeply): the
    server closes the connection (1007) with this as the reason."""


@dataclass(frozen=True)
class PushMessage:
    t_s: float
    seq: int
    left: bytes
    right: bytes
    exposure_ms: float | None = None
    t_left_s: float | None = None
    t_right_s: float | None = None


def encode_message(
    left: bytes,
    right: bytes,
    *,
    t_s: float,
    seq: int,
    exposure_ms: float | None = None,
    t_left_s: float | None = None,
    t_right_s: float | None = None,
) -> bytes:
    header: dict[str, Any] = {
        "t_s": float(t_s),
        "seq": int(seq),
        "left_bytes": len(left),
        "right_bytes": len(right),
    }
    for name, value in (
        ("exposure_ms", exposure_ms),
        ("t_left_s", t_left_s),
        ("t_right_s", t_right_s),
    ):
        if value is not None:
            header[name] = float(value)
    raw = json.dumps(header, separators=(",", ":")).encode()
    return _PREFIX.pack(MAGIC, VERSION, len(raw)) + raw + left + right


def _number(header: dict[str, Any], name: str, required: bool) -> float | None:
    value = header.get(name)
    if value is None:
        if required:
            raise ProtocolError(f"header field {name!r} is missing")
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ProtocolError(f"header field {name!r} must be a finite number")
    return float(value)


def decode_message(data: bytes, max_bytes: int | None = None) -> PushMessage:
    """Parse one message (no image decoding: that happens off the event loop)."""
    if max_bytes is not None and len(data) > max_bytes:
        raise ProtocolError(f"message of {len(data)} bytes exceeds the limit of {max_bytes}")
    if len(data) < _PREFIX.size:
        raise ProtocolError("message shorter than the 10-byte prefix")
    magic, version, hlen = _PREFIX.unpack_from(data)
    if magic != MAGIC:
        raise ProtocolError("bad magic (expected b'AARP')")
    if version != VERSION:
        raise ProtocolError(f"unsupported protocol version {version}")
    if hlen > MAX_HEADER_BYTES or _PREFIX.size + hlen > len(data):
        raise ProtocolError(f"bad header length {hlen}")
    try:
        header = json.loads(data[_PREFIX.size : _PREFIX.size + hlen])
    except RecursionError:  # "[[[[…" a few thousand deep: the parser's stack, not ours
        raise HeaderSyntaxError("unparsable header: JSON nested too deeply") from None
    except ValueError:  # UnicodeDecodeError included
        raise HeaderSyntaxError("unparsable header: not UTF-8 JSON") from None
    if not isinstance(header, dict):
        raise ProtocolError("header must be a JSON object")
    t_s = _number(header, "t_s", True)
    seq = header.get("seq")
    nl, nr = header.get("left_bytes"), header.get("right_bytes")
    for name, v in (("seq", seq), ("left_bytes", nl), ("right_bytes", nr)):
        if isinstance(v, bool) or not isinstance(v, int) or v < (0 if name == "seq" else 1):
            raise ProtocolError(f"header field {name!r} must be an integer ≥ {int(name != 'seq')}")
    assert isinstance(nl, int) and isinstance(nr, int) and isinstance(seq, int) and t_s is not None
    start = _PREFIX.size + hlen
    if start + nl + nr != len(data):
        raise ProtocolError(
            f"message length {len(data)} ≠ 10 + header {hlen} + left {nl} + right {nr}"
        )
    return PushMessage(
        t_s=t_s,
        seq=seq,
        left=data[start : start + nl],
        right=data[start + nl :],
        exposure_ms=_number(header, "exposure_ms", False),
        t_left_s=_number(header, "t_left_s", False),
        t_right_s=_number(header, "t_right_s", False),
    )
