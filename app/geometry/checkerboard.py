"""Stereo rig calibration from checkerboard pictures (paper §3.2, Zhang's method [18, 19]).

The paper photographs a checkerboard (CCP) from several angles with both cameras and
estimates fx, fy, γ, u0, v0, k1, k2 for each camera (eqs. 2, 7) and the rig's R, T (eqs. 3–5).
Here the same is done with OpenCV:

1. inner corners are found and localised to sub-pixel accuracy with
   ``cv2.findChessboardCornersSB`` (``CALIB_CB_ACCURACY``; ``cv2.cornerSubPix`` and the classic
   detector are options, see :func:`detect_corners`);
2. each camera is calibrated (``cv2.calibrateCamera``: Zhang's closed form + Levenberg–Marquardt);
3. the rig is refined jointly (``cv2.stereoCalibrate``, intrinsics as initial guess);
4. optionally (``estimate_skew``) everything is refined once more *with* the skew γ
   (:func:`refine_with_skew`, sparse least squares), which OpenCV's model lacks.

Distortion models: ``"paper"`` estimates k1, k2 only (``CALIB_FIX_K3 | CALIB_ZERO_TANGENT_DIST``,
the paper's eq. 7); ``"full"`` estimates OpenCV's five terms k1, k2, p1, p2, k3.
OpenCV's pinhole model has no skew: without step 4, γ is **not** estimated and is 0 in the
output.

Bad input raises :class:`CheckerboardError` (a ``ValueError``) with a one-line message.
This module is pure (numpy/OpenCV; matplotlib only inside :func:`write_report_png`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import CalibrationError, FloatArray, StereoCalibration

MIN_VIEWS = 6
DEFAULT_MAX_STEREO_RMS_PX = 0.5
Model = Literal["paper", "full"]
MODEL_FLAGS: dict[str, int] = {
    "paper": cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST,
    "full": 0,
}
SKEW_NOTE = (
    "OpenCV's camera model has no skew term: γ is not estimated and is written as 0 "
    "(the paper's Table 1 lists γ = -4.5 / -0.49 px)."
)
SKEW_REFINED_NOTE = (
    "Skew γ estimated: OpenCV's skew-free result was refined jointly with γ (both cameras, "
    "rig and board poses) by sparse least squares."
)
_TERM = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-10)


class CheckerboardError(ValueError):
    """A checkerboard set cannot be calibrated; the message says why, in one line."""


# ---------------------------------------------------------------------------------------
# board description
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Board:
    """``cols`` × ``rows`` inner corners (OpenCV's patternSize), squares of ``square_mm``."""

    cols: int
    rows: int
    square_mm: float

    def __post_init__(self) -> None:
        if self.cols < 3 or self.rows < 3:
            raise CheckerboardError(
                f"board {self.cols}x{self.rows}: need at least 3x3 inner corners "
                "(the board size counts inner corners, i.e. squares - 1)"
            )
        if self.cols == self.rows:
            raise CheckerboardError(
                f"board {self.cols}x{self.rows}: a square board's orientation is ambiguous; "
                "use a board with different inner-corner counts per row and column"
            )
        if not (math.isfinite(self.square_mm) and self.square_mm > 0):
            raise CheckerboardError(
                f"square size must be a positive number of mm, got {self.square_mm}"
            )

    @property
    def pattern_size(self) -> tuple[int, int]:
        return (self.cols, self.rows)

    def object_points(self) -> NDArray[np.float32]:
        """Inner corners in the board frame (N×3, mm), row-major: corner (i, j) at (i·s, j·s, 0)."""
        jj, ii = np.mgrid[0 : self.rows, 0 : self.cols]
        pts = np.column_stack([ii.ravel(), jj.ravel(), np.zeros(ii.size)]) * self.square_mm
        return pts.astype(np.float32)


def parse_board(text: str) -> tuple[int, int]:
    """``"9x6"`` → (9, 6) inner corners per row × per column."""
    m = re.fullmatch(r"\s*(\d+)\s*[xX×*,]\s*(\d+)\s*", str(text))
    if not m:
        raise CheckerboardError(f"board {text!r}: expected COLSxROWS inner corners, e.g. 9x6")
    return int(m.group(1)), int(m.group(2))


def pair_name(left_file: str, right_file: str) -> str:
    """Short name of a stereo pair from its file names: ``left_03.png``/``right_03.png`` → ``03``."""
    ls, rs = Path(left_file).stem, Path(right_file).stem
    for lp, rp in (("left", "right"), ("l", "r")):
        if ls.lower().startswith(lp) and rs.lower().startswith(rp):
            rest_l, rest_r = ls[len(lp) :], rs[len(rp) :]
            if rest_l == rest_r and rest_l.strip("_-. "):
                return rest_l.strip("_-. ")
    return ls if ls == rs else f"{ls}|{rs}"


# ---------------------------------------------------------------------------------------
# corner detection
# ---------------------------------------------------------------------------------------
def to_gray(image: NDArray[Any]) -> NDArray[np.uint8]:
    """8-bit grey from grey/BGR/BGRA (uint8 or uint16) input."""
    img = np.asarray(image)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise CheckerboardError(f"images must be 8- or 16-bit, got {img.dtype}")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY)
    if img.ndim != 2:
        raise CheckerboardError(f"unsupported image shape {img.shape}")
    return np.ascontiguousarray(img)


def _canonical_order(corners: FloatArray) -> FloatArray:
    """Put corner 0 at the image's upper-left end of the grid (the grid is 180°-ambiguous)."""
    d = corners[-1] - corners[0]
    return corners[::-1].copy() if d[0] + d[1] < 0 else corners


def detect_corners(
    image: NDArray[Any],
    pattern_size: tuple[int, int],
    accurate: bool = True,
    corner_subpix: bool = False,
    classic_fallback: bool = False,
) -> FloatArray | None:
    """Inner corners (N×2, px, row-major; pixel centres at integers) or None if not found.

    ``findChessboardCornersSB`` finds the board and localises the corners to sub-pixel
    accuracy; ``accurate`` then repeats it with ``CALIB_CB_ACCURACY`` (the image is up-sampled
    for the sub-pixel step, ≈ 4× slower; a miss stays fast). ``corner_subpix`` refines further with ``cv2.cornerSubPix``
    (window ≈ a quarter of the corner spacing) — off by default: on the synthetic set it biased
    the recovered focal lengths by +0.03 % to +0.06 %, against < 0.01 % without
    (docs/calibration.md). ``classic_fallback`` tries ``findChessboardCorners`` when SB fails
    (≈ 4× slower on a miss, rarely finds more).
    """
    gray = to_gray(image)
    flags = cv2.CALIB_CB_NORMALIZE_IMAGE
    ok, corners = cv2.findChessboardCornersSB(gray, pattern_size, flags=flags)
    if ok and corners is not None and accurate:
        # the board is there: locate the corners again on the up-sampled image
        ok_acc, corners_acc = cv2.findChessboardCornersSB(
            gray, pattern_size, flags=flags | cv2.CALIB_CB_ACCURACY
        )
        if ok_acc and corners_acc is not None:
            corners = corners_acc
    if (not ok or corners is None) and classic_fallback:
        ok, corners = cv2.findChessboardCorners(
            gray, pattern_size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        )
        if ok and corners is not None:
            corner_subpix = True  # the classic detector is only pixel-accurate
    if not ok or corners is None:
        return None
    pts = np.asarray(corners, dtype=np.float64).reshape(-1, 2)
    if len(pts) != pattern_size[0] * pattern_size[1]:
        return None
    if corner_subpix:
        grid = pts.reshape(pattern_size[1], pattern_size[0], 2)
        spacing = min(
            float(np.min(np.linalg.norm(np.diff(grid, axis=1), axis=2))),
            float(np.min(np.linalg.norm(np.diff(grid, axis=0), axis=2))),
        )
        half = int(np.clip(round(spacing / 4), 2, 11))
        refined = cv2.cornerSubPix(
            gray,
            pts.astype(np.float32).reshape(-1, 1, 2),
            (half, half),
            (-1, -1),
            (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4),
        )
        pts = np.asarray(refined, dtype=np.float64).reshape(-1, 2)
    return _canonical_order(pts)


def _match_orientation(left: FloatArray, right: FloatArray) -> FloatArray:
    """Return ``right`` in the corner order that matches ``left`` (near-parallel rig:
    the right corners are the left ones shifted by a smoothly varying disparity)."""
    flipped = right[::-1]
    spread = float(np.var(right - left, axis=0).sum())
    spread_f = float(np.var(flipped - left, axis=0).sum())
    return flipped.copy() if spread_f < spread else right


@dataclass
class PairDetection:
    """Corners found in one stereo pair (None where not found) and why a pair is unusable."""

    name: str
    image_size: tuple[int, int]  # (w, h) px
    left: FloatArray | None
    right: FloatArray | None

    @property
    def usable(self) -> bool:
        return self.left is not None and self.right is not None

    @property
    def reason(self) -> str | None:
        if self.usable:
            return None
        if self.left is None and self.right is None:
            return "board not found in either image"
        if self.left is None:
            return "board found in the right image only"
        return "board found in the left image only"


def image_size_of(image: NDArray[Any]) -> tuple[int, int]:
    arr = np.asarray(image)
    if arr.ndim not in (2, 3) or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise CheckerboardError(f"not an image (array shape {arr.shape})")
    return (int(arr.shape[1]), int(arr.shape[0]))


def check_image_sizes(
    names: Sequence[str], lefts: Sequence[NDArray[Any]], rights: Sequence[NDArray[Any]]
) -> tuple[int, int]:
    """All images must share one size; returns it (w, h) or raises with the first offender."""
    if len(lefts) != len(rights):
        raise CheckerboardError(f"{len(lefts)} left images but {len(rights)} right images")
    if not lefts:
        raise CheckerboardError("no images given")
    ref = image_size_of(lefts[0])
    for name, li, ri in zip(names, lefts, rights, strict=True):
        for side, img in (("left", li), ("right", ri)):
            size = image_size_of(img)
            if size != ref:
                raise CheckerboardError(
                    f"image sizes differ: {side} image of pair {name} is {size[0]}x{size[1]} px, "
                    f"the first left image is {ref[0]}x{ref[1]} px"
                )
    return ref


def detect_pairs(
    names: Sequence[str],
    lefts: Sequence[NDArray[Any]],
    rights: Sequence[NDArray[Any]],
    pattern_size: tuple[int, int],
    progress: bool = False,
    accurate: bool = True,
) -> list[PairDetection]:
    """Detect the board in every pair (sizes checked first). ``progress``: tqdm on stderr;
    ``accurate``: see :func:`detect_corners`."""
    size = check_image_sizes(names, lefts, rights)
    indices: Any = range(len(names))
    if progress:
        from tqdm import tqdm

        indices = tqdm(indices, desc="corners", unit="pair")
    out: list[PairDetection] = []
    for k in indices:
        cl = detect_corners(lefts[k], pattern_size, accurate=accurate)
        cr = detect_corners(rights[k], pattern_size, accurate=accurate)
        if cl is not None and cr is not None:
            cr = _match_orientation(cl, cr)
        out.append(PairDetection(names[k], size, cl, cr))
    return out


def suggest_board(image: NDArray[Any], pattern_size: tuple[int, int]) -> tuple[int, int] | None:
    """A nearby inner-corner count that *is* found in ``image`` (to explain a wrong --board)."""
    gray = to_gray(image)
    small = cv2.resize(gray, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    c, r = pattern_size
    candidates = [(c - 1, r - 1), (c + 1, r + 1), (c - 1, r), (c, r - 1), (c + 1, r), (c, r + 1)]
    candidates += [(c - 2, r - 2), (c + 2, r + 2)]
    for cand in candidates:
        if min(cand) < 3 or cand[0] == cand[1]:
            continue
        ok, _ = cv2.findChessboardCornersSB(small, cand, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if ok:
            return cand
    return None


# ---------------------------------------------------------------------------------------
# calibration + report
# ---------------------------------------------------------------------------------------
@dataclass
class ViewReport:
    """Per-view reprojection RMS (px) after the joint stereo refinement."""

    name: str
    left_rms_px: float
    right_rms_px: float


@dataclass
class RejectedView:
    name: str
    reason: str


@dataclass
class CalibrationReport:
    """Everything a user needs to judge a calibration (serialisable with :meth:`to_dict`)."""

    board: str  # "9x6" inner corners
    square_mm: float
    model: str
    image_size: tuple[int, int]
    pairs_given: int
    views_used: int
    views: list[ViewReport]
    rejected: list[RejectedView]
    left_rms_px: float  # single-camera calibration RMS (with skew: of the joint refinement)
    right_rms_px: float
    stereo_rms_px: float  # joint refinement RMS over both cameras
    max_stereo_rms_px: float
    baseline_mm: float
    convergence_deg: float
    T_mm: list[float]
    rotation_deg: float  # angle of R
    intrinsics: dict[str, dict[str, float]]
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["image_size"] = list(self.image_size)
        return d


@dataclass
class CheckerboardCalibration:
    """Result of :func:`calibrate_from_detections`: the validated calibration and its report."""

    calibration: StereoCalibration
    report: CalibrationReport
    detections: list[PairDetection]
    used: list[int]  # indices into detections

    def save(self, path: str | Path) -> None:
        self.calibration.save(path)


def _intrinsics_summary(K: FloatArray, dist: FloatArray) -> dict[str, float]:
    d = np.zeros(5)
    d[: min(5, dist.size)] = dist.ravel()[:5]
    return {
        "fx": float(K[0, 0]),
        "fy": float(K[1, 1]),
        "skew": float(K[0, 1]),
        "u0": float(K[0, 2]),
        "v0": float(K[1, 2]),
        "k1": float(d[0]),
        "k2": float(d[1]),
        "p1": float(d[2]),
        "p2": float(d[3]),
        "k3": float(d[4]),
    }


def _too_few_message(detections: Sequence[PairDetection], n_ok: int) -> str:
    counts: dict[str, int] = {}
    for det in detections:
        r = det.reason
        if r is not None:
            counts[r] = counts.get(r, 0) + 1
    why = "; ".join(f"{n} {r}" for r, n in sorted(counts.items(), key=lambda kv: -kv[1]))
    return (
        f"too few usable views: {n_ok} of {len(detections)} pairs have the board in both images, "
        f"need at least {MIN_VIEWS}" + (f" ({why})" if why else "")
    )


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


@dataclass
class _SkewFit:
    K_l: FloatArray
    d_l: FloatArray
    K_r: FloatArray
    d_r: FloatArray
    R: FloatArray
    T: FloatArray
    per_view: FloatArray  # (N, 2) RMS px, left/right
    rms: float
    rms_l: float
    rms_r: float


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
) -> _SkewFit:
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
    return _SkewFit(
        K_l=Kl,
        d_l=dl,
        K_r=Kr,
        d_r=dr,
        R=_rodrigues_many(x[o_rig : o_rig + 3][None])[0],
        T=x[o_rig + 3 : o_rig + 6].copy(),
        per_view=per_view,
        rms=float(np.sqrt(np.mean(sq))),
        rms_l=float(np.sqrt(np.mean(sq[:, 0]))),
        rms_r=float(np.sqrt(np.mean(sq[:, 1]))),
    )


def calibrate_from_detections(
    detections: Sequence[PairDetection],
    board: Board,
    model: Model | str = "paper",
    max_stereo_rms_px: float = DEFAULT_MAX_STEREO_RMS_PX,
    hint: Callable[[], str | None] | None = None,
    estimate_skew: bool = False,
) -> CheckerboardCalibration:
    """Calibrate both cameras, then the rig (Zhang's method via OpenCV), from detected corners.

    ``estimate_skew``: afterwards refine everything jointly with the skew γ of eq. 2
    (:func:`refine_with_skew`; OpenCV alone writes γ = 0). ``hint`` is called when too few
    views are usable to add e.g. a board-size suggestion.
    """
    if model not in MODEL_FLAGS:
        raise CheckerboardError(f"model {model!r}: expected one of {sorted(MODEL_FLAGS)}")
    if not detections:
        raise CheckerboardError("no images given")
    flags = MODEL_FLAGS[model]
    used = [k for k, d in enumerate(detections) if d.usable]
    if len(used) < MIN_VIEWS:
        msg = _too_few_message(detections, len(used))
        extra = hint() if hint is not None else None
        raise CheckerboardError(msg + (f"; {extra}" if extra else ""))
    size = detections[0].image_size
    obj = [board.object_points() for _ in used]
    img_l = [np.asarray(detections[k].left, dtype=np.float32).reshape(-1, 1, 2) for k in used]
    img_r = [np.asarray(detections[k].right, dtype=np.float32).reshape(-1, 1, 2) for k in used]

    try:
        rms_l, K_l0, d_l0, *_ = cv2.calibrateCamera(
            obj, img_l, size, None, None, flags=flags, criteria=_TERM
        )
        rms_r, K_r0, d_r0, *_ = cv2.calibrateCamera(
            obj, img_r, size, None, None, flags=flags, criteria=_TERM
        )
        res = cv2.stereoCalibrateExtended(
            obj,
            img_l,
            img_r,
            K_l0,
            d_l0,
            K_r0,
            d_r0,
            size,
            np.eye(3),
            np.zeros((3, 1)),
            flags=flags | cv2.CALIB_USE_INTRINSIC_GUESS,
            criteria=_TERM,
        )
    except cv2.error as exc:
        first = str(exc).strip().splitlines()[-1] if str(exc).strip() else "OpenCV error"
        raise CheckerboardError(
            f"calibration failed in OpenCV ({first}); check the views"
        ) from None
    stereo_rms, K_l_cv, d_l_cv, K_r_cv, d_r_cv, R, T, _E, _F, rvecs, tvecs, per_view = res
    K_l = np.asarray(K_l_cv, dtype=np.float64)
    K_r = np.asarray(K_r_cv, dtype=np.float64)
    d_l = np.asarray(d_l_cv, dtype=np.float64).ravel()
    d_r = np.asarray(d_r_cv, dtype=np.float64).ravel()
    K_l[0, 1] = K_r[0, 1] = 0.0
    if estimate_skew:
        fit = refine_with_skew(
            board.object_points().astype(np.float64),
            [np.asarray(p, dtype=np.float64) for p in img_l],
            [np.asarray(p, dtype=np.float64) for p in img_r],
            K_l,
            d_l,
            K_r,
            d_r,
            np.asarray(R, dtype=np.float64),
            np.asarray(T, dtype=np.float64),
            [np.asarray(v, dtype=np.float64) for v in rvecs],
            [np.asarray(v, dtype=np.float64) for v in tvecs],
            str(model),
        )
        K_l, d_l, K_r, d_r = fit.K_l, fit.d_l, fit.K_r, fit.d_r
        R, T = fit.R, fit.T
        stereo_rms, per_view, rms_l, rms_r = fit.rms, fit.per_view, fit.rms_l, fit.rms_r
    data = {
        "image_size": [size[0], size[1]],
        "left": {"K": K_l.tolist(), "dist": d_l[:5].tolist()},
        "right": {"K": K_r.tolist(), "dist": d_r[:5].tolist()},
        "R": np.asarray(R, dtype=np.float64).tolist(),
        "T": np.asarray(T, dtype=np.float64).ravel().tolist(),
        "units": "mm",
    }
    try:
        calib = StereoCalibration.from_dict(data)
    except CalibrationError as exc:
        raise CheckerboardError(f"calibration result is invalid: {exc}") from None

    per_view = np.asarray(per_view, dtype=np.float64).reshape(len(used), 2)
    views = [
        ViewReport(detections[k].name, float(per_view[i, 0]), float(per_view[i, 1]))
        for i, k in enumerate(used)
    ]
    rejected = [RejectedView(d.name, d.reason or "") for d in detections if not d.usable]
    warnings: list[str] = []
    if stereo_rms > max_stereo_rms_px:
        warnings.append(
            f"stereo RMS {stereo_rms:.3f} px is above {max_stereo_rms_px:.3f} px: check focus, "
            "board flatness, that left/right pairs were taken at the same instant, and the worst views"
        )
    med = float(np.median(per_view))
    for v in views:
        worst = max(v.left_rms_px, v.right_rms_px)
        if worst > max(3 * med, max_stereo_rms_px):
            warnings.append(f"view {v.name} fits poorly ({worst:.3f} px vs median {med:.3f} px)")
    for r in rejected:
        warnings.append(f"pair {r.name} rejected: {r.reason}")
    if len(used) < 10:
        warnings.append(f"only {len(used)} usable views; 10-20 varied views are recommended")
    rot_deg = float(np.degrees(np.linalg.norm(cv2.Rodrigues(calib.R)[0])))
    report = CalibrationReport(
        board=f"{board.cols}x{board.rows}",
        square_mm=float(board.square_mm),
        model=str(model),
        image_size=(int(size[0]), int(size[1])),
        pairs_given=len(detections),
        views_used=len(used),
        views=views,
        rejected=rejected,
        left_rms_px=float(rms_l),
        right_rms_px=float(rms_r),
        stereo_rms_px=float(stereo_rms),
        max_stereo_rms_px=float(max_stereo_rms_px),
        baseline_mm=calib.baseline_mm,
        convergence_deg=calib.convergence_deg,
        T_mm=[float(x) for x in calib.T],
        rotation_deg=rot_deg,
        intrinsics={"left": _intrinsics_summary(K_l, d_l), "right": _intrinsics_summary(K_r, d_r)},
        warnings=warnings,
        notes=[
            SKEW_REFINED_NOTE if estimate_skew else SKEW_NOTE,
            "Distortion model: "
            + ("k1, k2 only (the paper's eq. 7)" if model == "paper" else "k1, k2, p1, p2, k3"),
            "Convention: X_right = R * X_left + T (mm); left camera frame = world frame.",
        ],
    )
    return CheckerboardCalibration(calib, report, list(detections), used)


def calibrate_checkerboard(
    names: Sequence[str],
    lefts: Sequence[NDArray[Any]],
    rights: Sequence[NDArray[Any]],
    board: Board,
    model: Model | str = "paper",
    max_stereo_rms_px: float = DEFAULT_MAX_STEREO_RMS_PX,
    progress: bool = False,
    estimate_skew: bool = False,
    accurate: bool = True,
) -> CheckerboardCalibration:
    """Whole workflow on in-memory images: size checks, detection, calibration, report."""
    if model not in MODEL_FLAGS:
        raise CheckerboardError(f"model {model!r}: expected one of {sorted(MODEL_FLAGS)}")
    if len(names) < MIN_VIEWS:
        check_image_sizes(names, lefts, rights)
        raise CheckerboardError(
            f"too few usable views: only {len(names)} pairs given, need at least {MIN_VIEWS} "
            "(10-20 varied board poses are recommended)"
        )
    detections = detect_pairs(
        names, lefts, rights, board.pattern_size, progress=progress, accurate=accurate
    )

    def hint() -> str | None:
        if any(d.left is not None or d.right is not None for d in detections):
            return None
        cand = suggest_board(lefts[0], board.pattern_size)
        if cand is None:
            return (
                f"no {board.cols}x{board.rows} board was found in any image; --board counts "
                "inner corners (squares - 1 per side)"
            )
        return (
            f"board size does not match: no {board.cols}x{board.rows} board found, but a "
            f"{cand[0]}x{cand[1]} board is visible in pair {names[0]} (--board counts inner corners)"
        )

    return calibrate_from_detections(
        detections, board, model, max_stereo_rms_px, hint, estimate_skew=estimate_skew
    )


# ---------------------------------------------------------------------------------------
# report picture
# ---------------------------------------------------------------------------------------
def write_report_png(
    result: CheckerboardCalibration,
    path: str | Path,
    example_left: NDArray[Any] | None = None,
    example_right: NDArray[Any] | None = None,
) -> Path:
    """PNG: an example pair with its detected corners, corner coverage of all used views,
    and the per-view reprojection RMS of both cameras (matplotlib, Agg canvas)."""
    out = Path(path)
    out.write_bytes(report_png_bytes(result, example_left, example_right))
    return out


def report_png_bytes(
    result: CheckerboardCalibration,
    example_left: NDArray[Any] | None = None,
    example_right: NDArray[Any] | None = None,
) -> bytes:
    """The report picture of :func:`write_report_png` as PNG bytes."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rep = result.report
    w, h = rep.image_size
    fig = Figure(figsize=(14, 9), dpi=90)
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2)
    ex = result.detections[result.used[0]] if result.used else None
    for ax, img, side in ((axes[0, 0], example_left, "left"), (axes[0, 1], example_right, "right")):
        if img is not None:
            ax.imshow(to_gray(img), cmap="gray", vmin=0, vmax=255)
        else:
            ax.set_xlim(0, w)
            ax.set_ylim(h, 0)
        if ex is not None:
            pts = ex.left if side == "left" else ex.right
            if pts is not None:
                ax.plot(pts[:, 0], pts[:, 1], "-", color="tab:orange", lw=0.8)
                ax.plot(pts[:, 0], pts[:, 1], "+", color="tab:red", ms=6)
                ax.plot(pts[0, 0], pts[0, 1], "o", mfc="none", color="tab:cyan", ms=10)
        # corner coverage of every used view
        for k in result.used:
            d = result.detections[k]
            p = d.left if side == "left" else d.right
            if p is not None:
                ax.plot(p[:, 0], p[:, 1], ".", ms=3, alpha=0.6)
        ax.set_title(f"{side}: corners of view {ex.name if ex else '-'} (+), all views (dots)")
        ax.set_aspect("equal")
    names = [v.name for v in rep.views]
    x = np.arange(len(names))
    ax = axes[1, 0]
    ax.bar(x - 0.2, [v.left_rms_px for v in rep.views], 0.4, label="left")
    ax.bar(x + 0.2, [v.right_rms_px for v in rep.views], 0.4, label="right")
    ax.axhline(
        rep.stereo_rms_px, color="k", ls="--", lw=1, label=f"stereo RMS {rep.stereo_rms_px:.3f} px"
    )
    ax.set_xticks(x, names, rotation=60, fontsize=7)
    ax.set_ylabel("reprojection RMS (px)")
    ax.set_title("per-view reprojection error")
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    ax.axis("off")
    il, ir = rep.intrinsics["left"], rep.intrinsics["right"]
    lines = [
        f"board {rep.board} inner corners, {rep.square_mm:g} mm squares, model '{rep.model}'",
        f"views used {rep.views_used} of {rep.pairs_given}, image {w}x{h} px",
        f"RMS left {rep.left_rms_px:.3f} px, right {rep.right_rms_px:.3f} px, stereo {rep.stereo_rms_px:.3f} px",
        f"baseline {rep.baseline_mm:.2f} mm, convergence {rep.convergence_deg:.3f} deg",
        f"T = ({rep.T_mm[0]:.2f}, {rep.T_mm[1]:.2f}, {rep.T_mm[2]:.2f}) mm",
        f"left  fx {il['fx']:.1f} fy {il['fy']:.1f} u0 {il['u0']:.1f} v0 {il['v0']:.1f} k1 {il['k1']:.4f} k2 {il['k2']:.4f}",
        f"right fx {ir['fx']:.1f} fy {ir['fy']:.1f} u0 {ir['u0']:.1f} v0 {ir['v0']:.1f} k1 {ir['k1']:.4f} k2 {ir['k2']:.4f}",
        (
            f"skew estimated: left {il['skew']:.2f} px, right {ir['skew']:.2f} px"
            if rep.notes and rep.notes[0] == SKEW_REFINED_NOTE
            else "skew: not estimated by OpenCV (0 in the output)"
        ),
    ]
    for r in rep.rejected[:6]:
        lines.append(f"rejected {r.name}: {r.reason}")
    for wmsg in rep.warnings[:4]:
        if not wmsg.startswith("pair "):
            lines.append(f"WARNING: {wmsg[:90]}")
    ax.text(0, 1, "\n".join(lines), va="top", family="monospace", fontsize=8.5)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()
