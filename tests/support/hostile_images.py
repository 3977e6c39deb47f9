"""Image files that lie about themselves (headers against the decoder), for the guards tests."""

from __future__ import annotations

import struct
import zlib

import cv2
import numpy as np


def tiff(
    width: int,
    height: int,
    extra: list[tuple[int, int, int, int]] | None = None,
    *,
    pixels: tuple[int, int] | None = None,
    sort: bool = True,
) -> bytes:
    """A grey 8-bit deflate TIFF (one strip) of ``pixels`` (default ``width × height``) with
    ``extra`` directory entries ``(tag, type, count, value)`` (SHORT/LONG, one value)."""
    pw, ph = pixels or (width, height)
    strip = zlib.compress(bytes(pw * ph), 9)
    entries = [  # extra entries first: of two equal tags they come first (sorted stably)
        *(extra or []),
        (256, 3, 1, width),
        (257, 3, 1, height),
        (258, 3, 1, 8),
        (259, 3, 1, 8),  # deflate
        (262, 3, 1, 1),  # min-is-black
        (273, 4, 1, 0),  # strip offset, patched below
        (277, 3, 1, 1),
        (278, 4, 1, 0xFFFFFFFF),
        (279, 4, 1, len(strip)),
    ]
    if sort:
        entries.sort(key=lambda e: e[0])
    start = 8 + 2 + 12 * len(entries) + 4
    out = bytearray(b"II*\x00" + struct.pack("<IH", 8, len(entries)))
    for tag, typ, count, value in entries:
        value = start if tag == 273 else value
        if typ == 3:
            out += struct.pack("<HHIHH", tag, typ, count, value, 0)
        else:
            out += struct.pack("<HHII", tag, typ, count, value)
    return bytes(out + struct.pack("<I", 0) + strip)


def hostile_tiff() -> bytes:
    """35 KB: ImageWidth/ImageLength 6000 first (what libtiff reads), 1280 × 1024 after."""
    return tiff(1280, 1024, [(256, 3, 1, 6000), (257, 3, 1, 6000)], pixels=(6000, 6000))


def undecodable_png(img: np.ndarray) -> bytes:
    """A PNG whose header (size, type) is right but whose pixel data is garbage."""
    good = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])[1].tobytes()
    return good[:33] + struct.pack(">I", 64) + b"IDAT" + b"\x55" * 64 + b"\0" * 4 + good[-12:]
