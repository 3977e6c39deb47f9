"""Reading stereo images from files or bytes with clear errors (no web imports)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from app.vision.preprocess import ImageError


def decode_image(data: bytes, name: str) -> np.ndarray:
    """Decode PNG/JPEG/BMP/TIFF bytes to a uint8 gray or BGR array, or raise ImageError."""
    if not data:
        raise ImageError(f"{name}: empty file")
    buf = np.frombuffer(data, dtype=np.uint8)
    decoded = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if decoded is None:
        raise ImageError(f"{name}: not a readable PNG/JPEG/BMP/TIFF image")
    image: np.ndarray = np.asarray(decoded)
    if image.dtype == np.uint16:
        image = (image.astype(np.uint16) // 256).astype(np.uint8)
    if image.dtype != np.uint8:
        raise ImageError(f"{name}: unsupported pixel type {image.dtype}")
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return np.asarray(image)


def read_image(path: str | Path) -> np.ndarray:
    """Read an image file, or raise ImageError naming the file."""
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
