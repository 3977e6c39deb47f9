"""The one image decoder of the package, and reading stereo images with clear errors.

Every image that comes in as encoded bytes or a file — an uploaded pair (``POST /stereo``), a
checkerboard set, a pushed pair, an image folder, a frame recording, an MCAP log, the CLI —
goes through :func:`decode_image`, and every decoded or captured frame through
:func:`sensor_image`: 8-bit grey where the sensor is grey, 8-bit BGR where it has colour. The
pipeline's detection (:func:`app.vision.preprocess.detection_image`: green excess and the
colour gate on colour, the grey level on grey) then runs on the same array whichever way the
pair came in, so one pair gives one answer.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from app.types import UInt8Array
from app.vision.preprocess import ImageError

FORMATS = "PNG/JPEG/BMP/TIFF"


def sensor_image(image: NDArray[np.generic], name: str = "image") -> UInt8Array:
    """A decoded or captured frame as the pipeline takes it, or ``ImageError``.

    16-bit → the high byte; alpha dropped; one channel → grey; a colour frame whose three
    channels are equal (a grey sensor through a colour codec or a video file) → grey, since it
    carries no colour for the green-excess detection to use; a colour frame stays BGR."""
    img = np.asarray(image)
    if img.dtype == np.uint16:
        img = np.right_shift(img, 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise ImageError(f"{name}: unsupported pixel type {img.dtype} (8 or 16 bit)")
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] == 3:
        b, g, r = img[:, :, 0], img[:, :, 1], img[:, :, 2]
        if np.array_equal(b, g) and np.array_equal(g, r):
            img = b
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ImageError(f"{name}: unsupported image shape {img.shape}")
    return np.ascontiguousarray(img)


def decode_image(data: bytes, name: str) -> UInt8Array:
    """Decode PNG/JPEG/BMP/TIFF bytes to :func:`sensor_image`'s grey or BGR, or raise
    ``ImageError`` naming ``name`` (empty, undecodable, over OpenCV's pixel limit)."""
    if not data:
        raise ImageError(f"{name}: empty file")
    try:
        decoded = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:  # e.g. over OPENCV_IO_MAX_IMAGE_PIXELS
        decoded = None
    if decoded is None or decoded.size == 0:
        raise ImageError(f"{name}: could not decode the image (corrupt, or not {FORMATS})")
    return sensor_image(decoded, name)


def read_image(path: str | Path) -> UInt8Array:
    """Read an image file (:func:`decode_image`), or raise ImageError naming the file."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ImageError(f"{p}: cannot read ({exc.strerror or exc})") from None
    return decode_image(data, str(p))


def check_pair(left: np.ndarray, right: np.ndarray, left_name: str, right_name: str) -> None:
    """Raise ImageError if the two images of a pair differ in size."""
    if left.shape[:2] != right.shape[:2]:
        raise ImageError(
            f"{right_name}: size {right.shape[1]}×{right.shape[0]} px differs from "
            f"{left_name} ({left.shape[1]}×{left.shape[0]} px)"
        )
