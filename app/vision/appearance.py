"""LED appearance tests that separate the drogue's LEDs from other bright points.

A matched, triangulated point is kept as an LED candidate only if its two images look like the
same LED at that depth:

* **size** — the blob's equivalent radius (px) is consistent with the LED's physical diameter
  at the triangulated depth, ρ = f·(d/2)/Z, widened by the blur and the threshold (generous
  bounds: a glint of another size at that depth, or a far lamp, fails);
* **stereo size** — the left and right blobs have consistent sizes (an LED is a small sphere:
  both cameras see the same disc, scaled by f/Z);
* **stereo brightness** — both images see the same peak level (an emitter; a specular glint is
  view-dependent);
* **colour** (BGR input only) — green dominates (the LEDs are green, paper §3.1); saturated
  blobs are not judged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.vision.types import Blob


@dataclass(frozen=True)
class AppearanceConfig:
    """Bounds of the appearance tests (px, ratios)."""

    enabled: bool = True
    size_low_frac: float = 0.4  # r_eq ≥ low·ρ − slack_px
    size_high_frac: float = 2.5  # r_eq ≤ high·ρ + slack_px
    size_slack_px: float = 2.0
    stereo_size_ratio: float = 1.6  # max/min of the f/Z-normalised radii (+ slack)
    stereo_peak_ratio: float = 1.6  # max/min of the background-subtracted peaks
    green_ratio: float = 1.4  # G ≥ ratio·max(B, R) over the blob (colour input)
    saturated_dn: float = 250.0


def equivalent_radius_px(area_px: float) -> float:
    """Radius (px) of the disc of this area."""
    return math.sqrt(max(float(area_px), 0.0) / math.pi)


def blob_color_bgr(image: NDArray[np.uint8], blob: Blob, threshold: int) -> tuple[float, ...]:
    """Mean (B, G, R) over the blob's pixels at or above the gray threshold (colour input)."""
    x, y, w, h = blob.bbox
    patch = image[y : y + h, x : x + w, :3].astype(np.float64)
    gray = patch @ np.array([0.114, 0.587, 0.299])
    sel = gray >= threshold
    if not np.any(sel):
        return (0.0, 0.0, 0.0)
    return tuple(float(v) for v in patch[sel].mean(axis=0))


def appearance_reasons(
    left: Blob,
    right: Blob,
    z_left_mm: float,
    z_right_mm: float,
    f_left_px: float,
    f_right_px: float,
    led_diameter_mm: float,
    background_dn: tuple[float, float],
    cfg: AppearanceConfig,
) -> list[str]:
    """Why this matched pair does not look like one LED ([] when it does)."""
    if not cfg.enabled:
        return []
    out: list[str] = []
    rho_l = f_left_px * 0.5 * led_diameter_mm / max(z_left_mm, 1e-6)
    rho_r = f_right_px * 0.5 * led_diameter_mm / max(z_right_mm, 1e-6)
    r_l, r_r = equivalent_radius_px(left.area_px), equivalent_radius_px(right.area_px)
    for side, r, rho in (("left", r_l, rho_l), ("right", r_r, rho_r)):
        lo = cfg.size_low_frac * rho - cfg.size_slack_px
        hi = cfg.size_high_frac * rho + cfg.size_slack_px
        if not lo <= r <= hi:
            out.append(
                f"{side} blob radius {r:.1f} px is not an LED's at {z_left_mm / 1000:.2f} m "
                f"(expected {lo:.1f}–{hi:.1f} px)"
            )
    a, b = r_l / max(rho_l, 1e-9), r_r / max(rho_r, 1e-9)
    slack = cfg.size_slack_px / max(min(rho_l, rho_r), 1e-9)
    if max(a, b) > cfg.stereo_size_ratio * min(a, b) + slack:
        out.append(f"left/right blob sizes differ ({r_l:.1f} vs {r_r:.1f} px)")
    pl = max(left.peak - background_dn[0], 1.0)
    pr = max(right.peak - background_dn[1], 1.0)
    if max(pl, pr) > cfg.stereo_peak_ratio * min(pl, pr):
        out.append(f"left/right peak levels differ ({left.peak:.0f} vs {right.peak:.0f} DN)")
    for side, blob in (("left", left), ("right", right)):
        col = blob.color_bgr
        if col is None or max(col) >= cfg.saturated_dn:
            continue
        bb, g, rr = col
        if g < cfg.green_ratio * max(bb, rr):
            out.append(f"{side} blob is not green (B, G, R = {bb:.0f}, {g:.0f}, {rr:.0f})")
    return out
