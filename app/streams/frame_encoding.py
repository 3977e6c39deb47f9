"""How a frame recording stores its images: the codec, its level or quality, and encoding one
image with it (:class:`FrameEncoding`).

Codecs (sizes and MB per minute measured on the simulated stream: docs/ecosystem.md,
``benchmarks/bench_recording.py``):

``png-huffman`` (lossless, the default)
    PNG with no row filter and Huffman coding only. The cameras' dark, noisy frames (LEDs on a
    sensor-noise background) hold nothing a row filter or a back-reference predicts, so this is
    both the smallest and the fastest lossless form of them.
``png`` (lossless)
    PNG with adaptive row filters and deflate at ``png_level`` (1 fastest … 9 smallest): better
    on textured scenes (checkerboards, daylight backgrounds).
``jpeg`` (lossy)
    JPEG at ``jpeg_quality`` (1–100). Much smaller, but the LED centroids a replay measures are
    no longer those of the live run: a replay is close, not identical.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from app.streams.mcap_log.channels import ImageFormat

FrameCodec = Literal["png-huffman", "png", "jpeg"]
CODECS: tuple[FrameCodec, ...] = ("png-huffman", "png", "jpeg")


class FrameEncodingError(ValueError):
    """An encoding option out of range (one line: which and why)."""


@dataclass(frozen=True)
class FrameEncoding:
    """The codec of a frame recording's images; ``png_level`` (1–9) applies to ``png``,
    ``jpeg_quality`` (1–100) to ``jpeg``."""

    codec: FrameCodec = "png-huffman"
    png_level: int = 1
    jpeg_quality: int = 90

    def __post_init__(self) -> None:
        if self.codec not in CODECS:
            raise FrameEncodingError(
                f"codec must be one of {', '.join(CODECS)}, not {self.codec!r}"
            )
        if not 1 <= self.png_level <= 9:
            raise FrameEncodingError(f"png_level must be in 1..9, not {self.png_level}")
        if not 1 <= self.jpeg_quality <= 100:
            raise FrameEncodingError(f"jpeg_quality must be in 1..100, not {self.jpeg_quality}")

    @property
    def lossless(self) -> bool:
        return self.codec != "jpeg"

    @property
    def image_format(self) -> ImageFormat:
        """The container format of the encoded bytes (an MCAP ``CompressedImage.format``)."""
        return "jpeg" if self.codec == "jpeg" else "png"

    @property
    def extension(self) -> str:
        return ".jpg" if self.codec == "jpeg" else ".png"

    @property
    def label(self) -> str:
        """A short name with its parameter, e.g. ``png level 6``, ``jpeg q90 (lossy)``."""
        if self.codec == "png":
            return f"png level {self.png_level}"
        if self.codec == "jpeg":
            return f"jpeg q{self.jpeg_quality} (lossy)"
        return "png-huffman"

    def params(self) -> list[int]:
        """OpenCV ``imencode`` parameters."""
        if self.codec == "jpeg":
            return [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality]
        if self.codec == "png":
            return [cv2.IMWRITE_PNG_COMPRESSION, self.png_level]
        return [
            cv2.IMWRITE_PNG_COMPRESSION,
            1,
            cv2.IMWRITE_PNG_STRATEGY,
            cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
            cv2.IMWRITE_PNG_FILTER,
            cv2.IMWRITE_PNG_FILTER_NONE,
        ]

    def encode(self, image: np.ndarray) -> bytes:
        """One image's bytes (``OSError`` if OpenCV cannot encode it)."""
        ok, buf = cv2.imencode(self.extension, image, self.params())
        if not ok:
            raise OSError(f"{self.label} encoding failed")
        return bytes(buf.tobytes())

    def to_json(self) -> dict[str, str | int | bool]:
        return {
            "codec": self.codec,
            "png_level": self.png_level,
            "jpeg_quality": self.jpeg_quality,
            "lossless": self.lossless,
        }
