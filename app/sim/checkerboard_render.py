"""Synthetic checkerboard stereo views rendered exactly through a calibration (paper §3.2).

The paper calibrates its rig from checkerboard (CCP) pictures with Zhang's method. This module
renders such pictures *exactly* through a :class:`~app.geometry.calibration.StereoCalibration`
(distortion eq. 7 and skew γ of eq. 2 included), so the calibration workflow can be checked
against a known truth offline:

1. for every pixel (3×3 sub-pixel samples for anti-aliasing) the ideal normalised ray is found
   once per camera by undistorting the pixel grid (:func:`app.geometry.projection.undistort_pixels`,
   which handles the skew);
2. per view the rays are intersected with the board plane and the checker pattern is evaluated
   in board coordinates (mm);
3. the samples are averaged, then lit, blurred (Gaussian, px) and given sensor noise (DN).

Board frame: origin at the first inner corner, x along a row of inner corners, y along a
column, z into the board; inner corner (i, j) is at (i·s, j·s, 0) mm; the square touching
the origin's upper-left is black. Regenerate the sample set with::

    .venv/bin/python -m app.sim.checkerboard_render sample_data/checkerboard
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from app.geometry.calibration import CameraIntrinsics, StereoCalibration
from app.geometry.projection import project_camera, undistort_pixels
from app.types import FloatArray, UInt8Array


@dataclass(frozen=True)
class CheckerboardSpec:
    """A printed checkerboard: ``cols`` × ``rows`` inner corners, ``square_mm`` squares, and a
    white margin of ``margin_mm`` around the outer squares."""

    cols: int = 9
    rows: int = 6
    square_mm: float = 25.0
    margin_mm: float = 25.0

    def object_points(self) -> FloatArray:
        """Inner corners in the board frame (N×3, mm), row-major (OpenCV's detector order)."""
        jj, ii = np.mgrid[0 : self.rows, 0 : self.cols]
        pts = np.column_stack([ii.ravel(), jj.ravel(), np.zeros(ii.size)]) * self.square_mm
        return np.asarray(pts, dtype=np.float64)

    @property
    def extent_mm(self) -> tuple[float, float, float, float]:
        """Outer edge of the printed board (x0, x1, y0, y1) in the board frame, mm."""
        s, m = self.square_mm, self.margin_mm
        return (-s - m, self.cols * s + m, -s - m, self.rows * s + m)

    @property
    def center_mm(self) -> FloatArray:
        return np.array(
            [(self.cols - 1) * self.square_mm / 2, (self.rows - 1) * self.square_mm / 2, 0.0]
        )

    def outline_points(self, with_margin: bool = True) -> FloatArray:
        """The four outer corners of the printed board, or of its squares (4×3, mm)."""
        if with_margin:
            x0, x1, y0, y1 = self.extent_mm
        else:
            s = self.square_mm
            x0, x1, y0, y1 = -s, self.cols * s, -s, self.rows * s
        return np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])

    def reflectance(self, bx: FloatArray, by: FloatArray) -> FloatArray:
        """Pattern value at board coordinates (mm): 0 black square, 1 white, NaN off the board."""
        s = self.square_mm
        ix = np.floor(bx / s)
        iy = np.floor(by / s)
        in_squares = (ix >= -1) & (ix <= self.cols - 1) & (iy >= -1) & (iy <= self.rows - 1)
        black = in_squares & ((ix + iy) % 2 == 0)
        value = np.where(black, 0.0, 1.0)
        x0, x1, y0, y1 = self.extent_mm
        on_board = (bx >= x0) & (bx <= x1) & (by >= y0) & (by <= y1)
        return np.where(on_board, value, np.nan)


@dataclass(frozen=True)
class BoardPose:
    """Board frame → left camera frame: ``X_cam = R · X_board + t`` (t in mm)."""

    R: FloatArray
    t: FloatArray

    def to_dict(self) -> dict[str, Any]:
        return {"R": self.R.tolist(), "t_mm": self.t.tolist()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> BoardPose:
        return cls(
            R=np.asarray(data["R"], dtype=np.float64), t=np.asarray(data["t_mm"], dtype=np.float64)
        )


@dataclass(frozen=True)
class CheckerRenderSettings:
    """Photometry of the synthetic pictures (grey levels in DN of an 8-bit sensor)."""

    supersample: int = 3  # sub-pixel samples per axis (anti-aliasing)
    black_dn: float = 35.0
    white_dn: float = 215.0
    background_dn: float = 95.0
    illumination_gradient: float = 0.12  # ± relative brightness change across the image
    blur_sigma_px: float = 0.8
    noise_sigma_dn: float = 0.8


def pixel_rays(
    cam: CameraIntrinsics, image_size: tuple[int, int], supersample: int = 3
) -> NDArray[np.float32]:
    """Ideal normalised ray coordinates (x/z, y/z) for every sub-pixel sample.

    Returns an array (S, H, W, 2), S = supersample², float32. Pixel centres are at integer
    coordinates (OpenCV convention); sub-samples sit at offsets (k + 0.5)/n − 0.5.
    """
    w, h = image_size
    offsets = (np.arange(supersample) + 0.5) / supersample - 0.5
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    K_inv = np.linalg.inv(cam.K)
    out = np.empty((supersample * supersample, h, w, 2), dtype=np.float32)
    k = 0
    for dv in offsets:
        for du in offsets:
            px = np.column_stack([(uu + du).ravel(), (vv + dv).ravel()])
            ideal = undistort_pixels(cam, px)  # ideal pixels in the same K (skew included)
            norm = ideal @ K_inv[:2, :2].T + K_inv[:2, 2]
            out[k] = norm.reshape(h, w, 2).astype(np.float32)
            k += 1
    return out


def _illumination(h: int, w: int, gradient: float, phase: float) -> FloatArray:
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    x = (uu / max(w - 1, 1)) * 2 - 1
    y = (vv / max(h - 1, 1)) * 2 - 1
    return 1.0 + gradient * (math.cos(phase) * x + math.sin(phase) * y)


def render_board_view(
    rays: NDArray[np.float32],
    R_cam_board: FloatArray,
    t_cam_board_mm: FloatArray,
    spec: CheckerboardSpec,
    settings: CheckerRenderSettings | None = None,
    rng: np.random.Generator | None = None,
    light_phase_rad: float = 0.0,
) -> UInt8Array:
    """Render the board seen by one camera (board pose given in that camera's frame).

    ``rays`` comes from :func:`pixel_rays`. Each ray (x, y, 1)·λ meets the plane
    n·(X − t) = 0 at λ = n·t / n·d; board coordinates are Rᵀ(X − t).
    """
    st = settings or CheckerRenderSettings()
    rng = rng if rng is not None else np.random.default_rng(0)
    _, h, w, _ = rays.shape
    R = np.asarray(R_cam_board, dtype=np.float64)
    t = np.asarray(t_cam_board_mm, dtype=np.float64)
    n = R[:, 2]
    r0, r1 = R[:, 0], R[:, 1]
    nt, r0t, r1t = float(n @ t), float(r0 @ t), float(r1 @ t)
    acc = np.zeros((h, w), dtype=np.float64)
    for s in range(rays.shape[0]):
        x = rays[s, :, :, 0].astype(np.float64)
        y = rays[s, :, :, 1].astype(np.float64)
        nd = n[0] * x + n[1] * y + n[2]
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = nt / nd
        bx = lam * (r0[0] * x + r0[1] * y + r0[2]) - r0t
        by = lam * (r1[0] * x + r1[1] * y + r1[2]) - r1t
        refl = spec.reflectance(bx, by)
        refl = np.where(lam > 0, refl, np.nan)
        board_dn = st.black_dn + (st.white_dn - st.black_dn) * refl
        acc += np.where(np.isnan(refl), st.background_dn, board_dn)
    img = acc / rays.shape[0]
    img *= _illumination(h, w, st.illumination_gradient, light_phase_rad)
    if st.blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), st.blur_sigma_px)
    if st.noise_sigma_dn > 0:
        img = img + rng.normal(0.0, st.noise_sigma_dn, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _rot_axis_angle(axis: FloatArray, angle_rad: float) -> FloatArray:
    rvec = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis) * angle_rad
    R, _ = cv2.Rodrigues(rvec)
    return np.asarray(R, dtype=np.float64)


def board_visible(
    calib: StereoCalibration, pose: BoardPose, spec: CheckerboardSpec, border_px: float = 25.0
) -> bool:
    """True when all the squares of the board project inside both images with ``border_px`` to
    spare (the white margin may be cut by the image edge)."""
    w, h = calib.image_size
    pts = (pose.R @ spec.outline_points(with_margin=False).T).T + pose.t
    pts_r = (calib.R @ pts.T).T + calib.T
    if np.any(pts[:, 2] <= 0) or np.any(pts_r[:, 2] <= 0):
        return False
    for cam, p in ((calib.left, pts), (calib.right, pts_r)):
        uv = project_camera(cam, p)
        if (
            np.any(uv < border_px)
            or np.any(uv[:, 0] > w - 1 - border_px)
            or np.any(uv[:, 1] > h - 1 - border_px)
        ):
            return False
    return True


def sample_poses(
    calib: StereoCalibration,
    spec: CheckerboardSpec,
    n_views: int = 14,
    seed: int = 7,
    distance_mm: tuple[float, float] = (700.0, 1200.0),
    max_tilt_deg: float = 35.0,
    max_roll_deg: float = 20.0,
) -> list[BoardPose]:
    """Varied board poses seen fully by both cameras.

    Distances are spread evenly over ``distance_mm`` (shuffled); tilts (out-of-plane rotation
    about a random in-plane axis) alternate between strong (≥ 60 % of ``max_tilt_deg``) and
    moderate; the board centre is placed at a random point of the shared field of view.
    """
    rng = np.random.default_rng(seed)
    dists = np.linspace(distance_mm[0], distance_mm[1], n_views)
    rng.shuffle(dists)
    # the rig's mid axis: between the left optical axis and the right one
    z_mid = np.array([0.0, 0.0, 1.0]) + calib.R.T @ np.array([0.0, 0.0, 1.0])
    z_mid /= np.linalg.norm(z_mid)
    mid_origin = calib.right_center_mm / 2
    poses: list[BoardPose] = []
    for k, dist in enumerate(dists):
        lo = 0.6 * max_tilt_deg if k % 2 == 0 else 0.0
        hi = max_tilt_deg if k % 2 == 0 else 0.6 * max_tilt_deg
        for _attempt in range(2000):
            tilt = math.radians(rng.uniform(lo, hi))
            phi = rng.uniform(0, 2 * math.pi)
            axis = np.array([math.cos(phi), math.sin(phi), 0.0])
            roll = math.radians(rng.uniform(-max_roll_deg, max_roll_deg))
            R = _rot_axis_angle(axis, tilt) @ _rot_axis_angle(np.array([0.0, 0.0, 1.0]), roll)
            # field of view fraction that the centre may wander in (smaller when close)
            shift = rng.uniform(-1, 1, size=2) * dist * np.array([0.16, 0.12])
            center = mid_origin + z_mid * dist + np.array([shift[0], shift[1], 0.0])
            t = center - R @ spec.center_mm
            pose = BoardPose(R=R, t=t)
            if board_visible(calib, pose, spec):
                poses.append(pose)
                break
        else:
            raise RuntimeError(f"could not place a fully visible board at {dist:.0f} mm")
    return poses


@dataclass
class RenderedCheckerSet:
    """Rendered stereo checkerboard views and the truth they were made from."""

    left: list[UInt8Array]
    right: list[UInt8Array]
    poses: list[BoardPose]
    spec: CheckerboardSpec
    settings: CheckerRenderSettings
    calibration: StereoCalibration
    seed: int
    names: list[str] = field(default_factory=list)


def render_checker_set(
    calib: StereoCalibration,
    spec: CheckerboardSpec | None = None,
    n_views: int = 14,
    seed: int = 7,
    settings: CheckerRenderSettings | None = None,
    poses: list[BoardPose] | None = None,
    progress: bool = False,
) -> RenderedCheckerSet:
    """Render ``n_views`` stereo pairs of the board through ``calib`` (exact, with skew)."""
    spec = spec or CheckerboardSpec()
    st = settings or CheckerRenderSettings()
    poses = poses if poses is not None else sample_poses(calib, spec, n_views, seed)
    rays_l = pixel_rays(calib.left, calib.image_size, st.supersample)
    rays_r = pixel_rays(calib.right, calib.image_size, st.supersample)
    rng = np.random.default_rng(seed + 1000)
    left: list[UInt8Array] = []
    right: list[UInt8Array] = []
    iterator: Any = range(len(poses))
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc="render", unit="pair")
    for k in iterator:
        pose = poses[k]
        phase = rng.uniform(0, 2 * math.pi)
        left.append(render_board_view(rays_l, pose.R, pose.t, spec, st, rng, phase))
        R_r = calib.R @ pose.R
        t_r = calib.R @ pose.t + calib.T
        right.append(render_board_view(rays_r, R_r, t_r, spec, st, rng, phase))
    names = [f"{k:02d}" for k in range(len(poses))]
    return RenderedCheckerSet(left, right, list(poses), spec, st, calib, seed, names)


def write_sample_set(
    out_dir: str | Path,
    calib: StereoCalibration,
    spec: CheckerboardSpec | None = None,
    n_views: int = 14,
    seed: int = 7,
    settings: CheckerRenderSettings | None = None,
    progress: bool = True,
) -> Path:
    """Render and write ``left_NN.png`` / ``right_NN.png`` (8-bit grey) and ``truth.json``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rs = render_checker_set(calib, spec, n_views, seed, settings, progress=progress)
    for name, li, ri in zip(rs.names, rs.left, rs.right, strict=True):
        cv2.imwrite(str(out / f"left_{name}.png"), li, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        cv2.imwrite(str(out / f"right_{name}.png"), ri, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    truth = {
        "description": "synthetic checkerboard stereo set rendered by app.sim.checkerboard_render",
        "board": asdict(rs.spec),
        "render": asdict(rs.settings),
        "seed": seed,
        "calibration": calib.to_dict(),
        "views": [
            {
                "name": n,
                "left": f"left_{n}.png",
                "right": f"right_{n}.png",
                "pose_left_cam": p.to_dict(),
            }
            for n, p in zip(rs.names, rs.poses, strict=True)
        ],
    }
    (out / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return out


def zero_skew(calib: StereoCalibration) -> StereoCalibration:
    """Copy of ``calib`` with γ = 0 in both cameras (OpenCV's model cannot represent skew)."""
    d = calib.to_dict()
    d["left"]["K"][0][1] = 0.0
    d["right"]["K"][0][1] = 0.0
    return StereoCalibration.from_dict(d)


def load_truth(path: str | Path) -> tuple[StereoCalibration, CheckerboardSpec, list[BoardPose]]:
    """Read a ``truth.json`` written by :func:`write_sample_set`."""
    data = json.loads(Path(path).read_text())
    calib = StereoCalibration.from_dict(data["calibration"])
    spec = CheckerboardSpec(**data["board"])
    poses = [BoardPose.from_dict(v["pose_left_cam"]) for v in data["views"]]
    return calib, spec, poses


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description="Regenerate the synthetic checkerboard sample set."
    )
    parser.add_argument("out_dir", nargs="?", default="sample_data/checkerboard")
    parser.add_argument("--calibration", default="sample_data/calibration.json")
    parser.add_argument("--views", type=int, default=14)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument(
        "--keep-skew",
        action="store_true",
        help="render with the calibration's skew γ (default: γ set to 0, see docs/calibration.md)",
    )
    args = parser.parse_args(argv)
    calib = StereoCalibration.load(args.calibration)
    if not args.keep_skew:
        calib = zero_skew(calib)
    out = write_sample_set(args.out_dir, calib, n_views=args.views, seed=args.seed)
    print(f"wrote {args.views} stereo pairs to {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
