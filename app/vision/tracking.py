"""Windowed stereo tracking of the LED ring after a full-frame lock.

``StereoTracker(calibration).update(left, right) -> PoseResult`` (the pipeline's contract):

* **Acquisition** (no lock yet, lock lost, or any tracked check failed): the whole frame goes
  through a :class:`~app.vision.pipeline.NavigationPipeline` that the tracker owns.
* **Tracking** (after a lock): each LED's pixel position is predicted in both images
  (constant velocity on the LED pixels; an LED missing from the last lock is predicted by
  re-projecting its slot on the last fitted circle), and only a small window around each
  prediction is processed. The windows of both images are copied into one *mosaic* (left
  windows on the top row, right windows below, a zero column/row between windows), so that
  graying (BGR input) runs once per frame pair on a few per cent of the pixels, and the eq. 10
  threshold (per image), the median filter, labelling and the eq. 11 centroids run in one
  compiled call around each window's bright pixels, with each window's local-support
  centroid (:func:`~app.vision.blob_kernels.window_blobs`). Window half-size: max(3·r, 12
  px, the support) + |velocity| + 2 px (24 px of motion allowance while an LED's velocity is
  unknown), where the support is the blob, its centroid margin and, with ``describe``, its
  IHWT descriptor window; a blob
  whose support is not inside its window sends the frame to acquisition, so the centroids
  and descriptors equal the full-frame ones bit for bit.
* The threshold is the pipeline's "auto" rule, bg + max(0.25·(peak − bg), 6σ), with the
  background level and σ of the last acquisition and the peak of the windows and, for gray
  input with ``exact_peak`` (default), of the whole frame (one read-only max reduction per
  image, skipped when a window is saturated: a glint brighter than the LEDs sets the same
  threshold as in the full-frame pipeline). BGR input uses the windows' peak only (equal
  whenever the brightest pixel is an LED). An int threshold is used as is; "otsu" keeps the
  last acquisition's.
* **Integrity every tracked frame**: every window of a tracked LED holds exactly one LED-like
  blob (two → acquisition), the pair passes the epipolar gate, triangulates in the depth range
  with a small reprojection error and passes the appearance test; the points fit the ring
  (radius, RMS, one point per evenly spaced slot, view angle), agree with the last lock
  (:class:`~app.geometry.ring.RingPrior` gates), pass the a-contrario NFA test in the prior's
  neighbourhood, and the ids given by the slots (roll continuity, as the pipeline) equal the
  windows' ids; ≥ ``min_leds`` LEDs. Any failure → full-frame acquisition on the same frame.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np

from app.geometry.calibration import StereoCalibration
from app.geometry.circle_fit import (
    Circle3D,
    FitError,
    plane_basis,
)
from app.geometry.led_ids import led_ids_for_angles, roll_from_offset
from app.geometry.projection import project_stereo, undistort_pixels
from app.geometry.ring import (
    RingParams,
    RingPrior,
    agrees_with_prior,
    log10_nfa,
    prior_volume_mm3,
    ring_measures,
    view_angle_deg,
)
from app.geometry.triangulation import refine_reprojection, triangulate_linear
from app.model.pose import LedResult, PoseResult, StageTimings
from app.types import Rect
from app.vision.appearance import (
    BlobTable,
    appearance_ok,
    appearance_reasons,
    blob_color_bgr,
    equivalent_radius_px,
)
from app.vision.blob_kernels import window_blobs
from app.vision.error_bound import (
    bound_lock,
    drogue_with_bound,
    isotropic_sigma_px,
    led_bound_fields,
)
from app.vision.features import gate_array
from app.vision.ihwt import SAMPLES_PER_SUBSQUARE, describe
from app.vision.ihwt import window_side_px as ihwt_window_side_px
from app.vision.local_centroid import local_blob, measure_blobs, prefer_sharper, window_pad_px
from app.vision.local_centroid_kernels import OUT_U, OUT_V, OUT_X0, OUT_X1, OUT_Y0, OUT_Y1
from app.vision.matching import epipolar_distances
from app.vision.pipeline import (
    NavigationPipeline,
    PipelineConfig,
    PipelineTrace,
    check_pair,
)
from app.vision.preprocess import (
    ImageError,
    choose_threshold,
    detection_image,
    to_gray,
)
from app.vision.types import Blob

__all__ = ["ImageError", "Rect", "StereoTracker", "TrackerStats"]

UNKNOWN_MOTION_PX = 24.0  # window growth (px) while an LED's velocity is not known yet
Mode = Literal["acquired", "tracked", "lost"]


class _Fallback(Exception):
    """A tracked check failed: the frame goes to full-frame acquisition."""


@dataclass(slots=True)
class _Led:
    """One tracked LED: last centroids (px), the previous ones (velocity), blob radius."""

    left: tuple[float, float]
    right: tuple[float, float]
    prev_left: tuple[float, float] | None
    prev_right: tuple[float, float] | None
    radius_px: float


@dataclass
class _State:
    leds: dict[int, _Led]
    background: tuple[tuple[float, float], tuple[float, float]]  # (bg, σ) left, right
    thresholds: tuple[int, int]  # of the last acquisition ("otsu" mode)
    center_mm: np.ndarray
    normal: np.ndarray
    roll_deg: float


@dataclass
class TrackerStats:
    """Counts since construction (or ``reset``)."""

    acquired: int = 0
    tracked: int = 0
    fallbacks: int = 0
    lost: int = 0


@dataclass(slots=True)
class _Prediction:
    led_id: int
    left: tuple[float, float]  # predicted centroid (px)
    right: tuple[float, float]
    half: float  # window half-size (px)
    expected: bool  # in the last lock (else the search for a missing LED)


@dataclass(slots=True)
class _Window:
    led_id: int
    x0: int
    y0: int
    side: int
    mx: int  # column of the window in the mosaic
    row: int  # row of the window in the mosaic (0: left image, side + 1: right image)
    expected: bool  # the LED was in the last lock (else a search for a missing LED)


class StereoTracker:
    """Full-frame acquisition, then windowed tracking with integrity re-verified every frame.

    ``last_mode`` is ``"acquired"``, ``"tracked"`` or ``"lost"`` for the last ``update``;
    ``last_fallback`` says why tracking handed the last frame to acquisition (or ``None``).
    A locked result's ``reason`` carries the same information ("tracked" / "acquired: …").
    """

    def __init__(
        self,
        calibration: StereoCalibration,
        config: PipelineConfig | None = None,
        exact_peak: bool = True,
        describe: bool = False,
    ) -> None:
        # describe: IHWT descriptors of the tracked blobs, for ``descriptor_distance`` (as
        # the pipeline). Off by default: a tracked LED keeps its id by continuity, so the
        # descriptor serves no decision there (the field is −1: not computed), and the
        # windows need not hold the descriptor's window
        self.describe = describe
        # exact_peak: gray input, "auto" threshold: take the peak of eq. 10's rule over the
        # whole frame (a max reduction) so that a glint brighter than the LEDs sets the same
        # threshold as in the full-frame pipeline; False: the windows' peak only
        self.exact_peak = exact_peak
        self.pipeline = NavigationPipeline(calibration, config)
        self.calibration = calibration
        self.config = self.pipeline.config
        self._state: _State | None = None
        self.last_mode: Mode = "lost"
        self.last_fallback: str | None = None
        self.stats = TrackerStats()
        # the windows next_windows() planned for the next update (reused there, not redone)
        self._planned: tuple[list[_Window], list[_Window]] | None = None
        self._params: RingParams = self.pipeline.ring_params
        self._gate = gate_array(self.config.gate)
        # the local centroid's parameters for the windows' compiled call (empty: eq. 11 only)
        self._local_params = self.config.centroid.kernel_params()
        # _support_half by blob radius (px): a few radii recur frame after frame
        self._support_cache: dict[float, float] = {}

    def reset(self) -> None:
        """Forget the lock and the pipeline's track (a new, unrelated sequence)."""
        self._state = None
        self._planned = None
        self.pipeline.reset()
        self.stats = TrackerStats()

    @property
    def locked(self) -> bool:
        return self._state is not None

    # ------------------------------------------------------------------ entry
    def update(
        self,
        left: np.ndarray,
        right: np.ndarray,
        full_frame: Callable[[], tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> PoseResult:
        """Track (or acquire) on one stereo pair; same inputs and result as ``process``.

        ``full_frame``: optional zero-argument callable giving the full (left, right) pair,
        called only when a tracked frame falls back to full-frame acquisition. With it a
        caller may pass images in which only the rectangles of :meth:`next_windows` are
        filled in (a windowed render; full images when it returned ``None``) and still get
        exactly the result of full images.
        """
        t0 = time.perf_counter()
        planned, self._planned = self._planned, None
        left, right = check_pair(self.calibration, left, right)
        self.last_fallback = None
        if self._state is not None:
            try:
                result = self._track_frame(left, right, planned)
            except _Fallback as exc:
                self.last_fallback = str(exc)
                self.stats.fallbacks += 1
                if full_frame is not None:
                    left, right = check_pair(self.calibration, *full_frame())
            else:
                self.last_mode = "tracked"
                self.stats.tracked += 1
                total = (time.perf_counter() - t0) * 1e3
                result.timing_ms = StageTimings(total=total)
                return result
        return self._acquire(left, right)

    def next_windows(self) -> tuple[list[Rect], list[Rect]] | None:
        """Pixel rectangles (x0, y0, x1, y1), half-open, of the left and right images that
        the next :meth:`update` reads if it tracks; ``None`` when it will acquire on the full
        frame (no lock, or a predicted window leaves the image). A caller that fills in only
        these windows should build the tracker with ``exact_peak=False`` (the whole frame's
        peak is then unknown)."""
        if self._state is None:
            return None
        try:
            self._planned = win_l, win_r = self._plan(self._state)
        except _Fallback:
            return None
        side = (win_l or win_r)[0].side
        return (
            [(w.x0, w.y0, w.x0 + side, w.y0 + side) for w in win_l],
            [(w.x0, w.y0, w.x0 + side, w.y0 + side) for w in win_r],
        )

    # ------------------------------------------------------------------ acquisition
    def _acquire(self, left: np.ndarray, right: np.ndarray) -> PoseResult:
        result = self.pipeline.process(left, right)
        if not result.lock:
            self._state = None
            self.last_mode = "lost"
            self.stats.lost += 1
            return result
        trace = self.pipeline.trace
        track = self.pipeline.track
        assert trace.left is not None and trace.right is not None and track is not None
        radius_l = {b.centroid_px: equivalent_radius_px(b.area_px) for b in trace.left.blobs}
        radius_r = {b.centroid_px: equivalent_radius_px(b.area_px) for b in trace.right.blobs}
        old = {} if self._state is None else self._state.leds
        leds = {}
        for led in result.leds:
            r = max(radius_l.get(led.left_px, 2.0), radius_r.get(led.right_px, 2.0))
            o = old.get(led.id)  # the velocity continues through an acquisition, not a jump
            if o is not None and (
                math.dist(o.left, led.left_px) > 2.0 * UNKNOWN_MOTION_PX
                or math.dist(o.right, led.right_px) > 2.0 * UNKNOWN_MOTION_PX
            ):
                o = None
            leds[led.id] = _Led(
                led.left_px,
                led.right_px,
                None if o is None else o.left,
                None if o is None else o.right,
                r,
            )
        self._state = _State(
            leds=leds,
            background=trace.backgrounds,
            thresholds=trace.thresholds,
            center_mm=track.center_mm.copy(),
            normal=track.normal.copy(),
            roll_deg=track.roll_deg,
        )
        self.last_mode = "acquired"
        self.stats.acquired += 1
        why = f" (tracking fell back: {self.last_fallback})" if self.last_fallback else ""
        result.reason = f"acquired: full frame{why}"
        return result

    # ------------------------------------------------------------------ tracking
    def _support_half(self, radius_px: float) -> float:
        """Half-size (px) around a centroid that must lie inside its window: the blob, its
        eq. 11 centroid margin and (with descriptors) the IHWT descriptor window (cached by
        radius: :meth:`_support_half_of`)."""
        got = self._support_cache.get(radius_px)
        if got is None:
            if len(self._support_cache) > 256:
                self._support_cache.clear()
            got = self._support_cache[radius_px] = self._support_half_of(radius_px)
        return got

    def _support_half_of(self, radius_px: float) -> float:
        """:meth:`_support_half` computed."""
        area = math.pi * radius_px * radius_px
        support = radius_px + 2.0 + max(2.0, 0.5 * math.sqrt(area)) + 2.0
        # the local centroid's window and its background ring (app.vision.local_centroid)
        side = int(math.ceil(2.0 * radius_px)) + 1
        support = max(support, radius_px + 1.0 + window_pad_px(side, side) + 2.0)
        if self.describe:
            cfg = self.config
            win = ihwt_window_side_px(area, self.pipeline.window_factor, cfg.min_window_px)
            support = max(support, 0.5 * win + win / (4 * SAMPLES_PER_SUBSQUARE) + 3.0)
        return support

    def _window_half(self, radius_px: float, speed_px: float) -> int:
        """Window half-size: max(3·r, 12 px, the support) + |velocity| + 2 px."""
        base = max(3.0 * radius_px, 12.0, self._support_half(radius_px))
        return int(math.ceil(base + speed_px + 2.0))

    def _predict(self, st: _State) -> list[_Prediction]:
        """(id, left px, right px, half-size, expected) for every LED slot to look at."""
        out = []
        speeds = []
        vel_l, vel_r = [], []
        for led_id, led in st.leds.items():
            (lu, lv), (ru, rv) = led.left, led.right
            if led.prev_left is None or led.prev_right is None:
                vl = vr = (0.0, 0.0)
                speed = UNKNOWN_MOTION_PX  # unknown velocity (first frame)
            else:
                vl = (lu - led.prev_left[0], lv - led.prev_left[1])
                vr = (ru - led.prev_right[0], rv - led.prev_right[1])
                speed = max(math.hypot(*vl), math.hypot(*vr))  # |velocity| widens the window
            vel_l.append(vl)
            vel_r.append(vr)
            speeds.append(speed)
            half = self._window_half(led.radius_px, speed)
            left = (lu + vl[0], lv + vl[1])
            out.append(_Prediction(led_id, left, (ru + vr[0], rv + vr[1]), float(half), True))
        n = self.config.led_count
        missing = [i for i in range(1, n + 1) if i not in st.leds]
        if missing:
            # slot positions of the missing LEDs on the last circle, moved like the others
            mean_l = np.mean(vel_l, axis=0)
            mean_r = np.mean(vel_r, axis=0)
            e_up, e_right = plane_basis(st.normal)
            spacing = 360.0 / n
            ang = np.radians(
                self.config.led_phase_deg + st.roll_deg + spacing * (np.array(missing) - 1)
            )
            pts = st.center_mm + self.config.ring_radius_mm * (
                np.outer(np.cos(ang), e_up) + np.outer(np.sin(ang), e_right)
            )
            pl, pr = project_stereo(self.calibration, pts)
            pl, pr = (pl + mean_l).tolist(), (pr + mean_r).tolist()
            r = max(led.radius_px for led in st.leds.values())
            half = self._window_half(r, max(speeds) + 4.0)
            for k, led_id in enumerate(missing):
                out.append(_Prediction(led_id, tuple(pl[k]), tuple(pr[k]), float(half), False))
        return out

    def _windows(
        self,
        centres: list[tuple[float, float]],
        ids: list[int],
        expected: list[bool],
        side: int,
        row: int,
    ) -> list[_Window]:
        """Windows of one image (clipped windows of tracked LEDs → acquisition)."""
        w_img, h_img = self.calibration.image_size
        out: list[_Window] = []
        for led_id, c, exp in zip(ids, centres, expected, strict=True):
            x0 = round(c[0]) - side // 2
            y0 = round(c[1]) - side // 2
            if x0 < 1 or y0 < 1 or x0 + side > w_img - 1 or y0 + side > h_img - 1:
                if exp:
                    raise _Fallback(f"the window of LED {led_id} leaves the image")
                continue  # a missing LED predicted out of view stays missing
            out.append(_Window(led_id, x0, y0, side, 1 + len(out) * (side + 1), row, exp))
        return out

    def _plan(self, st: _State) -> tuple[list[_Window], list[_Window]]:
        """The windows (one common side) of both images for the predicted LEDs."""
        pred = self._predict(st)
        side = 2 * int(max(p.half for p in pred)) + 1
        ids = [p.led_id for p in pred]
        expected = [p.expected for p in pred]
        win_l = self._windows([p.left for p in pred], ids, expected, side, 0)
        win_r = self._windows([p.right for p in pred], ids, expected, side, side + 1)
        return win_l, win_r

    def _threshold(
        self,
        gray: np.ndarray,
        frame: np.ndarray | None,
        background: tuple[float, float],
        last: int,
    ) -> int:
        """Eq. 10's threshold for the windows of one image (see the module docstring);
        ``frame``: the gray frame whose whole peak counts (exact peak), else None."""
        mode = self.config.threshold
        if mode == "otsu":
            return last
        if mode != "auto":
            return choose_threshold(gray, mode, background)
        peak = float(cv2.minMaxLoc(gray)[1])
        if frame is not None and peak < 255.0:
            # a glint may outshine the LEDs: the full frame's peak, one read-only max
            # reduction (numpy's: no minimum or location kept; no gray conversion,
            # threshold, median or labelling); not read when a window is saturated (nothing
            # in the frame is brighter)
            peak = max(peak, float(frame.max()))
        bg, sigma = background
        return int(min(255, max(1, round(bg + max(0.25 * (peak - bg), 6.0 * sigma)))))

    def _extract(
        self,
        left: np.ndarray,
        right: np.ndarray,
        st: _State,
        planned: tuple[list[_Window], list[_Window]] | None = None,
    ) -> tuple[
        list[_Window], list[_Window], np.ndarray, dict[int, Blob], dict[int, Blob], tuple[int, int]
    ]:
        """Crop every window of both images into one mosaic (left windows on the top row,
        right windows below, one zero column/row between windows) and find each window's
        blob there: one gray conversion for the whole frame pair, then one compiled call
        (:func:`~app.vision.blob_kernels.window_blobs`: eq. 10 with each image's threshold,
        the median filter, labelling and eq. 11 around each window's bright pixels).
        Returns (windows left/right, the gray mosaic, ids → blob (mosaic px) left/right,
        the thresholds)."""
        cfg = self.config
        win_l, win_r = planned if planned is not None else self._plan(st)
        side = win_l[0].side
        cols = max(len(win_l), len(win_r))
        if left.ndim != right.ndim or (left.ndim == 3 and left.shape[2] != right.shape[2]):
            raise _Fallback("left and right images have different channel counts")
        mosaic = np.zeros((2 * side + 1, cols * (side + 1) + 1) + left.shape[2:], np.uint8)
        for wins, image in ((win_l, left), (win_r, right)):
            for w in wins:
                mosaic[w.row : w.row + side, w.mx : w.mx + side] = image[
                    w.y0 : w.y0 + side, w.x0 : w.x0 + side
                ]
        gray = detection_image(mosaic, cfg.colour_detect)
        top, bottom = gray[:side], gray[side + 1 :]
        exact = self.exact_peak and left.ndim == 2
        thr_l = self._threshold(top, left if exact else None, st.background[0], st.thresholds[0])
        thr_r = self._threshold(
            bottom, right if exact else None, st.background[1], st.thresholds[1]
        )
        wins = win_l + win_r
        rows = np.array([[w.mx, w.row, side] for w in wins], np.int64)
        thr = np.array([thr_l] * len(win_l) + [thr_r] * len(win_r), np.int64)
        bgs = [st.background[0][0]] * len(win_l) + [st.background[1][0]] * len(win_r)
        # with the local-support centroids of all windows' blobs, measured in the same call
        # (a window with no blob or several is refused below before its row is used)
        counts, stats, cents, table = window_blobs(
            gray,
            rows,
            thr,
            np.array(bgs, np.float64),
            cfg.median_ksize,
            self._gate,
            self._local_params,
        )
        local = table.tolist() if cfg.centroid.enabled else None
        got: list[dict[int, Blob]] = [{}, {}]
        outside: str | None = None  # the first blob whose local centroid reads outside its window
        for k, ((x, y, w, h, area), (u, v, mass, peak), n) in enumerate(
            zip(stats.tolist(), cents.tolist(), counts.tolist(), strict=True)
        ):
            win = wins[k]
            side_name = "left" if k < len(win_l) else "right"
            if n > 1:
                raise _Fallback(f"{n} LED-like blobs in the {side_name} window of LED {win.led_id}")
            if n == 0:
                if win.expected:
                    raise _Fallback(f"LED {win.led_id} not found in its {side_name} window")
                continue
            # the centroid support and the descriptor window must lie inside the window
            # (around the local centroid where it is measured: eq. 11 then is not computed)
            if local is not None and local[k][OUT_U] == local[k][OUT_U]:
                u, v = local[k][OUT_U], local[k][OUT_V]
            need = self._support_half(equivalent_radius_px(area))
            if (
                u - need < win.mx
                or u + need > win.mx + side - 1
                or v - need < win.row
                or v + need > win.row + side - 1
            ):
                raise _Fallback(f"LED {win.led_id} is at the edge of its {side_name} window")
            colour = None
            if mosaic.ndim == 3 and cfg.appearance.enabled:
                t = thr_l if k < len(win_l) else thr_r
                sat = cfg.appearance.saturated_dn
                colour = blob_color_bgr(
                    mosaic, Blob((u, v), area, (x, y, w, h), peak, mass), t, sat
                )
            if local is None:
                blob = Blob((u, v), area, (x, y, w, h), peak, mass, colour)
            else:
                # the pixels the local centroid reads must lie in its own window (else they
                # are not the full frame's)
                row = local[k]
                x0, y0, x1, y1 = row[OUT_X0], row[OUT_Y0], row[OUT_X1], row[OUT_Y1]
                if outside is None and (
                    x0 < win.mx or y0 < win.row or x1 > win.mx + side or y1 > win.row + side
                ):
                    outside = f"LED {win.led_id}'s centroid support leaves its window"
                blob = local_blob((u, v), area, (x, y, w, h), peak, mass, colour, row)
            got[0 if k < len(win_l) else 1][win.led_id] = blob
        if outside is not None:
            raise _Fallback(outside)
        if mosaic.ndim == 3 and cfg.colour_detect == "green" and cfg.centroid.enabled:
            if cfg.centroid.gray_too:
                got = self._sharper_on_gray(mosaic, (win_l, win_r), got)
        return win_l, win_r, gray, got[0], got[1], (thr_l, thr_r)

    def _sharper_on_gray(
        self,
        mosaic: np.ndarray,
        windows: tuple[list[_Window], list[_Window]],
        got: list[dict[int, Blob]],
    ) -> list[dict[int, Blob]]:
        """The windows' blobs (mosaic px) with each one's measurement on eq. 9's gray where
        that is the sharper (:func:`~app.vision.local_centroid.prefer_sharper`, as the full
        frame's pipeline does), read inside its own window only."""
        gray = to_gray(mosaic)
        out: list[dict[int, Blob]] = []
        for wins, blobs in zip(windows, got, strict=True):
            ids = list(blobs)
            if not ids:
                out.append(blobs)
                continue
            rect = {w.led_id: (w.mx, w.row, w.mx + w.side, w.row + w.side) for w in wins}
            listed = [blobs[i] for i in ids]
            table = measure_blobs(gray, listed, self.config.centroid)
            sharper = prefer_sharper(listed, table, [rect[i] for i in ids])
            out.append(dict(zip(ids, sharper, strict=True)))
        return out

    def _track_frame(
        self,
        left: np.ndarray,
        right: np.ndarray,
        planned: tuple[list[_Window], list[_Window]] | None = None,
    ) -> PoseResult:
        st = self._state
        assert st is not None
        cfg, cal = self.config, self.calibration
        win_l, win_r, gray, got_l, got_r, (thr_l, thr_r) = self._extract(left, right, st, planned)
        led_ids = sorted(i for i in got_l if i in got_r)
        for i in set(got_l) ^ set(got_r):
            if i in st.leds:
                raise _Fallback(f"LED {i} seen in one image only")
            raise _Fallback(f"missing LED {i} reappeared in one image only")
        if len(led_ids) < cfg.min_leds:
            raise _Fallback(f"only {len(led_ids)} LEDs tracked; need {cfg.min_leds}")
        # the blobs (mosaic coordinates: size, peak and colour serve below) and their
        # centroids in image coordinates
        bl = [got_l[i] for i in led_ids]
        br = [got_r[i] for i in led_ids]
        off_l = {w.led_id: (w.x0 - w.mx, w.y0 - w.row) for w in win_l}
        off_r = {w.led_id: (w.x0 - w.mx, w.y0 - w.row) for w in win_r}
        pl = np.array([b.centroid_px for b in bl]) + np.array([off_l[i] for i in led_ids])
        pr = np.array([b.centroid_px for b in br]) + np.array([off_r[i] for i in led_ids])
        n_led = len(led_ids)
        if self.describe:
            # IHWT descriptors on the mosaic (each window holds its descriptor window)
            wf, mw = self.pipeline.window_factor, cfg.min_window_px
            mblobs = [got_l[i] for i in led_ids] + [got_r[i] for i in led_ids]
            desc = describe(gray, mblobs, wf, mw)
            desc_dist = np.sqrt(np.sum((desc[:n_led] - desc[n_led:]) ** 2, axis=1)).tolist()
        else:
            desc_dist = [-1.0] * n_led  # not computed
        # --- epipolar gate and triangulation (as the pipeline)
        xl = undistort_pixels(cal.left, pl)
        xr = undistort_pixels(cal.right, pr)
        epi = np.diagonal(epipolar_distances(self.pipeline.fundamental, xl, xr))  # pairs i ↔ i
        epi_f = epi.tolist()
        if any(e > cfg.epipolar_tol_px for e in epi_f):
            raise _Fallback("a tracked LED pair left the epipolar gate")
        X0 = triangulate_linear(cal.P_left, cal.P_right, xl, xr)
        X, reproj = refine_reprojection(cal.P_left, cal.P_right, xl, xr, X0)
        z0, z1 = cfg.depth_range_mm
        if not (
            np.isfinite(X).all()
            and reproj.max() <= cfg.max_reprojection_px
            and X0[:, 2].min() >= z0
            and X0[:, 2].max() <= z1
            and X[:, 2].min() > 0
        ):
            raise _Fallback("a tracked LED does not triangulate consistently")
        # --- appearance (the pipeline's verdict, all pairs at once; reasons on failure only)
        if cfg.appearance.enabled:
            z_l = X[:, 2]
            z_r = X @ cal.R[2] + float(cal.T[2])  # depth in the right camera
            f_l, f_r = cal.left.fx, cal.right.fx
            bgs = (st.background[0][0], st.background[1][0])
            pair = np.arange(n_led, dtype=np.int64)
            ok = appearance_ok(
                BlobTable.of(bl), BlobTable.of(br), pair, pair, z_l, z_r, f_l, f_r,
                cfg.led_diameter_mm, bgs, cfg.appearance,
            )  # fmt: skip
            if not ok.all():
                k = int(np.flatnonzero(~ok)[0])
                reasons = appearance_reasons(
                    bl[k], br[k], float(z_l[k]), float(z_r[k]), f_l, f_r,
                    cfg.led_diameter_mm, bgs, cfg.appearance,
                )  # fmt: skip
                raise _Fallback(f"LED {led_ids[k]} fails the appearance test: {reasons[0]}")
        # --- ring, integrity, ids
        circle, roll, slot_ids = self._ring_checks(X, st)
        if slot_ids != led_ids:
            raise _Fallback(f"slot ids {slot_ids} differ from the tracked ids {led_ids}")
        # the pipeline's track continues through tracked frames (ids after a fallback)
        self.pipeline.continue_track(circle.center.copy(), circle.normal.copy(), roll)
        # --- state for the next frame
        pl_f, pr_f, X_f = pl.tolist(), pr.tolist(), X.tolist()
        leds: dict[int, _Led] = {}
        for k, i in enumerate(led_ids):
            old = st.leds.get(i)
            r = max(equivalent_radius_px(bl[k].area_px), equivalent_radius_px(br[k].area_px))
            leds[i] = _Led(
                (pl_f[k][0], pl_f[k][1]),
                (pr_f[k][0], pr_f[k][1]),
                None if old is None else old.left,
                None if old is None else old.right,
                r,
            )
        st.leds = leds
        st.center_mm, st.normal, st.roll_deg = circle.center.copy(), circle.normal.copy(), roll
        # the pipeline's trace describes its last full frame; a tracked frame leaves only
        # its thresholds there (no full-frame features were computed)
        self.pipeline.trace = PipelineTrace(thresholds=(thr_l, thr_r), roll_deg=roll)
        sigmas = [
            (isotropic_sigma_px(a), isotropic_sigma_px(b)) for a, b in zip(bl, br, strict=True)
        ]
        bound = bound_lock(cal, pl, pr, sigmas, X, circle, cfg.error_bound)
        if isinstance(bound, str):
            raise _Fallback(bound)
        results = [
            LedResult(
                id=i,
                left_px=(pl_f[k][0], pl_f[k][1]),
                right_px=(pr_f[k][0], pr_f[k][1]),
                xyz_mm=(X_f[k][0], X_f[k][1], X_f[k][2]),
                descriptor_distance=d,
                epipolar_px=e,
                reprojection_px=rp,
                **led_bound_fields(bound, k, sigmas[k]),
            )
            for k, (i, d, e, rp) in enumerate(
                zip(led_ids, desc_dist, epi_f, reproj.tolist(), strict=True)
            )
        ]
        drogue = drogue_with_bound(circle, bound)
        return PoseResult(lock=True, reason="tracked", leds=results, drogue=drogue)

    def _ring_checks(self, X: np.ndarray, st: _State) -> tuple[Circle3D, float, list[int]]:
        """The ring tests of :func:`app.geometry.ring.find_ring` on the tracked points, with
        the last lock as the prior; returns (circle, roll deg, ids in point order)."""
        cfg, params = self.config, self._params
        n = cfg.led_count
        try:
            ring = ring_measures(X, n)
        except FitError as exc:
            raise _Fallback(f"ring fit failed: {exc}") from None
        circle, offset, slots, resid = ring.circle, ring.offset_deg, ring.slots, ring.resid_deg
        z = float(circle.center[2])
        itol, atol = float(params.inlier_tol(z)), float(params.angle_tol_deg_at(z))
        if abs(circle.radius - params.radius_mm) > float(params.radius_tol(z)):
            raise _Fallback(f"ring radius {circle.radius:.1f} mm out of tolerance")
        if circle.rms > itol:
            raise _Fallback(f"ring RMS {circle.rms:.2f} mm > {itol:.2f} mm")
        if ring.distance_mm.max() > itol:
            raise _Fallback("a tracked LED is off the ring")
        if len(set(slots.tolist())) != len(slots) or np.abs(resid).max() > atol:
            raise _Fallback("the tracked LEDs are not on distinct, evenly spaced slots")
        if view_angle_deg(circle) > params.max_view_angle_deg:
            raise _Fallback("the ring is seen edge-on")
        prior = RingPrior.at_range(st.center_mm, st.normal, params)
        if not agrees_with_prior(circle, prior):
            dc = float(np.linalg.norm(circle.center - prior.center_mm))
            raise _Fallback(f"the ring moved away from the last lock ({dc:.0f} mm)")
        volume = prior_volume_mm3(params, prior)
        nfa = log10_nfa(len(X), volume, circle, X, resid, params, ring.distance_mm)
        if nfa > params.log10_nfa_max:
            raise _Fallback(f"not distinctive (NFA 10^{nfa:.1f})")
        moved = circle.center - st.center_mm
        near = math.sqrt(float(moved @ moved)) <= 2.0 * cfg.ring_radius_mm
        roll = roll_from_offset(offset, n, cfg.led_phase_deg, st.roll_deg if near else None)
        slot_angles = offset + (360.0 / n) * slots.astype(np.float64)
        ids = led_ids_for_angles(slot_angles, roll, n, cfg.led_phase_deg)
        return circle, roll, [int(i) for i in ids]
