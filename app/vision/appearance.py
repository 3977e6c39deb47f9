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

:func:`appearance_reasons` says why one pair fails (the text for the trace);
:func:`appearance_ok` gives the verdicts for all matched pairs at once in a compiled loop
(:mod:`app.vision.appearance_kernels`; the same operations in the same order: the same
verdicts), so that the pipeline builds the reason strings for the rejected pairs only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from app.vision.appearance_kernels import appearance_kernel
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
    # colour input: refuse clearly non-green blobs before matching (else only after it)
    colour_gate: bool = True


def equivalent_radius_px(area_px: float) -> float:
    """Radius (px) of the disc of this area."""
    return math.sqrt(max(float(area_px), 0.0) / math.pi)


def blob_color_bgr(
    image: NDArray[np.uint8], blob: Blob, threshold: int, saturated_dn: float = 250.0
) -> tuple[float, ...]:
    """The blob's colour (B, G, R, DN) as its light above the local background: over the
    blob's box grown by 2 px, the mean excess over the box border's per-channel median of the
    pixels that are bright (gray ≥ background + 10 % of the peak's excess) and unsaturated in
    every channel — a saturated LED is judged on its unsaturated flanks, where a green LED
    stays green and a sun glint is white or yellow. With no such pixel, the mean over the
    pixels at or above the gray threshold (saturated: not judged)."""
    x, y, w, h = blob.bbox
    height, width = image.shape[:2]
    x0, y0 = max(0, x - 2), max(0, y - 2)
    x1, y1 = min(width, x + w + 2), min(height, y + h + 2)
    patch = image[y0:y1, x0:x1, :3].astype(np.float64)
    gray = patch @ np.array([0.114, 0.587, 0.299])
    border = np.concatenate([patch[0], patch[-1], patch[1:-1, 0], patch[1:-1, -1]])
    bg = np.median(border, axis=0)
    bg_gray = float(bg @ np.array([0.114, 0.587, 0.299]))
    level = bg_gray + 0.1 * (float(gray.max()) - bg_gray)
    sel = (gray >= level) & (patch.max(axis=2) < saturated_dn)
    if np.count_nonzero(sel) >= 2:
        excess = np.maximum(patch[sel].mean(axis=0) - bg, 0.0)
        return tuple(float(v) for v in excess)
    sel = gray >= threshold
    if not np.any(sel):
        return (0.0, 0.0, 0.0)
    return tuple(float(v) for v in patch[sel].mean(axis=0))


def colour_reason(blob: Blob, cfg: AppearanceConfig) -> str | None:
    """Why a blob's colour is not an LED's (None: green, or not judged: gray input or
    saturated) — the colour gate before matching and the appearance test's colour rule."""
    col = blob.color_bgr
    if not cfg.enabled or col is None or max(col) >= cfg.saturated_dn:
        return None
    bb, g, rr = col
    if g < cfg.green_ratio * max(bb, rr):
        return f"not green (B, G, R = {bb:.0f}, {g:.0f}, {rr:.0f})"
    return None


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
        why = colour_reason(blob, cfg)
        if why is not None:
            out.append(f"{side} blob is {why}")
    return out


_NO_COLOR = (math.nan, math.nan, math.nan)


@dataclass(frozen=True)
class BlobTable:
    """The appearance-relevant numbers of a list of blobs, one row per blob (aligned with the
    list): area (px), peak (DN), mean colour B, G, R (DN; NaN where the blob has none)."""

    values: NDArray[np.float64]  # (N, 5)

    @classmethod
    def of(cls, blobs: list[Blob]) -> BlobTable:
        values = np.empty((len(blobs), 5))
        values[:, 0] = [b.area_px for b in blobs]
        values[:, 1] = [b.peak for b in blobs]
        colors = [b.color_bgr for b in blobs]
        if any(c is not None for c in colors):
            values[:, 2:] = [c or _NO_COLOR for c in colors]
        else:  # gray input
            values[:, 2:] = math.nan
        return cls(values)


def _params(
    f_left_px: float,
    f_right_px: float,
    led_diameter_mm: float,
    background_dn: tuple[float, float],
    cfg: AppearanceConfig,
) -> NDArray[np.float64]:
    return np.array(
        [
            f_left_px,
            f_right_px,
            led_diameter_mm,
            background_dn[0],
            background_dn[1],
            cfg.size_low_frac,
            cfg.size_high_frac,
            cfg.size_slack_px,
            cfg.stereo_size_ratio,
            cfg.stereo_peak_ratio,
            cfg.green_ratio,
            cfg.saturated_dn,
        ],
        dtype=np.float64,
    )


def appearance_ok(
    left: BlobTable,
    right: BlobTable,
    left_index: NDArray[np.int64],
    right_index: NDArray[np.int64],
    z_left_mm: NDArray[np.float64],
    z_right_mm: NDArray[np.float64],
    f_left_px: float,
    f_right_px: float,
    led_diameter_mm: float,
    background_dn: tuple[float, float],
    cfg: AppearanceConfig,
) -> NDArray[np.bool_]:
    """For each pair ``left_index[k] ↔ right_index[k]``, whether it looks like one LED:
    :func:`appearance_reasons` returns [] exactly where this is True (compiled, all pairs at
    once; build the reasons for the others only)."""
    n = len(left_index)
    if not cfg.enabled or n == 0:
        return np.ones(n, dtype=np.bool_)
    li = np.ascontiguousarray(left_index, dtype=np.int64)
    ri = np.ascontiguousarray(right_index, dtype=np.int64)
    if len(ri) != n or len(z_left_mm) != n or len(z_right_mm) != n:
        raise ValueError("pairs, depths and blob tables do not agree")
    return np.asarray(
        appearance_kernel(
            left.values,
            right.values,
            li,
            ri,
            np.ascontiguousarray(z_left_mm, dtype=np.float64),
            np.ascontiguousarray(z_right_mm, dtype=np.float64),
            _params(f_left_px, f_right_px, led_diameter_mm, background_dn, cfg),
        )
    )
