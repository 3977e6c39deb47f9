"""The image guard of uploads and pushed pairs: an image refused on its header before any
decoding (:mod:`app.streams.image_header` reads the headers), answered 400, 413 or 422.

Second line of defence: ``OPENCV_IO_MAX_IMAGE_PIXELS`` is set here (unless the operator set
it) before ``cv2`` is first imported by the service, so OpenCV itself refuses larger images.
It only takes effect when this module is imported before ``cv2`` (``app.server.main`` does).
This module must therefore never import ``cv2``.
"""

from __future__ import annotations

import os
import sys

from app.streams.image_header import (
    DEFAULT_MAX_IMAGE_PIXELS,
    SUPPORTED,
    AmbiguousHeaderError,
    ImageHeader,
    ImageHeaderError,
    env_max_image_pixels,
    peek_header,
)

__all__ = [
    "DEFAULT_MAX_IMAGE_PIXELS",
    "OPENCV_LIMIT_ACTIVE",
    "SUPPORTED",
    "AmbiguousHeaderError",
    "ImageHeader",
    "ImageHeaderError",
    "ImageRefused",
    "check",
    "peek_header",
]

OPENCV_ENV = "OPENCV_IO_MAX_IMAGE_PIXELS"
OPENCV_LIMIT_PRESET = OPENCV_ENV in os.environ
os.environ.setdefault(OPENCV_ENV, str(env_max_image_pixels()))
#: True when this module ran before OpenCV was loaded (so the env limit is in force).
OPENCV_LIMIT_ACTIVE = OPENCV_LIMIT_PRESET or "cv2" not in sys.modules


class ImageRefused(ValueError):
    """An image refused on its header: the HTTP status (400, 413, 422) and the reason."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail


def check(data: bytes, name: str, *, max_pixels: int) -> ImageHeader:
    """The header of an uploaded or pushed image, or :class:`ImageRefused`: 400 (empty, not a
    supported image), 422 (a size field written twice or contradicting another), 413 (more
    than ``max_pixels``). Nothing is decoded."""
    if not data:
        raise ImageRefused(400, f"{name}: empty file")
    try:
        header = peek_header(data)
    except AmbiguousHeaderError as exc:
        raise ImageRefused(
            422, f"{name}: ambiguous image header ({exc}); refused before decoding"
        ) from None
    except ImageHeaderError as exc:
        raise ImageRefused(400, f"{name}: could not decode the image ({exc})") from None
    if header.pixels > max_pixels:
        raise ImageRefused(
            413,
            f"{name}: {header.describe()} ({header.pixels / 1e6:.4g} Mpx) exceeds the limit of "
            f"{max_pixels / 1e6:.4g} Mpx (AAR_MAX_IMAGE_PIXELS); refused before decoding",
        )
    return header
