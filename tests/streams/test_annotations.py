"""app.streams.annotations: the marks of a result and their drawing (the page, the 3-D view)."""

from __future__ import annotations

import numpy as np

from app.model.pose import LedResult, PoseResult
from app.streams.annotations import WINDOW_RGB, annotate, image_marks, led_color


def _led(led_id: int, left: tuple[float, float], right: tuple[float, float]) -> LedResult:
    return LedResult(
        id=led_id,
        left_px=left,
        right_px=right,
        xyz_mm=(0.0, 0.0, 1.0),
        descriptor_distance=0.0,
        epipolar_px=0.0,
        reprojection_px=0.0,
    )


def test_each_led_circled_in_its_colour() -> None:
    img = np.zeros((1024, 1280), np.uint8)
    pose = PoseResult(lock=True, leds=[_led(3, (640.0, 512.0), (100.0, 100.0))])
    out = annotate(img, pose, "left", width=320)
    assert out.shape == (256, 320, 3) and out.dtype == np.uint8
    # the circle (radius 7 px) around (160, 128) is drawn in LED 3's colour (green channel)
    ring = out[128, 160 + 7]
    assert ring[1] > 100 and ring[1] > ring[0]
    assert out[128, 160].sum() < 60  # centre left untouched (dark background)


def test_marks_follow_the_side_and_carry_the_ids_of_matched_pairs() -> None:
    pose = PoseResult(lock=True, leds=[_led(1, (10, 20), (5, 20)), _led(4, (30, 40), (25, 40))])
    left, right = image_marks(pose, "left"), image_marks(pose, "right")
    assert left.led_ids == right.led_ids == [1, 4]  # a matched pair: one id in both images
    assert [(m.u_px, m.v_px) for m in left.leds] == [(10, 20), (30, 40)]
    assert [(m.u_px, m.v_px) for m in right.leds] == [(5, 20), (25, 40)]
    assert image_marks(None, "left").leds == ()


def test_windows_and_banner_are_drawn() -> None:
    img = np.zeros((1024, 1280), np.uint8)
    out = annotate(img, None, "right", lock=False, windows_px=[(400, 400, 480, 480)], width=640)
    # the window's top edge at y = 200 (scale 0.5) between x = 200 and 240: the window colour
    edge = out[200, 220].astype(int)
    assert np.abs(edge - np.array(WINDOW_RGB)).max() < 40
    assert out[220, 220].sum() < 60  # inside left dark
    # the NO LOCK banner: red text in the top-left corner
    corner = out[4:20, 4:120].reshape(-1, 3).astype(int)
    assert (corner[:, 0] - corner[:, 1] > 100).any()


def test_colours_cycle_past_five_ids() -> None:
    assert led_color(6) == led_color(1) and led_color(5) != led_color(1)


def test_rejected_candidates_are_grey_crosses() -> None:
    img = np.zeros((1024, 1280), np.uint8)
    pose = PoseResult(lock=False, rejected_left_px=[(400.0, 400.0)], rejected_right_px=[])
    marks = image_marks(pose, "left")
    assert marks.rejected_px == ((400.0, 400.0),) and image_marks(pose, "right").rejected_px == ()
    out = annotate(img, pose, "left", width=640)
    # a tilted cross centred on (200, 200): grey on its diagonals, dark off them
    diag = out[202, 202].astype(int)
    assert diag.min() > 60 and np.ptp(diag) < 30
    assert out[200, 206].sum() < 60
