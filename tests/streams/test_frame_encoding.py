"""The frame recordings' codecs (issue 33 item 4): the lossless ones give back every pixel
(decoded by Pillow, a reader we did not write), JPEG is lossy and says so, bad options are
refused in one line."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from app.streams.frame_encoding import FrameEncoding, FrameEncodingError


def _noisy_frame(seed: int = 0) -> np.ndarray:
    """A dark frame with sensor noise (σ = 2 DN) and two bright LEDs, like the cameras'."""
    rng = np.random.default_rng(seed)
    img = np.clip(np.rint(12.0 + 2.0 * rng.standard_normal((240, 320))), 0, 255)
    img[100:106, 50:56] = 250
    img[30:35, 200:205] = 240
    return img.astype(np.uint8)


@pytest.mark.parametrize(
    "encoding", [FrameEncoding(), FrameEncoding("png", png_level=1), FrameEncoding("png", 9)]
)
def test_lossless_codecs_give_back_every_pixel(encoding: FrameEncoding) -> None:
    img = _noisy_frame()
    data = encoding.encode(img)
    assert encoding.lossless and encoding.image_format == "png" and data[:8] == b"\x89PNG\r\n\x1a\n"
    back = np.asarray(Image.open(io.BytesIO(data)))
    assert np.array_equal(back, img)


def test_png_huffman_is_smaller_than_the_old_level_1_png_on_noisy_frames() -> None:
    img = _noisy_frame()
    assert len(FrameEncoding().encode(img)) < 0.9 * len(FrameEncoding("png", 1).encode(img))


def test_jpeg_is_lossy_and_smaller() -> None:
    img = _noisy_frame()
    enc = FrameEncoding("jpeg", jpeg_quality=80)
    data = enc.encode(img)
    assert not enc.lossless and enc.extension == ".jpg" and "lossy" in enc.label
    back = np.asarray(Image.open(io.BytesIO(data)))
    assert back.shape == img.shape and not np.array_equal(back, img)
    assert np.abs(back.astype(int) - img).mean() < 4.0  # close, not identical
    assert len(data) < len(FrameEncoding().encode(img)) / 2


@pytest.mark.parametrize(
    ("kw", "word"),
    [
        ({"codec": "webp"}, "codec"),
        ({"png_level": 0}, "png_level"),
        ({"jpeg_quality": 101}, "jpeg"),
    ],
)
def test_bad_options_are_refused_in_one_line(kw: dict[str, object], word: str) -> None:
    with pytest.raises(FrameEncodingError, match=word):
        FrameEncoding(**kw)  # type: ignore[arg-type]
