"""Colour of a blob judged on its unsaturated flanks over the local background (a saturated
green LED stays green; a saturated white or yellow sun glint is refused), on blue sky too."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from app.vision.appearance import AppearanceConfig, blob_color_bgr, colour_reason
from app.vision.types import Blob


def _spot(
    colour_bgr: tuple[float, float, float], sky_bgr: tuple[float, float, float]
) -> np.ndarray:
    """A 40×40 BGR image: sky plus a Gaussian spot (σ 2.5 px) of peak ``colour_bgr`` × 3,
    clipped at 255 (a saturated core, unsaturated flanks)."""
    yy, xx = np.mgrid[0:40, 0:40]
    g = np.exp(-((xx - 20.3) ** 2 + (yy - 19.6) ** 2) / (2 * 2.5**2))
    img = np.array(sky_bgr)[None, None, :] + 3.0 * g[:, :, None] * np.array(colour_bgr)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


BLOB = Blob((20.3, 19.6), 60, (15, 15, 11, 11), 255.0, 1.0)


@pytest.mark.parametrize("sky", [(3.0, 3.0, 3.0), (170.0, 120.0, 90.0)])
def test_saturated_green_led_is_green_and_white_or_yellow_glints_are_not(sky) -> None:
    cfg = AppearanceConfig()
    led = _spot((30.0, 250.0, 50.0), sky)
    assert led[20, 20, 1] == 255  # the core is saturated
    col = blob_color_bgr(led, BLOB, threshold=100)
    assert max(col) < cfg.saturated_dn  # judged on the flanks
    assert colour_reason(replace(BLOB, color_bgr=col), cfg) is None
    for glint in ((250.0, 250.0, 250.0), (120.0, 240.0, 250.0)):  # white, yellow (BGR)
        img = _spot(glint, sky)
        col = blob_color_bgr(img, BLOB, threshold=100)
        why = colour_reason(replace(BLOB, color_bgr=col), cfg)
        assert why is not None and "not green" in why


def test_fully_saturated_blob_is_not_judged() -> None:
    img = np.full((40, 40, 3), 255, np.uint8)
    col = blob_color_bgr(img, BLOB, threshold=100)
    blob = replace(BLOB, color_bgr=col)
    assert colour_reason(blob, AppearanceConfig()) is None
