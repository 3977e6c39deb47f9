"""The binocular LED navigation pipeline (paper Algorithm 1, §4–§5).

``NavigationPipeline(calibration).process(left, right) -> PoseResult``:
gray (eq. 9) → threshold (eq. 10) → median filter → connected components + eq. 11 centroids →
IHWT descriptors (eqs. 12–13) → matching (eq. 14; paper or epipolar-gated) → undistortion →
least-squares triangulation (eqs. 15–16) + reprojection refinement → ring consensus, plane and
circle fit (§5.2) → lock decision.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Literal

import numpy as np

from app.geometry.calibration import StereoCalibration
from app.geometry.led_ids import DEFAULT_PHASE_DEG, led_ids_for_angles, roll_from_offset
from app.geometry.projection import undistort_pixels
from app.geometry.ring import (
    STRICT_RANK,
    RingFit,
    RingParams,
    RingPrior,
    RingRejection,
    find_ring,
)
from app.geometry.triangulation import refine_reprojection, triangulate_linear
from app.model.pose import MAX_REJECTED_SHOWN, LedResult, PoseResult, StageTimings
from app.vision.appearance import (
    AppearanceConfig,
    BlobTable,
    appearance_ok,
    appearance_reasons,
    blob_color_bgr,
    colour_reason,
)
from app.vision.error_bound import (
    ErrorBoundConfig,
    bound_lock,
    drogue_with_bound,
    isotropic_model_sigma_px,
    isotropic_sigma_px,
    led_bound_fields,
    lock_bound,
)
from app.vision.features import (
    BAND_ROWS,
    MAX_REJECTED_REPORTED,
    BlobGate,
    TooManyBlobs,
    detect_blobs,
)
from app.vision.ihwt import describe
from app.vision.local_centroid import (
    LocalCentroidConfig,
    measure_blobs,
    prefer_sharper,
    read_rects,
)
from app.vision.matching import (
    MatchArrays,
    descriptor_distances,
    epipolar_distances,
    match_epipolar_indices,
    match_min_distance_indices,
)
from app.vision.pipeline_records import RingIds, RingLeds, StereoMatches, StereoPoints
from app.vision.preprocess import (
    BACKGROUND_COL_STEP,
    BACKGROUND_ROW_STEP,
    ColourDetect,
    ImageError,
    ThresholdMode,
    choose_threshold,
    detection_image,
    local_contrast,
    to_gray,
    validate_image,
)
from app.vision.preprocess_kernels import frame_levels, frame_summary
from app.vision.track_memory import TrackMemory
from app.vision.types import Blob, FeatureSet, Match, RejectedBlob

OUR_WINDOW_FACTOR = 8.0
PAPER_WINDOW_FACTOR = 80.0

__all__ = ["ImageError", "NavigationPipeline", "PipelineConfig", "PipelineTrace"]


def rejected_candidates(
    feats: FeatureSet, used_px: list[tuple[float, float]]
) -> list[tuple[float, float]]:
    """The candidates of one image that are not among the reported LEDs (px): blobs that were
    gated out (eq. 11's area/shape gate), not matched, or refused (appearance, ring), at most
    :data:`MAX_REJECTED_SHOWN` — what the operators' page marks as rejected."""
    pts = [b.centroid_px for b in feats.blobs] + [r.centroid_px for r in feats.rejected]
    if not pts or (len(pts) <= len(used_px) and set(pts) <= set(used_px)):
        return []  # nothing, or every candidate is a reported LED (a clean frame)
    p = np.asarray(pts, dtype=np.float64)
    if used_px:  # drop the reported LEDs (their centroids are these blobs')
        used = np.asarray(used_px, dtype=np.float64)
        d = np.abs(p[:, None, :] - used[None, :, :]).sum(axis=2).min(axis=1)
        p = p[d >= 1e-6]
    return [(u, v) for u, v in p[:MAX_REJECTED_SHOWN].tolist()]


def check_pair(
    calibration: StereoCalibration, left: object, right: object
) -> tuple[np.ndarray, np.ndarray]:
    """Validated uint8 images of the calibration's size (else :class:`ImageError`)."""
    left = validate_image(left, "left")
    right = validate_image(right, "right")
    w, h = calibration.image_size
    for name, img in (("left", left), ("right", right)):
        if img.shape[1] != w or img.shape[0] != h:
            raise ImageError(
                f"{name}: image is {img.shape[1]}×{img.shape[0]} px but the calibration "
                f"is for {w}×{h} px"
            )
    return left, right


@dataclass(frozen=True)
class PipelineConfig:
    """Tunable parameters. Lengths in mm, image quantities in px."""

    # colour input: find and measure the LEDs on eq. 9's gray ("gray", the paper) or on the
    # green excess G − max(B, R) ("green", app.vision.preprocess.green_excess)
    colour_detect: ColourDetect = "green"
    threshold: ThresholdMode = "auto"  # eq. 10: int DN, "auto" (half-max) or "otsu"
    median_ksize: int = 3
    gate: BlobGate = field(default_factory=BlobGate)
    # local-support centroids (app.vision.local_centroid); disabled: the paper's eq. 11
    centroid: LocalCentroidConfig = field(default_factory=LocalCentroidConfig)
    # covariance, protection levels and the residual test of every lock (app.vision.error_bound)
    error_bound: ErrorBoundConfig = field(default_factory=ErrorBoundConfig)
    # IHWT window side = factor × blob equivalent radius; None → per matcher: ours 8 (the LED
    # and its fringe), the paper's 80 (§4.3: "as the area described becomes larger, the
    # description is more detailed": a window spanning the neighbouring LEDs).
    window_factor: float | None = None
    min_window_px: int = 16
    matcher: Literal["epipolar", "paper"] = "epipolar"
    epipolar_tol_px: float = 2.0
    depth_range_mm: tuple[float, float] = (100.0, 50_000.0)
    ring_radius_mm: float = 75.0
    led_count: int = 5
    led_phase_deg: float = DEFAULT_PHASE_DEG  # angle of LED 1 at roll 0 (app.geometry.led_ids)
    led_diameter_mm: float = 5.0  # physical LED size, for the appearance test
    ring_radius_tol_frac: float = 0.1  # of the expected radius, plus depth noise
    ring_inlier_tol_mm: float = 2.0  # floor; grows with the depth noise σ_Z ≈ Z²σ_d/(fB)
    disparity_sigma_px: float = 0.05  # assumed centroid disparity noise for the tolerances
    angle_tol_deg: float = 2.0  # floor of the slot residual; grows with σ_Z (max 12°)
    min_leds: int = 3
    max_reprojection_px: float = 1.5  # matched points reprojecting worse are dropped
    appearance: AppearanceConfig = field(default_factory=AppearanceConfig)
    log10_nfa_max: float = -2.0  # a-contrario integrity: lock only if NFA ≤ 10^this
    # A frame refused while blobs of this area (px) up to the gate's minimum were gated out
    # is solved once more with them as candidates (None: never). A far, dim LED lights only
    # 2 px above eq. 10's threshold (the flight drogue at 9.5 m in sunlight, its 20 mm LEDs
    # ≈ 5 px across); taking such blobs on every frame lets glints compete with rings the
    # larger blobs already give (docs/integrity.md, "Small blobs, second pass").
    retry_min_area_px: int | None = 2
    # A colour frame refused on the green excess is solved once more on eq. 9's gray (with
    # the colour gate as before). JPEG's 4:2:0 chroma subsampling, bloom and motion blur
    # smear a small LED's green excess below eq. 10's threshold while its gray image stays
    # sharp (docs/integrity.md, "Second pass").
    retry_gray: bool = True
    # A frame still refused is solved once more on the detection image's local contrast (a
    # white top-hat of this square side, px: app.vision.preprocess.local_contrast; None:
    # never). In sunlight an LED can be no brighter than the sky or the lit rim around its
    # bezel, so eq. 10's global threshold either misses it or joins it to the rim; against
    # its own surroundings it stands out (docs/integrity.md, "Local-contrast pass"). Only
    # on a bright frame (either image's background median ≥ ``local_contrast_min_background_dn``):
    # on a dark one eq. 10's threshold already measures each LED against its surroundings
    retry_local_contrast_px: int | None = 31
    local_contrast_min_background_dn: float = 64.0
    track_frames: int = 5  # a lock this many frames old still serves as the prior


@dataclass
class PipelineTrace:
    """Intermediate results of the last ``process`` call (for the dashboard and tests)."""

    left: FeatureSet | None = None
    right: FeatureSet | None = None
    # the stereo matches (rows of ``xyz_mm``); ``matches`` holds them as records
    match_arrays: MatchArrays | None = None
    xyz_mm: np.ndarray | None = None
    ring: RingFit | None = None
    thresholds: tuple[int, int] = (0, 0)
    # background level and noise σ (DN) of each image, as the eq. 10 threshold used them
    backgrounds: tuple[tuple[float, float], tuple[float, float]] = ((0.0, 0.0), (0.0, 0.0))
    appearance_rejected: dict[int, list[str]] = field(default_factory=dict)  # match → reasons
    roll_deg: float | None = None

    @cached_property
    def matches(self) -> list[Match]:
        """The stereo matches as records (built on first access from ``match_arrays``)."""
        return [] if self.match_arrays is None else self.match_arrays.records()


class NavigationPipeline:
    """Holds the calibration, the configuration and the last lock (the track).

    Each frame pair is solved on its own; the track only continues the LED ids through roll
    (:mod:`app.geometry.led_ids`) and lets a 3-LED fit that agrees with it be judged locally.
    ``reset()`` forgets it (a new, unrelated frame sequence).
    """

    def __init__(
        self, calibration: StereoCalibration, config: PipelineConfig | None = None
    ) -> None:
        self.calibration = calibration
        self.config = config or PipelineConfig()
        self.trace = PipelineTrace()
        self.fundamental = calibration.fundamental  # F of the calibration (x_rᵀ F x_l = 0)
        fbar = 0.5 * (calibration.left.fx + calibration.right.fx)
        self._f_mean_px = fbar
        self._f_times_b = fbar * calibration.baseline_mm
        self._track: TrackMemory | None = None
        w, h = calibration.image_size
        self._fov_tan = (w / calibration.left.fx, h / calibration.left.fy)

    def reset(self) -> None:
        """Forget the track (ids restart from the acquisition convention)."""
        self._track = None

    @property
    def window_factor(self) -> float:
        """IHWT window factor in use (the config's, else the matcher's default)."""
        if self.config.window_factor is not None:
            return float(self.config.window_factor)
        return PAPER_WINDOW_FACTOR if self.config.matcher == "paper" else OUR_WINDOW_FACTOR

    # ------------------------------------------------------------------ stages
    def _features(
        self,
        image: np.ndarray,
        gate: BlobGate | None = None,
        detect: ColourDetect | None = None,
        local_px: int | None = None,
    ) -> tuple[FeatureSet, int, tuple[float, float]]:
        """The blobs of one image and their descriptors, with eq. 10's threshold and the
        background level and noise it used; ``local_px``: on the detection image's local
        contrast (:func:`~app.vision.preprocess.local_contrast`)."""
        cfg = self.config
        detect = detect or cfg.colour_detect
        t0 = time.perf_counter()
        gray = detection_image(image, detect)
        if local_px is not None:
            gray = local_contrast(gray, local_px)
        # one pass over the frame: the band maxima (the peak of eq. 10's "auto" rule and the
        # bright bands), the background's histogram and that of neighbouring pixels'
        # differences
        bands, hist, dhist = frame_summary(
            gray, BAND_ROWS, BACKGROUND_ROW_STEP, BACKGROUND_COL_STEP
        )
        # the background level (median) and the sensor's noise σ from neighbouring pixels'
        # differences (preprocess.noise_sigma): the MAD of the values would measure a sunlit
        # scene, not the noise, and lift the 6σ floor of eq. 10's threshold above unsaturated
        # LEDs
        stats = frame_levels(hist, dhist)
        bg = stats[0]
        threshold = choose_threshold(gray, cfg.threshold, stats, float(bands.max()))
        t1 = time.perf_counter()
        # binarise, median-filter, label and centroid only around the bright pixels
        # (each blob built once with its local-support centroid: app.vision.local_centroid)
        blobs, rejected = detect_blobs(
            gray, threshold, bg, gate or cfg.gate, cfg.median_ksize, bands, cfg.centroid
        )
        if image.ndim == 3 and detect == "green" and cfg.centroid.enabled:
            if cfg.centroid.gray_too and blobs:
                # each blob measured on eq. 9's gray too; the sharper measurement is kept
                # (eq. 9 only where the local centroids read: the rest is never looked at)
                lit = np.empty(image.shape[:2], np.uint8)
                for x0, y0, x1, y1 in read_rects(blobs, image.shape[1], image.shape[0]):
                    lit[y0:y1, x0:x1] = to_gray(image[y0:y1, x0:x1])
                table = measure_blobs(lit, blobs, cfg.centroid)
                blobs = prefer_sharper(blobs, table)
        if image.ndim == 3 and cfg.appearance.enabled:
            sat = cfg.appearance.saturated_dn
            blobs = [replace(b, color_bgr=blob_color_bgr(image, b, threshold, sat)) for b in blobs]
            # the colour gate: a blob that is clearly not green (a white or yellow sun glint)
            # never reaches the matcher
            kept: list[Blob] = []
            for b in blobs:
                why = colour_reason(b, cfg.appearance)
                if why is None:
                    kept.append(b)
                elif len(rejected) < MAX_REJECTED_REPORTED:
                    rejected.append(RejectedBlob(b.centroid_px, b.area_px, why))
            if cfg.appearance.colour_gate:
                blobs = kept
        t2 = time.perf_counter()
        desc = describe(gray, blobs, self.window_factor, cfg.min_window_px)
        t3 = time.perf_counter()
        self._stage_ms["preprocess"] += (t1 - t0) * 1e3
        self._stage_ms["extract"] += (t2 - t1) * 1e3
        self._stage_ms["describe"] += (t3 - t2) * 1e3
        return FeatureSet(blobs=blobs, descriptors=desc, rejected=rejected), threshold, stats

    @property
    def track(self) -> TrackMemory | None:
        """The last lock (``None`` when there is none or it aged out)."""
        return self._track

    def continue_track(self, center_mm: np.ndarray, normal: np.ndarray, roll_deg: float) -> None:
        """Make a lock found outside :meth:`process` (a tracked frame) the track: the prior
        of the next frame's ids and 3-LED integrity, age 0."""
        self._track = TrackMemory(center_mm, normal, roll_deg)

    @property
    def ring_params(self) -> RingParams:
        """The ring the pipeline looks for and its tolerances (from the config; the depth
        noise from the calibration's focal length and baseline)."""
        cfg = self.config
        return RingParams(
            radius_mm=cfg.ring_radius_mm,
            led_count=cfg.led_count,
            radius_tol_frac=cfg.ring_radius_tol_frac,
            inlier_tol_mm=cfg.ring_inlier_tol_mm,
            angle_tol_deg=cfg.angle_tol_deg,
            depth_sigma_per_mm=cfg.disparity_sigma_px / self._f_times_b,
            lateral_sigma_per_mm=cfg.disparity_sigma_px / self._f_mean_px,
            min_leds=cfg.min_leds,
            log10_nfa_max=cfg.log10_nfa_max,
            fov_tan=(self._fov_tan),
        )

    # ------------------------------------------------------------------ main entry
    def process(self, left: np.ndarray, right: np.ndarray) -> PoseResult:
        """Run the whole pipeline on one stereo pair (uint8, gray or BGR)."""
        t_start = time.perf_counter()
        self._stage_ms = dict.fromkeys(
            ("preprocess", "extract", "describe", "match", "triangulate", "pose", "bound"), 0.0
        )
        self.trace = PipelineTrace()
        left, right = check_pair(self.calibration, left, right)
        try:
            feats_l, thr_l, stats_l = self._features(left)
            feats_r, thr_r, stats_r = self._features(right)
        except TooManyBlobs as exc:
            self._age_track()
            result = PoseResult(lock=False, reason=str(exc))
            self._stage_ms["total"] = (time.perf_counter() - t_start) * 1e3
            result.timing_ms = StageTimings(**self._stage_ms)
            return result
        self.trace.left, self.trace.right = feats_l, feats_r
        self.trace.thresholds = (thr_l, thr_r)
        self.trace.backgrounds = (stats_l, stats_r)
        result = self._solve(feats_l, feats_r, (stats_l[0], stats_r[0]))
        if not result.lock:
            retried = self._second_pass(left, right, feats_l, feats_r)
            if retried is None or not retried[0].lock:
                retried = self._local_contrast_pass(left, right, (stats_l[0], stats_r[0]))
            if retried is not None and retried[0].lock:
                result, feats_l, feats_r = retried
        result.rejected_left_px = rejected_candidates(feats_l, [led.left_px for led in result.leds])
        result.rejected_right_px = rejected_candidates(
            feats_r, [led.right_px for led in result.leds]
        )
        if not result.lock:
            self._age_track()
        self._stage_ms["total"] = (time.perf_counter() - t_start) * 1e3
        result.timing_ms = StageTimings(**self._stage_ms)
        return result

    def _small_blob_floor(self, feats_l: FeatureSet, feats_r: FeatureSet) -> int | None:
        """``retry_min_area_px`` if either image gated out a blob of an area from it up to the
        gate's minimum (the second pass's condition: the area test comes first, so such a
        blob was refused for its area), else None."""
        lo, gate = self.config.retry_min_area_px, self.config.gate
        if lo is None or lo >= gate.min_area_px:
            return None
        small = any(
            lo <= r.area_px < gate.min_area_px for r in (*feats_l.rejected, *feats_r.rejected)
        )
        return lo if small else None

    def _second_pass(
        self, left: np.ndarray, right: np.ndarray, feats_l: FeatureSet, feats_r: FeatureSet
    ) -> tuple[PoseResult, FeatureSet, FeatureSet] | None:
        """A refused frame solved once more where the first pass may have missed LEDs: with
        blobs down to ``retry_min_area_px`` (if such blobs were gated out) and, for a colour
        frame detected on the green excess, on eq. 9's gray (``retry_gray``). Every other test
        is unchanged (the NFA counts the extra candidates, the colour gate still applies).
        None when neither applies or the second pass floods the frame."""
        cfg = self.config
        floor = self._small_blob_floor(feats_l, feats_r)
        gray = cfg.retry_gray and left.ndim == 3 and cfg.colour_detect == "green"
        if floor is None and not gray:
            return None
        gate = cfg.gate if floor is None else replace(cfg.gate, min_area_px=floor)
        detect: ColourDetect | None = "gray" if gray else None
        return self._solve_again(left, right, gate, detect, None)

    def _local_contrast_pass(
        self, left: np.ndarray, right: np.ndarray, backgrounds_dn: tuple[float, float]
    ) -> tuple[PoseResult, FeatureSet, FeatureSet] | None:
        """A bright frame (the first pass's background medians ``backgrounds_dn``) both
        passes refused, solved once more on each image's local contrast
        (``retry_local_contrast_px``); every test unchanged. None when off, on a dark frame,
        or when it floods."""
        cfg = self.config
        side = cfg.retry_local_contrast_px
        if side is None or max(backgrounds_dn) < cfg.local_contrast_min_background_dn:
            return None
        return self._solve_again(left, right, None, None, side)

    def _solve_again(
        self,
        left: np.ndarray,
        right: np.ndarray,
        gate: BlobGate | None,
        detect: ColourDetect | None,
        local_px: int | None,
    ) -> tuple[PoseResult, FeatureSet, FeatureSet] | None:
        """One more pass of a refused frame with these feature settings (:meth:`_features`);
        the trace shows it only if it locks. None when it floods the frame."""
        try:
            feats_l, thr_l, stats_l = self._features(left, gate, detect, local_px)
            feats_r, thr_r, stats_r = self._features(right, gate, detect, local_px)
        except TooManyBlobs:
            return None
        trace = self.trace
        self.trace = PipelineTrace(
            left=feats_l, right=feats_r, thresholds=(thr_l, thr_r), backgrounds=(stats_l, stats_r)
        )
        result = self._solve(feats_l, feats_r, (stats_l[0], stats_r[0]))
        if not result.lock:
            self.trace = trace
        return result, feats_l, feats_r

    def _age_track(self) -> None:
        if self._track is not None:
            self._track.age += 1
            if self._track.age > self.config.track_frames:
                self._track = None

    def _appearance_ok(
        self,
        pairs: tuple[np.ndarray, np.ndarray],
        idx: np.ndarray,
        X: np.ndarray,
        feats_l: FeatureSet,
        feats_r: FeatureSet,
        background: tuple[float, float],
    ) -> np.ndarray:
        """Subset of ``idx`` (into the matched pairs ``pairs``: left, right blob indices) whose
        blobs look like one LED (app.vision.appearance): the verdicts for all matches at once,
        the reasons built for the rejected ones only."""
        cfg, cal = self.config, self.calibration
        if not cfg.appearance.enabled or len(idx) == 0:
            return idx
        z_l = X[idx, 2]
        z_r = (cal.R @ X[idx].T).T[:, 2] + float(cal.T[2])
        li, ri = pairs[0][idx], pairs[1][idx]
        f_l, f_r = cal.left.fx, cal.right.fx
        ok = appearance_ok(
            BlobTable.of(feats_l.blobs),
            BlobTable.of(feats_r.blobs),
            li,
            ri,
            z_l,
            z_r,
            f_l,
            f_r,
            cfg.led_diameter_mm,
            background,
            cfg.appearance,
        )
        for k in np.flatnonzero(~ok).tolist():
            reasons = appearance_reasons(
                feats_l.blobs[int(li[k])],
                feats_r.blobs[int(ri[k])],
                float(z_l[k]),
                float(z_r[k]),
                f_l,
                f_r,
                cfg.led_diameter_mm,
                background,
                cfg.appearance,
            )
            if reasons:
                self.trace.appearance_rejected[int(idx[k])] = reasons
            else:  # (the compiled verdict is tested equal; the reasons' rule has the last word)
                ok[k] = True
        return np.asarray(idx[ok], dtype=np.int64)

    def _solve(
        self, feats_l: FeatureSet, feats_r: FeatureSet, background: tuple[float, float]
    ) -> PoseResult:
        """Algorithm 1 after the features, in phases: match (eq. 14) → triangulate (eqs.
        15–16) → LED appearance → ring hypotheses, plane and circle fit (§5.2) → ids → error
        bound and records. ``background``: each image's background level (DN)."""
        cfg = self.config
        nl, nr = len(feats_l.blobs), len(feats_r.blobs)
        if nl < cfg.min_leds or nr < cfg.min_leds:
            return PoseResult(
                lock=False,
                reason=f"found {nl} LED candidate(s) in the left image and {nr} in the right; "
                f"need at least {cfg.min_leds} in each",
            )
        t0 = time.perf_counter()
        stereo = self._match(feats_l, feats_r)
        t1 = time.perf_counter()
        self._stage_ms["match"] = (t1 - t0) * 1e3
        if len(stereo.arrays) < cfg.min_leds:
            return PoseResult(
                lock=False,
                reason=f"only {len(stereo.arrays)} stereo match(es) passed the epipolar gate; "
                f"need at least {cfg.min_leds}",
            )
        points = self._triangulate(feats_l, feats_r, stereo)
        t2 = time.perf_counter()
        self._stage_ms["triangulate"] = (t2 - t1) * 1e3
        self.trace.match_arrays = points.matches
        self.trace.xyz_mm = points.xyz_mm
        idx = self._consistent_matches(points)
        if len(idx) < cfg.min_leds:
            return PoseResult(
                lock=False,
                reason=f"only {len(idx)} match(es) triangulate consistently "
                f"(reprojection ≤ {cfg.max_reprojection_px} px); need at least {cfg.min_leds}",
            )
        # --- LED appearance, ring hypotheses with integrity test, plane + circle fit
        n_matched = len(idx)
        pairs = (points.matches.left, points.matches.right)
        idx = self._appearance_ok(pairs, idx, points.xyz_mm, feats_l, feats_r, background)
        if len(idx) < cfg.min_leds:
            self._stage_ms["pose"] = (time.perf_counter() - t2) * 1e3
            return PoseResult(
                lock=False,
                reason=f"only {len(idx)} of {n_matched} matched point(s) look like LEDs "
                f"(size, stereo consistency, colour); need at least {cfg.min_leds}",
            )
        track = self._track
        ring = self._find_ring(points, idx, track)
        self._stage_ms["pose"] = (time.perf_counter() - t2) * 1e3
        if not isinstance(ring, RingFit):
            return PoseResult(lock=False, reason=ring.reason)
        self.trace.ring = ring
        ring_ids = self._ring_ids(ring, track)
        self.trace.roll_deg = ring_ids.roll_deg
        self._track = TrackMemory(
            ring.circle.center.copy(), ring.circle.normal.copy(), ring_ids.roll_deg
        )
        return self._bounded_lock(points, idx, ring, ring_ids)

    def _match(self, feats_l: FeatureSet, feats_r: FeatureSet) -> StereoMatches:
        """Undistort every candidate (px) and match them (eq. 14): the paper's minimum
        descriptor distance, or ours gated by the epipolar distance (``epipolar_tol_px``) and
        the depth range (mm) of the pair's linear triangulation."""
        cfg, cal = self.config, self.calibration
        xl = undistort_pixels(cal.left, feats_l.points_px)
        xr = undistort_pixels(cal.right, feats_r.points_px)
        ddist = descriptor_distances(feats_l.descriptors, feats_r.descriptors)
        epi = epipolar_distances(self.fundamental, xl, xr)
        if cfg.matcher == "paper":
            li, ri = match_min_distance_indices(ddist)
        else:
            # depth only for the pairs inside the epipolar gate (the others are never matched)
            il, ir = np.nonzero(epi <= cfg.epipolar_tol_px)
            depth = np.full((len(feats_l.blobs), len(feats_r.blobs)), np.inf)
            if len(il):
                X_g = triangulate_linear(cal.P_left, cal.P_right, xl[il], xr[ir])
                depth[il, ir] = X_g[:, 2]
            li, ri = match_epipolar_indices(
                ddist, epi, depth, cfg.epipolar_tol_px, cfg.depth_range_mm
            )
        return StereoMatches(left_px=xl, right_px=xr, arrays=MatchArrays.of(li, ri, ddist, epi))

    def _triangulate(
        self, feats_l: FeatureSet, feats_r: FeatureSet, stereo: StereoMatches
    ) -> StereoPoints:
        """Least-squares triangulation of every match (eqs. 15–16), refined by minimising the
        reprojection error (mm, left camera frame; the residual in px)."""
        cal = self.calibration
        li, ri = stereo.arrays.left, stereo.arrays.right
        xl, xr = stereo.left_px[li], stereo.right_px[ri]
        X0 = triangulate_linear(cal.P_left, cal.P_right, xl, xr)
        X, reproj = refine_reprojection(cal.P_left, cal.P_right, xl, xr, X0)
        return StereoPoints(feats_l, feats_r, stereo.arrays, X, reproj)

    def _consistent_matches(self, points: StereoPoints) -> np.ndarray:
        """Indices of the matches that reproject within ``max_reprojection_px`` (px) and lie
        finite in front of the cameras."""
        X = points.xyz_mm
        good = (
            (points.reprojection_px <= self.config.max_reprojection_px)
            & (X[:, 2] > 0)
            & np.all(np.isfinite(X), axis=1)
        )
        return np.flatnonzero(good)

    def _find_ring(
        self, points: StereoPoints, idx: np.ndarray, track: TrackMemory | None
    ) -> RingFit | RingRejection:
        """The ring among the points ``idx`` (§5.2: hypotheses with the a-contrario integrity
        test, plane and circle fit), a recent ``track`` as the prior of 3-LED hypotheses."""
        params = self.ring_params
        prior = None if track is None else RingPrior.at_range(track.center_mm, track.normal, params)
        return find_ring(
            points.xyz_mm[idx], params, prior, lambda fit: self._consistency(points, idx, fit)
        )

    def _consistency(self, points: StereoPoints, idx: np.ndarray, fit: RingFit) -> int:
        """How well this hypothesis' residuals agree with the centroid noise (the error
        bound's χ² test): 2 with the sensor model's σ alone (shot and read noise), 1 only
        with the σ the image itself shows (compression, blur: a glint's lopsided blob
        excuses its own offset that way), 0 with neither; 2 when not measured."""
        rows = [int(idx[k]) for k in fit.indices]
        bl, br = points.left_blobs(rows), points.right_blobs(rows)
        ul = np.array([b.centroid_px for b in bl])
        ur = np.array([b.centroid_px for b in br])
        rank = STRICT_RANK
        for sigma in (isotropic_model_sigma_px, isotropic_sigma_px):
            bound = lock_bound(
                self.calibration,
                ul,
                ur,
                np.array([sigma(b) for b in bl]),
                np.array([sigma(b) for b in br]),
                points.xyz_mm[rows],
                fit.circle,
                self.config.error_bound,
            )
            if bound is None or bound.consistent:
                return rank
            rank -= 1
        return 0

    def _ring_ids(self, ring: RingFit, track: TrackMemory | None) -> RingIds:
        """The LED ids of the fit's slots: they continue the track's roll only if the ring is
        where the track left it (within two radii, mm); otherwise the acquisition convention
        (:mod:`app.geometry.led_ids`)."""
        cfg = self.config
        spacing = 360.0 / cfg.led_count
        near = (
            track is not None
            and float(np.linalg.norm(ring.circle.center - track.center_mm))
            <= 2.0 * cfg.ring_radius_mm
        )
        roll = roll_from_offset(
            ring.offset_deg,
            cfg.led_count,
            cfg.led_phase_deg,
            track.roll_deg if (near and track is not None) else None,
        )
        slot_angles = ring.offset_deg + spacing * np.array(ring.slots, dtype=np.float64)
        ids = led_ids_for_angles(slot_angles, roll, cfg.led_count, cfg.led_phase_deg)
        return RingIds(roll_deg=roll, ids=ids)

    @staticmethod
    def _ring_leds(
        points: StereoPoints, idx: np.ndarray, ring: RingFit, ring_ids: RingIds
    ) -> RingLeds:
        """The ring's LEDs in id order with their blobs, centroid σ (px) and points (mm)."""
        order = sorted(zip(ring.indices, ring_ids.ids.tolist(), strict=True), key=lambda t: t[1])
        rows = [int(idx[k]) for k, _ in order]
        blobs_l, blobs_r = points.left_blobs(rows), points.right_blobs(rows)
        sigmas = [
            (isotropic_sigma_px(a), isotropic_sigma_px(b))
            for a, b in zip(blobs_l, blobs_r, strict=True)
        ]
        ids = [led_id for _, led_id in order]
        return RingLeds(ids, rows, blobs_l, blobs_r, sigmas, points.xyz_mm[rows])

    def _bounded_lock(
        self, points: StereoPoints, idx: np.ndarray, ring: RingFit, ring_ids: RingIds
    ) -> PoseResult:
        """The lock with its error bound (covariance, protection levels, residual test:
        :mod:`app.vision.error_bound`), the LED records built once with it; no lock (and no
        track) when the residual test fails."""
        leds_in = self._ring_leds(points, idx, ring, ring_ids)
        t3 = time.perf_counter()
        bound = bound_lock(
            self.calibration,
            np.array([b.centroid_px for b in leds_in.left]),
            np.array([b.centroid_px for b in leds_in.right]),
            leds_in.sigmas_px,
            leds_in.xyz_mm,
            ring.circle,
            self.config.error_bound,
        )
        self._stage_ms["bound"] = (time.perf_counter() - t3) * 1e3
        if isinstance(bound, str):
            self._track = None
            return PoseResult(lock=False, reason=bound)
        m = points.matches
        leds = [
            LedResult(
                id=int(led_id),
                left_px=bl.centroid_px,
                right_px=br.centroid_px,
                xyz_mm=(x[0], x[1], x[2]),
                descriptor_distance=float(m.descriptor_distance[j]),
                epipolar_px=float(m.epipolar_px[j]),
                reprojection_px=float(points.reprojection_px[j]),
                **led_bound_fields(bound, k, leds_in.sigmas_px[k]),
            )
            for k, (led_id, j, bl, br, x) in enumerate(
                zip(
                    leds_in.ids,
                    leds_in.rows,
                    leds_in.left,
                    leds_in.right,
                    leds_in.xyz_mm.tolist(),
                    strict=True,
                )
            )
        ]
        t4 = time.perf_counter()
        drogue = drogue_with_bound(ring.circle, bound)
        self._stage_ms["bound"] += (time.perf_counter() - t4) * 1e3
        return PoseResult(lock=True, reason=None, leds=leds, drogue=drogue)
