"""Joint refinement of a stereo calibration *with* the skew γ of eq. 2 (paper §3.2), which
OpenCV's camera model lacks: both cameras, the rig (R, T) and every board pose, by sparse
least squares (scipy), started from OpenCV's skew-free result.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from app.calibration.opencv_fit import StereoFit
from app.types import FloatArray


def _rodrigues_many(rvecs: FloatArray) -> FloatArray:
    """(N, 3) rotation vectors → (N, 3, 3) matrices."""
    theta = np.linalg.norm(rvecs, axis=1)
    safe = np.where(theta > 1e-12, theta, 1.0)
    k = rvecs / safe[:, None]
    kx = np.zeros((len(rvecs), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2] = -k[:, 2], k[:, 1]
    kx[:, 1, 0], kx[:, 1, 2] = k[:, 2], -k[:, 0]
    kx[:, 2, 0], kx[:, 2, 1] = -k[:, 1], k[:, 0]
    s = np.sin(theta)[:, None, None]
    c = (1 - np.cos(theta))[:, None, None]
    return np.asarray(np.eye(3)[None] + s * kx + c * (kx @ kx), dtype=np.float64)


def _project_skew(cam: FloatArray, n_dist: int, X: FloatArray) -> FloatArray:
    """Eqs. 2 + 7 with skew: camera-frame points (..., 3) → distorted pixels (..., 2).

    ``cam`` = [fx, fy, γ, u0, v0, k1, k2(, p1, p2, k3)]; same model as
    :func:`app.geometry.projection.project_camera`.
    """
    fx, fy, g, u0, v0 = cam[:5]
    k1, k2 = cam[5], cam[6]
    p1, p2, k3 = (cam[7], cam[8], cam[9]) if n_dist == 5 else (0.0, 0.0, 0.0)
    x = X[..., 0] / X[..., 2]
    y = X[..., 1] / X[..., 2]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([fx * xd + g * yd + u0, fy * yd + v0], axis=-1)


def refine_with_skew(
    obj: FloatArray,
    img_l: Sequence[FloatArray],
    img_r: Sequence[FloatArray],
    K_l: FloatArray,
    d_l: FloatArray,
    K_r: FloatArray,
    d_r: FloatArray,
    R: FloatArray,
    T: FloatArray,
    rvecs: Sequence[FloatArray],
    tvecs: Sequence[FloatArray],
    model: str,
) -> StereoFit:
    """Joint refinement of both cameras *with* the skew γ of eq. 2, the rig (R, T) and every
    board pose, by sparse least squares (scipy), started from OpenCV's skew-free result.

    This restores the parameter the paper's calibration (Zhang's method) estimates and
    OpenCV's model lacks.
    """
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    n_dist = 2 if model == "paper" else 5
    nc = 5 + n_dist
    n_views = len(img_l)
    obs_l = np.stack([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in img_l])
    obs_r = np.stack([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in img_r])
    n_pts = obs_l.shape[1]
    X = np.asarray(obj, dtype=np.float64).reshape(-1, 3)

    def cam_vec(K: FloatArray, d: FloatArray) -> FloatArray:
        dd = np.zeros(5)
        dd[: min(5, d.size)] = d.ravel()[:5]
        terms = dd[:2] if n_dist == 2 else dd
        return np.concatenate([[K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2]], terms])

    x0 = np.concatenate(
        [
            cam_vec(K_l, d_l),
            cam_vec(K_r, d_r),
            cv2.Rodrigues(np.asarray(R, dtype=np.float64))[0].ravel(),
            np.asarray(T, dtype=np.float64).ravel(),
            np.concatenate(
                [
                    np.concatenate([np.ravel(rv), np.ravel(tv)])
                    for rv, tv in zip(rvecs, tvecs, strict=True)
                ]
            ),
        ]
    )
    o_rig = 2 * nc
    o_views = o_rig + 6

    def residuals(x: FloatArray) -> FloatArray:
        poses = x[o_views:].reshape(n_views, 6)
        Rv = _rodrigues_many(poses[:, :3])
        Xl = np.einsum("nij,pj->npi", Rv, X) + poses[:, None, 3:]
        R_rig = _rodrigues_many(x[o_rig : o_rig + 3][None])[0]
        Xr = Xl @ R_rig.T + x[o_rig + 3 : o_rig + 6]
        el = _project_skew(x[:nc], n_dist, Xl) - obs_l
        er = _project_skew(x[nc : 2 * nc], n_dist, Xr) - obs_r
        return np.concatenate([el, er], axis=1).ravel()

    n_res = n_views * 2 * n_pts * 2
    sparsity = lil_matrix((n_res, x0.size), dtype=np.int8)
    for i in range(n_views):
        base = i * 4 * n_pts
        left_rows = slice(base, base + 2 * n_pts)
        right_rows = slice(base + 2 * n_pts, base + 4 * n_pts)
        view_cols = slice(o_views + 6 * i, o_views + 6 * i + 6)
        sparsity[left_rows, 0:nc] = 1
        sparsity[left_rows, view_cols] = 1
        sparsity[right_rows, nc : 2 * nc] = 1
        sparsity[right_rows, o_rig : o_rig + 6] = 1
        sparsity[right_rows, view_cols] = 1
    sol = least_squares(
        residuals,
        x0,
        jac_sparsity=sparsity,
        method="trf",
        x_scale="jac",
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
        max_nfev=200,
    )
    x = sol.x
    e = residuals(x).reshape(n_views, 2, n_pts, 2)
    sq = np.sum(e**2, axis=3)  # (views, cam, pts)
    per_view = np.sqrt(np.mean(sq, axis=2))

    def unpack(v: FloatArray) -> tuple[FloatArray, FloatArray]:
        K = np.array([[v[0], v[2], v[3]], [0.0, v[1], v[4]], [0.0, 0.0, 1.0]])
        d = np.zeros(5)
        d[:n_dist] = v[5 : 5 + n_dist]
        return K, d

    Kl, dl = unpack(x[:nc])
    Kr, dr = unpack(x[nc : 2 * nc])
    poses = x[o_views:].reshape(n_views, 6)
    return StereoFit(
        rms=float(np.sqrt(np.mean(sq))),
        K_l=Kl,
        d_l=dl,
        K_r=Kr,
        d_r=dr,
        R=_rodrigues_many(x[o_rig : o_rig + 3][None])[0],
        T=x[o_rig + 3 : o_rig + 6].copy(),
        rvecs=[p[:3].reshape(3, 1) for p in poses],
        tvecs=[p[3:].reshape(3, 1) for p in poses],
        per_view=per_view,
    )
