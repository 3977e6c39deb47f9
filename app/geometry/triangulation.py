"""Stereo triangulation: the paper's linear least squares (eqs. 15–16) and a refinement
minimising the reprojection error in both images. Inputs are ideal (undistorted) pixels.

The per-point arithmetic (a 3×3 normal-equation solve per point and per Gauss–Newton step)
runs in the compiled loops of :mod:`app.geometry.triangulation_kernels`.
"""

from __future__ import annotations

import numpy as np

from app.geometry.triangulation_kernels import linear_kernel, refine_kernel
from app.types import FloatArray


def _points(x: FloatArray, width: int) -> FloatArray:
    """A C-contiguous float64 (n, width) read-only view: the compiled loops then always see
    the same argument type (cached projection matrices are read-only, computed points not)."""
    out = np.ascontiguousarray(np.asarray(x, dtype=np.float64).reshape(-1, width)).view()
    out.setflags(write=False)
    return out


def triangulate_linear(
    P_left: FloatArray, P_right: FloatArray, x_left: FloatArray, x_right: FloatArray
) -> FloatArray:
    """Eqs. 15–16: X = (MᵀM)⁻¹ MᵀU, with rows ``u·h₃ − h₁`` (N×3, mm).

    M (4×3) stacks, per image, ``u·h_{31..33} − h_{11..13}`` and ``v·h_{31..33} − h_{21..23}``;
    U (4) stacks ``h_{14} − u·h_{34}`` and ``h_{24} − v·h_{34}``.
    """
    return np.asarray(
        linear_kernel(
            _points(P_left, 4), _points(P_right, 4), _points(x_left, 2), _points(x_right, 2)
        )
    )


def refine_reprojection(
    P_left: FloatArray,
    P_right: FloatArray,
    x_left: FloatArray,
    x_right: FloatArray,
    X0: FloatArray,
    iterations: int = 5,
) -> tuple[FloatArray, FloatArray]:
    """Gauss–Newton on the 4 reprojection residuals per point (the maximum-likelihood point
    under isotropic pixel noise). Returns (X mm N×3, RMS reprojection px N)."""
    X, rms = refine_kernel(
        _points(P_left, 4),
        _points(P_right, 4),
        _points(x_left, 2),
        _points(x_right, 2),
        _points(X0, 3),
        int(iterations),
    )
    return np.asarray(X), np.asarray(rms)
