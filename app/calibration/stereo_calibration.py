"""Stereo rig calibration from detected checkerboard corners (paper §3.2, Zhang's method [18, 19]).

The paper photographs a checkerboard (CCP) from several angles with both cameras and
estimates fx, fy, γ, u0, v0, k1, k2 for each camera (eqs. 2, 7) and the rig's R, T (eqs. 3–5).
Here, from the corners of :mod:`app.calibration.detection`:

1. each camera is calibrated alone (:func:`~app.calibration.opencv_fit.calibrate_camera`:
   Zhang's closed form + LM);
2. **rig check** (:func:`~app.calibration.rig_consistency.rig_check`): every pair's two board
   poses imply a rig (R, T); the rig most pairs agree on is calibrated from them, and each
   pair's corners are then triangulated with it under every index mapping and fitted to the
   flat board. A pair whose right grid is the left one reversed is corrected; a pair whose
   grids are offset by a column or row (not the same physical corners), or that fits no
   mapping, is rejected with the reason — :func:`calibrate_checkerboard` first searches its
   images again with the other detectors (:func:`redetect_rejected`) and keeps the pair if
   the new grids agree;
3. the rig is refined jointly (:func:`~app.calibration.opencv_fit.stereo_fit`,
   ``cv2.stereoCalibrateExtended``, intrinsics as initial guess);
4. **robust view dropping** (:func:`~app.calibration.robust.robust_outlier`): while the worst
   view's RMS reprojection error is a robust outlier, it is dropped and step 3 repeated — at
   most a quarter of the views, never below ``MIN_VIEWS``;
5. optionally (``estimate_skew``) everything is refined once more *with* the skew γ
   (:func:`~app.calibration.skew_refinement.refine_with_skew`, sparse least squares), which
   OpenCV's model lacks;
6. **held-out check** (:func:`~app.calibration.held_out.held_out_check`): each view's board is
   triangulated with a calibration made without it (k-fold) and its square size compared
   with the true one (mm).

Distortion models: ``"paper"`` estimates k1, k2 only (``CALIB_FIX_K3 | CALIB_ZERO_TANGENT_DIST``,
the paper's eq. 7); ``"full"`` estimates OpenCV's five terms k1, k2, p1, p2, k3.
Without step 5, γ is **not** estimated and is 0 in the output.

Bad input raises :class:`~app.calibration.board.CheckerboardError` (a ``ValueError``) with a
one-line message. Pure numpy/OpenCV/scipy.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from app.calibration.board import Board, CheckerboardError
from app.calibration.corners import METHODS, CornerResult, detect_corners_detail, suggest_board
from app.calibration.detection import (
    PairDetection,
    check_image_sizes,
    detect_pairs,
    match_orientation,
)
from app.calibration.held_out import held_out_check
from app.calibration.opencv_fit import (
    MODEL_FLAGS,
    CameraFit,
    Model,
    StereoFit,
    as_calibration,
    board_pose,
    calibrate_camera,
    stereo_fit,
)
from app.calibration.report import (
    SKEW_NOTE,
    SKEW_REFINED_NOTE,
    CalibrationReport,
    DroppedView,
    HeldOutCheck,
    RejectedView,
    ViewReport,
    coverage_map,
    coverage_warnings,
    intrinsics_summary,
)
from app.calibration.rig_consistency import (
    mapping_fits_mm,
    pair_verdict,
    rig_check,
    rig_tolerance_mm,
)
from app.calibration.robust import (
    MAX_DROP_FRACTION,
    OUTLIER_MIN_EXCESS_PX,
    OUTLIER_RATIO,
    OUTLIER_Z,
    robust_outlier,
)
from app.calibration.skew_refinement import refine_with_skew
from app.geometry.calibration import StereoCalibration
from app.types import FloatArray

MIN_VIEWS = 6
DEFAULT_MAX_STEREO_RMS_PX = 0.5


@dataclass
class CheckerboardCalibration:
    """Result of :func:`calibrate_from_detections`: the validated calibration and its report.

    ``detections`` are as used (a reversed right grid corrected, rig-check rejections set);
    ``used``: indices into ``detections`` of the views in the final calibration."""

    calibration: StereoCalibration
    report: CalibrationReport
    detections: list[PairDetection]
    used: list[int]

    def save(self, path: str | Path) -> None:
        self.calibration.save(path)


def _too_few_message(detections: Sequence[PairDetection], n_ok: int) -> str:
    counts: dict[str, int] = {}
    for det in detections:
        r = det.reason
        if r is not None:
            key = r.split(":")[0] if det.rejected else r
            counts[key] = counts.get(key, 0) + 1
    why = "; ".join(f"{n} {r}" for r, n in sorted(counts.items(), key=lambda kv: -kv[1]))
    return (
        f"too few usable views: {n_ok} of {len(detections)} pairs have the board in both images, "
        f"need at least {MIN_VIEWS}" + (f" ({why})" if why else "")
    )


def _image_points(det: PairDetection, side: str) -> NDArray[np.float32]:
    """One side's corners (px) as OpenCV's (n, 1, 2) float32 image points."""
    p = det.left if side == "left" else det.right
    return np.asarray(p, dtype=np.float32).reshape(-1, 1, 2)


@dataclass(frozen=True)
class RigChecked:
    """Step 2's outcome (the rig check): ``detections`` with reversed right grids corrected
    and rejections set, ``used`` the indices of the usable pairs, ``warnings`` what the check
    reports (inconclusive, grids reversed), ``first_fit`` the check's own joint fit when it
    used exactly the ``used`` pairs as they are (step 3 starts from it), else None."""

    detections: list[PairDetection]
    used: list[int]
    warnings: list[str]
    first_fit: StereoFit | None


@dataclass(frozen=True)
class JointFit:
    """Steps 3–4's outcome: the last joint fit (``stereoCalibrateExtended``), the views it
    used (indices into the detections) and the views dropped as reprojection outliers."""

    fit: StereoFit
    used: list[int]
    dropped: list[DroppedView]


@dataclass(frozen=True)
class FinalEstimate:
    """Steps 5–6's outcome: the final ``fit`` (OpenCV's, or the skew refinement's), each
    camera's RMS (px), the calibration made from it and the held-out check (None if
    skipped)."""

    fit: StereoFit
    rms_l: float
    rms_r: float
    calibration: StereoCalibration
    held: HeldOutCheck | None


def _usable_views(
    dets: Sequence[PairDetection], model: Model | str, hint: Callable[[], str | None] | None
) -> list[int]:
    """Indices of the pairs with the board in both images; CheckerboardError for an unknown
    model, no pairs or fewer than ``MIN_VIEWS`` usable ones (with ``hint``'s suggestion)."""
    if model not in MODEL_FLAGS:
        raise CheckerboardError(f"model {model!r}: expected one of {sorted(MODEL_FLAGS)}")
    if not dets:
        raise CheckerboardError("no images given")
    both = [k for k, d in enumerate(dets) if d.usable]
    if len(both) < MIN_VIEWS:
        msg = _too_few_message(dets, len(both))
        extra = hint() if hint is not None else None
        raise CheckerboardError(msg + (f"; {extra}" if extra else ""))
    return both


def _check_rig(
    dets: list[PairDetection],
    both: list[int],
    cams: tuple[CameraFit, CameraFit],
    board: Board,
    flags: int,
) -> RigChecked:
    """Step 2: do the two grids of each pair hold the same corners in the same order
    (:func:`rig_check`, from each camera's own fit ``cams``)? Reversed right grids are turned
    round, offset or unfit pairs rejected; CheckerboardError when fewer than ``MIN_VIEWS``
    pairs remain."""
    cam_l, cam_r = cams
    dets = list(dets)
    warnings: list[str] = []
    verdicts, inconclusive, seed = rig_check(
        [board_pose(r, t) for r, t in zip(cam_l.rvecs, cam_l.tvecs, strict=True)],
        [board_pose(r, t) for r, t in zip(cam_r.rvecs, cam_r.tvecs, strict=True)],
        board,
        ((cam_l.K, cam_l.dist), (cam_r.K, cam_r.dist)),
        [
            (
                np.asarray(dets[k].left, dtype=np.float64),
                np.asarray(dets[k].right, dtype=np.float64),
            )
            for k in both
        ],
        dets[0].image_size,
        flags,
    )
    if inconclusive:
        warnings.append(inconclusive)
    flipped = []
    for k, verdict in zip(both, verdicts, strict=True):
        if verdict.action == "flipped":
            right = np.asarray(dets[k].right)[::-1].copy()
            dets[k] = replace(dets[k], right=right)
            flipped.append(dets[k].name)
        elif verdict.action == "rejected":
            dets[k] = replace(dets[k], rejected=verdict.reason)
    if flipped:
        warnings.append(
            f"right grid reversed to match the left one in pair(s) {', '.join(flipped)}"
        )
    used = [k for k in both if dets[k].usable]
    if len(used) < MIN_VIEWS:
        raise CheckerboardError(_too_few_message(dets, len(used)))
    # the rig check's calibration is the first fit when it used exactly these pairs
    reuse = seed is not None and [both[i] for i in seed[0]] == used and not flipped
    first_fit = seed[1] if reuse and seed is not None else None
    return RigChecked(dets, used, warnings, first_fit)


def _refine_dropping_outliers(
    rig: RigChecked,
    cams: tuple[CameraFit, CameraFit],
    obj: FloatArray,
    flags: int,
    drop_outliers: bool,
) -> JointFit:
    """Steps 3–4: the joint stereo fit of the used views (``obj``: board points, mm), then,
    while the worst view's RMS reprojection error (px) is a robust outlier
    (:func:`robust_outlier`), that view dropped and the fit repeated from the last one — at
    most ``MAX_DROP_FRACTION`` of the views, never below ``MIN_VIEWS``."""
    dets, used = rig.detections, list(rig.used)
    size = dets[0].image_size
    K_l, K_r = cams[0].K, cams[1].K
    d_l, d_r = cams[0].dist.ravel(), cams[1].dist.ravel()
    dropped: list[DroppedView] = []
    max_drops = int(MAX_DROP_FRACTION * len(used))
    first = rig.first_fit
    while True:
        if first is not None:
            fit, first = first, None
        else:
            fit = stereo_fit(
                obj,
                [_image_points(dets[k], "left") for k in used],
                [_image_points(dets[k], "right") for k in used],
                K_l, d_l, K_r, d_r, size, flags,
            )  # fmt: skip
        if not drop_outliers or len(dropped) >= max_drops or len(used) <= MIN_VIEWS:
            break
        err = np.sqrt(np.mean(fit.per_view**2, axis=1))
        out = robust_outlier(err)
        if out is None:
            break
        i, z = out
        k = used.pop(i)
        med = float(np.median(err))
        dropped.append(
            DroppedView(
                dets[k].name,
                f"reprojection outlier: RMS {err[i]:.3f} px vs median {med:.3f} px "
                f"(robust z {z:.1f} > {OUTLIER_Z})",
                float(err[i]),
                float(z),
            )
        )
        K_l, d_l, K_r, d_r = fit.K_l, fit.d_l, fit.K_r, fit.d_r
    return JointFit(fit, used, dropped)


def _final_estimate(
    joint: JointFit,
    dets: Sequence[PairDetection],
    cams: tuple[CameraFit, CameraFit],
    board: Board,
    model: Model | str,
    estimate_skew: bool,
    held_out_folds: int | None,
) -> FinalEstimate:
    """Steps 6 then 5: OpenCV's skew is set to exactly 0 (γ of eq. 2, in the fit itself),
    the held-out scale check (mm) runs on that fit, then, with ``estimate_skew``, everything
    is refined jointly with γ (:func:`refine_with_skew`)."""
    fit, used = joint.fit, joint.used
    size = dets[0].image_size
    flags = MODEL_FLAGS[model]
    fit.K_l[0, 1] = fit.K_r[0, 1] = 0.0
    img_l = [_image_points(dets[k], "left") for k in used]
    img_r = [_image_points(dets[k], "right") for k in used]
    # 6. held-out scale check (OpenCV's model; before the skew refinement)
    names = [dets[k].name for k in used]
    held = (
        None
        if held_out_folds == 0
        else held_out_check(names, img_l, img_r, fit, board, size, flags, held_out_folds)
    )
    final, rms_l, rms_r = fit, cams[0].rms, cams[1].rms
    # 5. skew
    if estimate_skew:
        final = refine_with_skew(
            board.object_points().astype(np.float64),
            [np.asarray(p, dtype=np.float64) for p in img_l],
            [np.asarray(p, dtype=np.float64) for p in img_r],
            fit.K_l, fit.d_l, fit.K_r, fit.d_r, fit.R, fit.T, fit.rvecs, fit.tvecs, str(model),
        )  # fmt: skip
        rms_l, rms_r = final.rms_l, final.rms_r
    calib = as_calibration(size, final.K_l, final.d_l, final.K_r, final.d_r, final.R, final.T)
    return FinalEstimate(final, rms_l, rms_r, calib, held)


def _quality_warnings(
    rejected: Sequence[RejectedView],
    joint: JointFit,
    est: FinalEstimate,
    views: Sequence[ViewReport],
    max_stereo_rms_px: float,
) -> list[str]:
    """The report's warnings on the fit's quality (px): stereo RMS over the limit, views that
    fit poorly, rejected and dropped pairs, too few views."""
    warnings: list[str] = []
    stereo_rms, per_view = est.fit.rms, est.fit.per_view
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
    for dv in joint.dropped:
        warnings.append(f"pair {dv.name} dropped: {dv.reason}")
    if len(joint.used) < 10:
        warnings.append(f"only {len(joint.used)} usable views; 10-20 varied views are recommended")
    return warnings


def _report_notes(model: Model | str, estimate_skew: bool) -> list[str]:
    """The report's fixed notes: skew, distortion model, frame convention, outlier rule."""
    return [
        SKEW_REFINED_NOTE if estimate_skew else SKEW_NOTE,
        "Distortion model: "
        + ("k1, k2 only (the paper's eq. 7)" if model == "paper" else "k1, k2, p1, p2, k3"),
        "Convention: X_right = R * X_left + T (mm); left camera frame = world frame.",
        f"Outlier rule: a view is dropped when its RMS has robust z-score "
        f"0.6745*(e - median)/MAD > {OUTLIER_Z}, e > {OUTLIER_RATIO} x median and "
        f"e > median + {OUTLIER_MIN_EXCESS_PX} px "
        f"(at most {int(100 * MAX_DROP_FRACTION)} % of the views).",
    ]


def _detector_counts(dets: Sequence[PairDetection]) -> dict[str, int]:
    """How many grids each corner detector found."""
    detectors: dict[str, int] = {}
    for d in dets:
        for m in (d.left_method, d.right_method):
            if m is not None:
                detectors[m] = detectors.get(m, 0) + 1
    return detectors


def _calibration_report(
    rig: RigChecked,
    joint: JointFit,
    est: FinalEstimate,
    board: Board,
    model: Model | str,
    max_stereo_rms_px: float,
    estimate_skew: bool,
) -> CalibrationReport:
    """The report of a calibration: per-view RMS (px) and held-out residual (mm), rejected
    and dropped pairs, RMS, rig (mm, deg), intrinsics, coverage and every warning."""
    dets, used, calib, fit = rig.detections, joint.used, est.calibration, est.fit
    size = dets[0].image_size
    views = [
        ViewReport(
            dets[k].name,
            float(fit.per_view[i, 0]),
            float(fit.per_view[i, 1]),
            None if est.held is None else est.held.per_view_rms_mm[dets[k].name],
        )
        for i, k in enumerate(used)
    ]
    rejected = [RejectedView(d.name, d.reason or "") for d in dets if d.reason is not None]
    warnings = rig.warnings + _quality_warnings(rejected, joint, est, views, max_stereo_rms_px)
    cov = coverage_map(
        [np.asarray(dets[k].left) for k in used], [np.asarray(dets[k].right) for k in used], size
    )
    warnings.extend(coverage_warnings(cov))
    rot_deg = float(np.degrees(np.linalg.norm(cv2.Rodrigues(calib.R)[0])))
    return CalibrationReport(
        board=f"{board.cols}x{board.rows}",
        square_mm=float(board.square_mm),
        model=str(model),
        image_size=(int(size[0]), int(size[1])),
        pairs_given=len(dets),
        views_used=len(used),
        views=views,
        rejected=rejected,
        left_rms_px=float(est.rms_l),
        right_rms_px=float(est.rms_r),
        stereo_rms_px=float(fit.rms),
        max_stereo_rms_px=float(max_stereo_rms_px),
        baseline_mm=calib.baseline_mm,
        convergence_deg=calib.convergence_deg,
        T_mm=[float(x) for x in calib.T],
        rotation_deg=rot_deg,
        intrinsics={
            "left": intrinsics_summary(fit.K_l, fit.d_l),
            "right": intrinsics_summary(fit.K_r, fit.d_r),
        },
        warnings=warnings,
        notes=_report_notes(model, estimate_skew),
        dropped=joint.dropped,
        coverage=cov,
        held_out=est.held,
        detectors=_detector_counts(dets),
    )


def calibrate_from_detections(
    detections: Sequence[PairDetection],
    board: Board,
    model: Model | str = "paper",
    max_stereo_rms_px: float = DEFAULT_MAX_STEREO_RMS_PX,
    hint: Callable[[], str | None] | None = None,
    estimate_skew: bool = False,
    drop_outliers: bool = True,
    held_out_folds: int | None = None,
) -> CheckerboardCalibration:
    """Calibrate both cameras, check the pairs, then the rig (steps 1–6 of the module doc).

    ``estimate_skew``: refine everything jointly with the skew γ of eq. 2 at the end
    (:func:`refine_with_skew`; OpenCV alone writes γ = 0). ``drop_outliers``: the robust view
    dropping of step 4. ``held_out_folds``: 0 skips the held-out check. ``hint`` is called
    when too few views are usable to add e.g. a board-size suggestion."""
    dets = list(detections)
    both = _usable_views(dets, model, hint)
    flags = MODEL_FLAGS[model]
    size = dets[0].image_size
    obj = board.object_points()
    # 1. each camera alone (Zhang's closed form + LM)
    cams = (
        calibrate_camera(obj, [_image_points(dets[k], "left") for k in both], size, flags),
        calibrate_camera(obj, [_image_points(dets[k], "right") for k in both], size, flags),
    )
    rig = _check_rig(dets, both, cams, board, flags)  # 2.
    joint = _refine_dropping_outliers(  # 3.-4.
        rig, cams, obj.astype(np.float64), flags, drop_outliers
    )
    est = _final_estimate(  # 6., then 5.
        joint, rig.detections, cams, board, model, estimate_skew, held_out_folds
    )
    report = _calibration_report(rig, joint, est, board, model, max_stereo_rms_px, estimate_skew)
    return CheckerboardCalibration(est.calibration, report, rig.detections, joint.used)


def calibrate_checkerboard(
    names: Sequence[str],
    lefts: Sequence[NDArray[Any]],
    rights: Sequence[NDArray[Any]],
    board: Board,
    model: Model | str = "paper",
    max_stereo_rms_px: float = DEFAULT_MAX_STEREO_RMS_PX,
    progress: bool = False,
    estimate_skew: bool = False,
    workers: int | None = None,
    drop_outliers: bool = True,
    held_out_folds: int | None = None,
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
        names, lefts, rights, board.pattern_size, progress=progress, workers=workers
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

    kwargs: dict[str, Any] = {
        "estimate_skew": estimate_skew,
        "drop_outliers": drop_outliers,
        "held_out_folds": held_out_folds,
    }
    result = calibrate_from_detections(detections, board, model, max_stereo_rms_px, hint, **kwargs)
    dets, fixed = redetect_rejected(result, lefts, rights, board)
    if not fixed:
        return result
    again = calibrate_from_detections(dets, board, model, max_stereo_rms_px, hint, **kwargs)
    again.report.warnings.append(
        "rig check: grids re-detected with another detector, now consistent: " + "; ".join(fixed)
    )
    return again


def redetect_rejected(
    result: CheckerboardCalibration,
    lefts: Sequence[NDArray[Any]],
    rights: Sequence[NDArray[Any]],
    board: Board,
) -> tuple[list[PairDetection], list[str]]:
    """Correct pairs the rig check rejected: their images are searched again with the other
    detectors (a detector can lock onto a grid offset by a column); the first combination of
    grids (new left, new right, both) that :func:`pair_verdict` accepts under ``result``'s
    rig replaces the pair. Returns the detections and one line per corrected pair."""
    dets = list(result.detections)
    fixed: list[str] = []
    if not any(d.rejected is not None for d in dets):
        return dets, fixed
    kept = [dets[k] for k in result.used]
    as_detected = [
        mapping_fits_mm(result.calibration, np.asarray(d.left), np.asarray(d.right), board)[0]
        for d in kept
    ]
    tol = rig_tolerance_mm([float(f) for f in as_detected], board)
    for k, d in enumerate(dets):
        if d.rejected is None or d.left is None or d.right is None:
            continue
        alt = []
        for img, used in ((lefts[k], d.left_method), (rights[k], d.right_method)):
            others = [m for m in METHODS if used is None or not used.startswith(m)]
            alt.append(detect_corners_detail(img, board.pattern_size, others))
        alt_l, alt_r = alt
        combos: list[tuple[CornerResult | None, CornerResult | None]]
        combos = [(alt_l, None)] if alt_l is not None else []
        combos += [(None, alt_r)] if alt_r is not None else []
        combos += [(alt_l, alt_r)] if alt_l is not None and alt_r is not None else []
        for cl, cr in combos:
            left = d.left if cl is None else cl.corners
            right = d.right if cr is None else cr.corners
            right = match_orientation(left, right)
            fit = mapping_fits_mm(result.calibration, left, right, board)
            verdict = pair_verdict(fit, tol, board)
            if verdict.action == "rejected":
                continue
            if verdict.action == "flipped":
                right = right[::-1].copy()
            dets[k] = PairDetection(
                d.name,
                d.image_size,
                left,
                right,
                d.left_method if cl is None else cl.method,
                d.right_method if cr is None else cr.method,
            )
            sides = [f"{side} by {r.method}" for side, r in (("left", cl), ("right", cr)) if r]
            fixed.append(f"pair {d.name} ({', '.join(sides)})")
            break
    return dets, fixed
