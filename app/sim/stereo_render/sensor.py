"""The sensor's part of a rendered image: background and Gaussian sensor noise (fresh, or a
cached noise field at a random offset with ``fast_noise``), the blobs' patches added and the
result quantised to uint8 — optionally only inside a tracker's windows, bit-identical there to
the full render (the same random draws, the same blobs in the same order)."""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from app.sim.stereo_render.blobs import LightSpot, blob_patches, draw_spots
from app.sim.stereo_render.patch_kernels import paste_patch
from app.sim.stereo_render.scene import RenderSettings
from app.types import Rect

NOISE_FIELD_PAD = 256  # px added to each side of the cached noise field (fast_noise)
_GREY = np.ones(1, dtype=np.float32)  # a grey image's one channel weight


def _paste(
    canvas: NDArray[Any],
    x0: int,
    y0: int,
    patch: NDArray[np.float32],
    bgr: NDArray[np.float32] | None,
) -> tuple[int, int, int, int, NDArray[np.float32]] | None:
    """Clip a patch to the canvas; returns (ya, yb, xa, xb, clipped patch[, ×bgr]) or None."""
    h, w = canvas.shape[:2]
    ph, pw = patch.shape
    xa, ya = max(x0, 0), max(y0, 0)
    xb, yb = min(x0 + pw, w), min(y0 + ph, h)
    if xa >= xb or ya >= yb:
        return None
    p = patch[ya - y0 : yb - y0, xa - x0 : xb - x0]
    if bgr is not None:
        p = p[:, :, None] * bgr[None, None, :]
    return ya, yb, xa, xb, p


def clip_rects(rects: list[Rect], shape: tuple[int, ...]) -> list[Rect]:
    """Rectangles clipped to the image; empty ones dropped."""
    h, w = shape[:2]
    out = []
    for x0, y0, x1, y1 in rects:
        xa, ya, xb, yb = max(int(x0), 0), max(int(y0), 0), min(int(x1), w), min(int(y1), h)
        if xa < xb and ya < yb:
            out.append((xa, ya, xb, yb))
    return out


def compose(
    shape: tuple[int, ...],
    blobs: list[LightSpot],
    settings: RenderSettings,
    rng: np.random.Generator,
    windows: list[Rect] | None = None,
    patches: list[tuple[int, int, NDArray[np.float32], NDArray[np.float32]]] | None = None,
) -> NDArray[np.uint8]:
    """Background + noise + blobs → uint8 image.

    ``windows``: render only these rectangles (pixels elsewhere are 0); inside them the image
    is bit-identical to the full render (same random draws, same blobs in the same order).
    ``patches``: the blobs' patches (x0, y0, patch, bgr), computed beforehand (in order).
    """
    color = len(shape) == 3
    rects = None if windows is None else clip_rects(windows, shape)
    if settings.fast_noise:
        if rects is None:
            base = _noise_window(shape, settings, rng)
        else:
            base = _noise_windows(shape, settings, rng, rects)
        canvas = base.reshape(shape[0], shape[1], -1)  # a view: (h, w, channels)
        boxes = np.array(rects if rects is not None else [], dtype=np.int64).reshape(-1, 4)
        if patches is None:  # drawn straight into the image (only those reaching a window)
            draw_spots(canvas, blobs, settings, boxes, rects is None, color)
        for x0, y0, patch, bgr in patches or []:
            weights = bgr if color else _GREY
            paste_patch(canvas, x0, y0, patch, weights, boxes, rects is None)
        return base
    if patches is None:
        made = blob_patches(blobs, settings.supersample, settings.blur_sigma_px)
        patches = [(x0, y0, p, b.bgr) for (x0, y0, p), b in zip(made, blobs, strict=True)]
    img = np.full(shape, settings.background, dtype=np.float32)
    if settings.noise_sigma > 0:
        img += rng.standard_normal(shape, dtype=np.float32) * np.float32(settings.noise_sigma)
    for x0, y0, patch, bgr in patches:
        cut = _paste(img, x0, y0, patch, bgr if color else None)
        if cut is None:
            continue
        ya, yb, xa, xb, p = cut
        img[ya:yb, xa:xb] += p
    full = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if rects is None:
        return full
    out = np.zeros(shape, dtype=np.uint8)  # fresh noise needs the whole frame's draws anyway
    for xa, ya, xb, yb in rects:
        out[ya:yb, xa:xb] = full[ya:yb, xa:xb]
    return out


@lru_cache(maxsize=8)
def _noise_field(
    shape: tuple[int, ...], background: float, sigma: float, seed: int
) -> NDArray[np.uint8]:
    """Pre-quantised background + noise, padded by NOISE_FIELD_PAD px on each side."""
    h, w = shape[:2]
    big = (h + 2 * NOISE_FIELD_PAD, w + 2 * NOISE_FIELD_PAD, *shape[2:])
    rng = np.random.default_rng(seed)
    f = background + sigma * rng.standard_normal(big, dtype=np.float32)
    field_u8 = np.clip(np.rint(f), 0, 255).astype(np.uint8)
    field_u8.setflags(write=False)
    return field_u8


def _noise_window(
    shape: tuple[int, ...], settings: RenderSettings, rng: np.random.Generator
) -> NDArray[np.uint8]:
    """A writable copy of the cached noise field at a random offset (fast_noise)."""
    noise = _noise_field(shape, float(settings.background), float(settings.noise_sigma), 0)
    h, w = shape[:2]
    oy, ox = rng.integers(0, 2 * NOISE_FIELD_PAD + 1, size=2)
    return noise[oy : oy + h, ox : ox + w].copy()


def _noise_windows(
    shape: tuple[int, ...], settings: RenderSettings, rng: np.random.Generator, rects: list[Rect]
) -> NDArray[np.uint8]:
    """:func:`_noise_window`'s field (same offset draw) copied into ``rects`` only; zeros
    elsewhere."""
    noise = _noise_field(shape, float(settings.background), float(settings.noise_sigma), 0)
    oy, ox = rng.integers(0, 2 * NOISE_FIELD_PAD + 1, size=2)
    out = np.zeros(shape, dtype=np.uint8)
    for xa, ya, xb, yb in rects:
        out[ya:yb, xa:xb] = noise[oy + ya : oy + yb, ox + xa : ox + xb]
    return out
