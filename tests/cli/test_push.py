"""``aar-dock push``'s wire encodings (:func:`app.cli.push.push_encoder`): what the service's
decoder reads back, and that the tracker gives one answer whichever lossless form is pushed."""

from __future__ import annotations

import numpy as np
import pytest

from app.cli.push import UsageError, push_encoder
from app.model.frames import StereoFrame
from app.resources import load_default_calibration
from app.sim.led_ring import stereo_center_x_mm, tilted_normal
from app.sim.stereo_render import render_pair
from app.streams.image_header import peek_header
from app.streams.processor import StreamProcessor
from app.streams.sources import decode_image_bytes


def _pair() -> tuple[np.ndarray, np.ndarray]:
    calib = load_default_calibration()
    centre = np.array([stereo_center_x_mm(calib, 1000.0), -20.0, 1000.0])
    pair = render_pair(calib, centre, tilted_normal(6.0, 30.0), seed=3)
    return pair.left, pair.right


@pytest.mark.parametrize(("fmt", "container"), [("png", "png"), ("bmp", "bmp")])
def test_lossless_formats_decode_to_the_very_image(fmt: str, container: str) -> None:
    left, _ = _pair()
    colour = np.dstack([left, left // 2, 255 - left])
    encode = push_encoder(fmt, 95)
    for image in (left, colour):
        data = encode(image)
        assert peek_header(data).format == container
        assert np.array_equal(decode_image_bytes(data), image)


def test_jpeg_is_lossy_but_close_and_its_quality_is_used() -> None:
    left, _ = _pair()
    fine, coarse = push_encoder("jpg", 95)(left), push_encoder("jpg", 30)(left)
    assert peek_header(fine).format == "jpeg" and len(coarse) < len(fine)
    err = np.abs(decode_image_bytes(fine).astype(int) - left.astype(int))
    assert 0 < err.max() and err.mean() < 2.0


def test_png_and_bmp_pushes_give_one_answer() -> None:
    left, right = _pair()
    results = []
    for fmt in ("png", "bmp"):
        encode = push_encoder(fmt, 95)
        frame = StereoFrame(
            decode_image_bytes(encode(left)), decode_image_bytes(encode(right)), 0.0, 0
        )
        pose = StreamProcessor(load_default_calibration()).process(frame, "push").pose
        assert pose.lock and pose.drogue is not None, pose.reason
        results.append(pose.drogue.center_mm)
    assert results[0] == results[1]


def test_an_unknown_format_is_a_usage_error() -> None:
    with pytest.raises(UsageError, match="png, jpg or bmp"):
        push_encoder("webp", 95)


def test_the_default_wire_encoding_is_uncompressed() -> None:
    """``aar-dock push`` sends pixels as a camera link does (BMP: no decoding to speak of),
    lossless; PNG and JPEG are there for links short of bandwidth."""
    from app.cli.main import build_parser

    args = build_parser().parse_args(["push", "--left", "L", "--right", "R", "--url", "ws://h"])
    assert args.format == "bmp"
    left, _ = _pair()
    data = push_encoder(args.format, args.jpeg_quality)(left)
    assert peek_header(data).format == "bmp"
    assert len(data) >= left.size and np.array_equal(decode_image_bytes(data), left)
