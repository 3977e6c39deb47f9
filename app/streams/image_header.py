"""Image headers read before any decoding: format, width × height, channels, bit depth.

An image is refused on its *header* when it is too large, so a 400 KB PNG that declares
20000 × 20000 px is answered in microseconds instead of allocating gigabytes inside the
decoder (uploads and pushed pairs: :mod:`app.service.image_guard`; the images of an MCAP log:
:mod:`app.streams.mcap_source`). Only PNG, JPEG, BMP and classic TIFF are read; anything else
is refused without reaching OpenCV's other decoders.

The size read here must be the size the decoder allocates: each reader follows its decoder
(libpng: the first chunk is IHDR; libjpeg: the first SOF before SOS; OpenCV's own BMP reader;
libtiff: the first directory) and refuses what a decoder could read otherwise — a header field
written twice or contradicting another (:class:`AmbiguousHeaderError`: a TIFF tag twice or out
of order, a second IHDR, a TIFF strip or tile larger than the image) and animated PNG (its
frames are decoded into more buffers). ``tests/service/test_image_guard.py`` fuzzes the readers
against OpenCV: an accepted header never under-states the decoded size.

This module never imports ``cv2`` (:mod:`app.service.image_guard` must run before it).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass

DEFAULT_MAX_IMAGE_PIXELS = 40_000_000


def env_max_image_pixels() -> int:
    """``AAR_MAX_IMAGE_PIXELS`` (default 40 Mpx): the largest image decoded anywhere."""
    raw = os.environ.get("AAR_MAX_IMAGE_PIXELS")
    try:
        return max(1, int(float(raw))) if raw else DEFAULT_MAX_IMAGE_PIXELS
    except ValueError:
        return DEFAULT_MAX_IMAGE_PIXELS


SUPPORTED = "PNG, JPEG, BMP or TIFF"


class ImageHeaderError(ValueError):
    """The bytes are not a (supported, well-formed) image header; ``str(exc)`` says why."""


class AmbiguousHeaderError(ImageHeaderError):
    """A header field written twice or contradicting another: a decoder could read another
    size than the one checked here (answered 422)."""


@dataclass(frozen=True)
class ImageHeader:
    format: str  # "png" | "jpeg" | "bmp" | "tiff"
    width: int
    height: int
    channels: int  # channels of the decoded array (upper bound)
    bit_depth: int  # bits per sample of the decoded array (8 or 16)

    @property
    def pixels(self) -> int:
        return self.width * self.height

    @property
    def decoded_bytes(self) -> int:
        """Size of the array OpenCV returns for ``IMREAD_UNCHANGED`` (upper bound)."""
        return self.pixels * self.channels * (2 if self.bit_depth > 8 else 1)

    def describe(self) -> str:
        return f"{self.width}x{self.height} px {self.format.upper()}"


# ---- PNG ---------------------------------------------------------------------------------
_PNG_SIG = b"\x89PNG\r\n\x1a\n"
# colour type → (channels of the decoded array, allowed bit depths)
_PNG_COLOUR = {
    0: (1, (1, 2, 4, 8, 16)),  # grey
    2: (3, (8, 16)),  # RGB
    3: (4, (1, 2, 4, 8)),  # palette (→ BGR, BGRA with tRNS)
    4: (4, (8, 16)),  # grey + alpha (→ BGRA)
    6: (4, (8, 16)),  # RGBA
}


_MAX_PNG_CHUNKS = 4096


def _png(data: bytes) -> ImageHeader:
    if len(data) < 33:
        raise ImageHeaderError("truncated PNG header")
    length, ctype = struct.unpack(">I4s", data[8:16])
    if ctype != b"IHDR" or length != 13:
        raise ImageHeaderError("PNG without a valid IHDR chunk")
    width, height, depth, colour, comp, filt, interlace = struct.unpack(">IIBBBBB", data[16:29])
    if colour not in _PNG_COLOUR or depth not in _PNG_COLOUR[colour][1]:
        raise ImageHeaderError(f"PNG with invalid colour type {colour} / bit depth {depth}")
    if comp != 0 or filt != 0 or interlace > 1:
        raise ImageHeaderError("PNG with invalid compression/filter/interlace method")
    if not (0 < width < 2**31 and 0 < height < 2**31):
        raise ImageHeaderError(f"PNG with invalid size {width}x{height}")
    _png_chunks_before_data(data)
    return ImageHeader("png", width, height, _PNG_COLOUR[colour][0], 16 if depth == 16 else 8)


def _png_chunks_before_data(data: bytes) -> None:
    """The chunks up to the first IDAT (as far as the bytes go): no second IHDR, no APNG."""
    pos = 33  # after the signature and IHDR (length, type, 13 bytes, CRC)
    for _ in range(_MAX_PNG_CHUNKS):
        if pos + 8 > len(data):
            return  # truncated: the decoder fails on it
        length, ctype = struct.unpack(">I4s", data[pos : pos + 8])
        if ctype == b"IDAT":
            return
        if ctype == b"IHDR":
            raise AmbiguousHeaderError("PNG with a second IHDR chunk (image size written twice)")
        if ctype in (b"acTL", b"fcTL"):
            raise ImageHeaderError("animated PNG (APNG) is not supported")
        pos += 12 + length
    raise ImageHeaderError(f"PNG with more than {_MAX_PNG_CHUNKS} chunks before its data")


# ---- JPEG --------------------------------------------------------------------------------
# SOFn markers (frame headers); C4 = DHT, C8 = JPG (reserved), CC = DAC are not frames
_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
_STANDALONE = {0x01, *range(0xD0, 0xD8)}  # TEM, RSTn: no length field
_MAX_JPEG_SEGMENTS = 512


def _jpeg(data: bytes) -> ImageHeader:
    pos, n = 2, len(data)
    for _ in range(_MAX_JPEG_SEGMENTS):
        if pos >= n or data[pos] != 0xFF:
            raise ImageHeaderError("JPEG without a frame header (SOF) before its data")
        while pos < n and data[pos] == 0xFF:  # fill bytes
            pos += 1
        if pos >= n:
            break
        marker = data[pos]
        pos += 1
        if marker in _STANDALONE:
            continue
        if marker in (0xD9, 0xDA):  # EOI, SOS: image data without a frame header
            break
        if pos + 2 > n:
            break
        (length,) = struct.unpack(">H", data[pos : pos + 2])
        if length < 2:
            raise ImageHeaderError("JPEG with an invalid segment length")
        if marker in _SOF:
            if pos + 8 > n:
                break
            precision, height, width, comps = struct.unpack(">BHHB", data[pos + 2 : pos + 8])
            if height == 0 or width == 0:
                raise ImageHeaderError("JPEG with a zero (or DNL-deferred) image size")
            if comps not in (1, 3, 4) or precision not in (8, 12, 16):
                raise ImageHeaderError(f"JPEG with {comps} components at {precision} bit")
            return ImageHeader("jpeg", width, height, 1 if comps == 1 else 3, precision)
        pos += length
    raise ImageHeaderError("JPEG without a frame header (SOF) before its data")


# ---- BMP ---------------------------------------------------------------------------------
def _bmp(data: bytes) -> ImageHeader:
    if len(data) < 26:
        raise ImageHeaderError("truncated BMP header")
    (dib,) = struct.unpack("<I", data[14:18])
    if dib == 12:  # OS/2 BITMAPCOREHEADER
        width, height, planes, bits = struct.unpack("<HHHH", data[18:26])
    elif 40 <= dib <= 124:
        if len(data) < 30:
            raise ImageHeaderError("truncated BMP header")
        width, height, planes, bits = struct.unpack("<iiHH", data[18:30])
        height = abs(height)  # negative = top-down rows
    else:
        raise ImageHeaderError(f"BMP with an unknown header size {dib}")
    if width <= 0 or height <= 0 or planes != 1:
        raise ImageHeaderError(f"BMP with invalid size {width}x{height}")
    if bits not in (1, 4, 8, 16, 24, 32):
        raise ImageHeaderError(f"BMP with {bits} bits per pixel")
    return ImageHeader("bmp", width, height, 4 if bits == 32 else 3, 8)


# ---- TIFF (classic, first IFD) -------------------------------------------------------------
# The first directory is what OpenCV decodes (libtiff). Its tags must be in ascending order
# and each written once (libtiff would take the *first* of two ImageWidth entries); the size
# tags must be single BYTE/SHORT/LONG values; a strip or a tile (OpenCV allocates a 32-bit RGBA
# buffer of one strip/tile) may not be larger than the image.
_TIFF_TYPE_SIZE = {1: 1, 3: 2, 4: 4}  # BYTE, SHORT, LONG
_TIFF_FORMAT = {1: "B", 3: "H", 4: "I"}
_TIFF_NAMES = {
    256: "ImageWidth",
    257: "ImageLength",
    258: "BitsPerSample",
    274: "Orientation",
    277: "SamplesPerPixel",
    278: "RowsPerStrip",
    322: "TileWidth",
    323: "TileLength",
}
_TIFF_SINGLE = {256, 257, 274, 277, 278, 322, 323}  # one value each
_MAX_TIFF_ENTRIES = 1024
_NO_STRIPS = 0xFFFFFFFF  # RowsPerStrip "all the image in one strip"


def _tiff_entries(data: bytes, e: str) -> dict[int, list[int]]:
    n = len(data)
    (ifd,) = struct.unpack(e + "I", data[4:8])
    if ifd < 8 or ifd + 2 > n:
        raise ImageHeaderError("TIFF with an invalid IFD offset")
    (count,) = struct.unpack(e + "H", data[ifd : ifd + 2])
    if count == 0 or count > _MAX_TIFF_ENTRIES or ifd + 2 + 12 * count > n:
        raise ImageHeaderError("TIFF with an invalid IFD")
    tags: dict[int, list[int]] = {}
    previous = -1
    for k in range(count):
        off = ifd + 2 + 12 * k
        tag, typ, cnt = struct.unpack(e + "HHI", data[off : off + 8])
        name = _TIFF_NAMES.get(tag, f"tag {tag}")
        if tag == previous:
            raise AmbiguousHeaderError(f"TIFF with {name} written twice in its directory")
        if tag < previous:
            raise AmbiguousHeaderError(
                f"TIFF directory with its tags out of order ({name} after tag {previous})"
            )
        previous = tag
        if tag not in _TIFF_NAMES:
            continue
        if typ not in _TIFF_TYPE_SIZE:
            raise ImageHeaderError(f"TIFF with {name} of type {typ} (BYTE, SHORT or LONG only)")
        if cnt == 0 or (tag in _TIFF_SINGLE and cnt != 1) or cnt > 16:
            raise ImageHeaderError(f"TIFF with {cnt} values of {name}")
        size = _TIFF_TYPE_SIZE[typ]
        if size * cnt <= 4:
            raw = data[off + 8 : off + 8 + size * cnt]
        else:
            (voff,) = struct.unpack(e + "I", data[off + 8 : off + 12])
            if voff + size * cnt > n:
                raise ImageHeaderError("TIFF with a tag value outside the file")
            raw = data[voff : voff + size * cnt]
        tags[tag] = list(struct.unpack(e + _TIFF_FORMAT[typ] * cnt, raw))
    return tags


def _tiff(data: bytes) -> ImageHeader:
    e = "<" if data[:2] == b"II" else ">"
    if len(data) < 8:
        raise ImageHeaderError("truncated TIFF header")
    tags = _tiff_entries(data, e)
    if 256 not in tags or 257 not in tags:
        raise ImageHeaderError("TIFF without ImageWidth/ImageLength")
    width, height = tags[256][0], tags[257][0]
    spp = tags.get(277, [1])[0]
    bps = max(tags.get(258, [1]))
    if width <= 0 or height <= 0:
        raise ImageHeaderError(f"TIFF with invalid size {width}x{height}")
    if not 1 <= spp <= 8 or bps > 64:
        raise ImageHeaderError(f"TIFF with {spp} samples of {bps} bit")
    rows = tags.get(278, [_NO_STRIPS])[0]
    if rows != _NO_STRIPS and rows > height:
        raise AmbiguousHeaderError(
            f"TIFF with RowsPerStrip {rows} larger than its ImageLength {height}"
        )
    for tag, limit in ((322, width), (323, height)):
        if tag in tags and not 0 < tags[tag][0] <= -(-limit // 16) * 16:
            raise AmbiguousHeaderError(
                f"TIFF with {_TIFF_NAMES[tag]} {tags[tag][0]} larger than the image "
                f"({width}x{height})"
            )
    if tags.get(274, [1])[0] in (5, 6, 7, 8):  # decoded transposed (libtiff orientation)
        width, height = height, width
    return ImageHeader("tiff", width, height, max(spp, 1), 16 if bps > 8 else 8)


def peek_header(data: bytes) -> ImageHeader:
    """Parse the header of an uploaded image; :class:`ImageHeaderError` if not supported."""
    if data.startswith(_PNG_SIG):
        return _png(data)
    if data.startswith(b"\xff\xd8\xff"):
        return _jpeg(data)
    if data.startswith(b"BM"):
        return _bmp(data)
    if data[:4] in (b"II*\x00", b"MM\x00*"):
        return _tiff(data)
    if data[:4] in (b"II+\x00", b"MM\x00+"):
        raise ImageHeaderError("BigTIFF is not supported (classic TIFF only)")
    raise ImageHeaderError(f"not a {SUPPORTED} image")
