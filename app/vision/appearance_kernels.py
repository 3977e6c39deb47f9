"""The LED appearance test's compiled loop (numba, cached on disk): the verdicts of
:func:`app.vision.appearance.appearance_ok` for all matched pairs at once (size at depth,
stereo size, stereo brightness, colour), the operations of
:func:`~app.vision.appearance.appearance_reasons` in the same order.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def appearance_kernel(
    left: np.ndarray,
    right: np.ndarray,
    left_index: np.ndarray,
    right_index: np.ndarray,
    z_left: np.ndarray,
    z_right: np.ndarray,
    params: np.ndarray,
) -> np.ndarray:  # pragma: no cover - compiled
    """:func:`~app.vision.appearance.appearance_reasons`' tests for the pairs
    ``left[left_index[k]] ↔ right[right_index[k]]`` (rows of
    :class:`~app.vision.appearance.BlobTable` values) at depths ``z_left[k]``, ``z_right[k]``
    (mm); ``params``: f_left, f_right (px), LED diameter (mm), backgrounds left, right (DN),
    then the :class:`~app.vision.appearance.AppearanceConfig` bounds (size_low_frac,
    size_high_frac, size_slack_px, stereo_size_ratio, stereo_peak_ratio, green_ratio,
    saturated_dn). The same operations in the same order: the same verdicts."""
    f_l, f_r, led_d, bg_l, bg_r = params[0], params[1], params[2], params[3], params[4]
    low, high, slack_px, size_ratio = params[5], params[6], params[7], params[8]
    peak_ratio, green_ratio, saturated = params[9], params[10], params[11]
    n = left_index.shape[0]
    ok = np.ones(n, np.bool_)
    for k in range(n):
        i, j = left_index[k], right_index[k]
        if i < 0 or j < 0 or i >= left.shape[0] or j >= right.shape[0]:
            raise ValueError("pairs, depths and blob tables do not agree")
        bl, br = left[i], right[j]
        rho_l = f_l * 0.5 * led_d / max(z_left[k], 1e-6)
        rho_r = f_r * 0.5 * led_d / max(z_right[k], 1e-6)
        r_l = math.sqrt(max(bl[0], 0.0) / math.pi)
        r_r = math.sqrt(max(br[0], 0.0) / math.pi)
        if not (low * rho_l - slack_px <= r_l <= high * rho_l + slack_px):
            ok[k] = False
        if not (low * rho_r - slack_px <= r_r <= high * rho_r + slack_px):
            ok[k] = False
        a, b = r_l / max(rho_l, 1e-9), r_r / max(rho_r, 1e-9)
        slack = slack_px / max(min(rho_l, rho_r), 1e-9)
        if max(a, b) > size_ratio * min(a, b) + slack:
            ok[k] = False
        pl = max(bl[1] - bg_l, 1.0)
        pr = max(br[1] - bg_r, 1.0)
        if max(pl, pr) > peak_ratio * min(pl, pr):
            ok[k] = False
        for row in (bl, br):
            cb, cg, cr = row[2], row[3], row[4]
            if np.isnan(cb) or max(cb, cg, cr) >= saturated:
                continue
            if cg < green_ratio * max(cb, cr):
                ok[k] = False
    return ok
