"""The physically based optics test set (Mitsuba renders of a metal drogue) and its sensor model.

The set lives in ``tests/data/optics/<set>/`` (``dev``, ``holdout``): a ``manifest.json`` with
every case's truth and render settings, and per case a pair of *ideal* images: noise-free,
already through the calibration's distortion and skew (``sample_data/calibration.json``) and
the optical blur, in linear sensor DN, stored as 16-bit PNG of ``round(DN · dn_scale)``.
Mono images are the luminance 0.299 R + 0.587 G + 0.114 B of linear RGB; ``bayer_rggb``
images are an RGGB mosaic (R at even row/even column, G at even/odd and odd/even, B at
odd/odd). The renderer is ``benchmarks/optics/render_optics_set.py``.

:func:`sensor_pair` turns an ideal pair into camera output: gain → shot noise (Poisson on a
full well of ``FULL_WELL_E`` electrons at 255 DN) → read noise → black level → rounding and
clipping to uint8 (saturation) → for ``bayer_rggb`` demosaicing to BGR with OpenCV.

Truth frame: the left camera frame (x right, y down, z forward, mm). Row k of
``led_xyz_mm`` is LED id k+1 (:mod:`app.geometry.led_ids`); ``normal`` points from the
drogue towards the cameras.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

FULL_WELL_E = 8000.0  # electrons at 255 DN
READ_NOISE_DN = 1.5
BLACK_LEVEL_DN = 4.0
# OpenCV names Bayer patterns by the second row's (1, 1)-(1, 2) pixels; its RGGB alias is
# the same code as COLOR_BayerBG2BGR (checked in tests/sim/test_optics_set.py with red, green and
# blue patches: COLOR_BayerRG2BGR would swap red and blue for this mosaic)
BAYER_RGGB_TO_BGR = getattr(cv2, "COLOR_BayerRGGB2BGR", cv2.COLOR_BayerBG2BGR)

Sensor = Literal["mono", "bayer_rggb"]


# the set's conditions, one per case (the renderer's plan and the tests share them)
CONDITIONS: tuple[str, ...] = (
    "night_mono",
    "night_bayer",
    "sun_mono",
    "sun_bayer",
    "glint_mono",
    "glint_bayer",
    "occluded2",
    "defocus",
    "motion",
)


@dataclass(frozen=True)
class BlurInfo:
    """Optical blur applied to the linear ideal images (after the distortion remap)."""

    psf_sigma_px: float  # lens PSF (Gaussian), every case
    defocus_radius_px: float | None = None  # disc blur (``defocus`` cases)
    motion_length_px: float | None = None  # linear motion kernel, centred (``motion``)
    motion_angle_deg: float | None = None  # image angle, 0 = +x, 90 = +y


@dataclass(frozen=True, eq=False)
class OpticsCase:
    """One stereo pair of the optics set with its truth (mm, left camera frame)."""

    name: str
    condition: str  # night_mono, night_bayer, sun_mono, ..., occluded2, defocus, motion
    sensor: Sensor
    ring_config: str  # "lab" or "flight"
    ring_radius_mm: float
    led_count: int
    led_diameter_mm: float
    phase_deg: float
    led_xyz_mm: NDArray[np.float64]  # (N, 3); row k = LED id k+1
    led_visible: tuple[bool, ...]  # False: the LED's dome is hidden in either image
    center_mm: NDArray[np.float64]  # (3,)
    normal: NDArray[np.float64]  # (3,) unit, drogue → cameras
    range_mm: float  # |center_mm|
    roll_deg: float
    night: bool
    blur: BlurInfo
    left_path: Path
    right_path: Path
    dn_scale: float  # stored = round(DN · dn_scale)
    seed: int  # the render's seed (a default for the sensor noise)
    led_px: dict[str, NDArray[np.float64]] = field(default_factory=dict)  # calibration projection
    led_peak_dn: dict[str, tuple[float, ...]] = field(default_factory=dict)  # ideal peak per LED
    extra: dict[str, Any] = field(default_factory=dict)  # the manifest's full record

    @property
    def led_ids(self) -> NDArray[np.int64]:
        return np.arange(1, self.led_count + 1)


def _case_from_record(rec: dict[str, Any], directory: Path, dn_scale: float) -> OpticsCase:
    truth = rec["truth"]
    b = rec["blur"]
    return OpticsCase(
        name=str(rec["name"]),
        condition=str(rec["condition"]),
        sensor="bayer_rggb" if rec["sensor"] == "bayer_rggb" else "mono",
        ring_config=str(rec["ring_config"]),
        ring_radius_mm=float(rec["ring_radius_mm"]),
        led_count=int(rec["led_count"]),
        led_diameter_mm=float(rec["led_diameter_mm"]),
        phase_deg=float(rec["phase_deg"]),
        led_xyz_mm=np.asarray(truth["led_xyz_mm"], dtype=np.float64),
        led_visible=tuple(bool(v) for v in truth["led_visible"]),
        center_mm=np.asarray(truth["center_mm"], dtype=np.float64),
        normal=np.asarray(truth["normal"], dtype=np.float64),
        range_mm=float(truth["range_mm"]),
        roll_deg=float(truth["roll_deg"]),
        night=bool(rec["night"]),
        blur=BlurInfo(
            psf_sigma_px=float(b["psf_sigma_px"]),
            defocus_radius_px=b.get("defocus_radius_px"),
            motion_length_px=b.get("motion_length_px"),
            motion_angle_deg=b.get("motion_angle_deg"),
        ),
        left_path=directory / rec["images"]["left"],
        right_path=directory / rec["images"]["right"],
        dn_scale=dn_scale,
        seed=int(rec["seed"]),
        led_px={k: np.asarray(v, dtype=np.float64) for k, v in truth["led_px"].items()},
        led_peak_dn={k: tuple(float(x) for x in v) for k, v in rec["stats"]["led_peak_dn"].items()},
        extra=rec,
    )


def load_manifest(directory: str | Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((Path(directory) / "manifest.json").read_text())
    return data


def load_optics_set(directory: str | Path) -> list[OpticsCase]:
    """The cases of one rendered set (``tests/data/optics/dev`` or ``.../holdout``)."""
    d = Path(directory)
    man = load_manifest(d)
    scale = float(man["dn_scale"])
    return [_case_from_record(rec, d, scale) for rec in man["cases"]]


def read_ideal(path: str | Path, dn_scale: float) -> NDArray[np.float64]:
    """A stored ideal image in linear DN (float64; mono luminance or RGGB mosaic)."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.dtype != np.uint16 or img.ndim != 2:
        raise ValueError(f"{path}: not a 16-bit single-channel PNG")
    return np.asarray(img, dtype=np.float64) / dn_scale


def ideal_pair(case: OpticsCase) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The case's ideal images (linear DN, before the sensor model)."""
    return read_ideal(case.left_path, case.dn_scale), read_ideal(case.right_path, case.dn_scale)


def apply_sensor(
    ideal_dn: NDArray[np.float64],
    sensor: Sensor,
    rng: np.random.Generator,
    gain: float = 1.0,
    full_well_e: float = FULL_WELL_E,
    read_noise_dn: float = READ_NOISE_DN,
    black_level_dn: float = BLACK_LEVEL_DN,
) -> NDArray[np.uint8]:
    """One image through the sensor model: H×W uint8 (mono) or H×W×3 BGR uint8 (bayer)."""
    if not (np.isfinite(gain) and gain >= 0):
        raise ValueError(f"gain must be a finite number >= 0, got {gain}")
    e_per_dn = full_well_e / 255.0
    electrons = rng.poisson(np.clip(ideal_dn * gain, 0.0, None) * e_per_dn)
    dn = electrons / e_per_dn + rng.normal(0.0, read_noise_dn, size=ideal_dn.shape)
    dn += black_level_dn
    raw = np.clip(np.round(dn), 0, 255).astype(np.uint8)
    if sensor == "mono":
        return raw
    if sensor == "bayer_rggb":
        return np.asarray(cv2.cvtColor(raw, BAYER_RGGB_TO_BGR), dtype=np.uint8)
    raise ValueError(f"unknown sensor {sensor!r}")


def sensor_pair(
    case: OpticsCase, seed: int, gain: float = 1.0
) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """The case's (left, right) camera images with sensor noise drawn from ``seed``
    (deterministic per seed; the two images get independent noise)."""
    left, right = ideal_pair(case)
    rng = np.random.default_rng(seed)
    return (
        apply_sensor(left, case.sensor, rng, gain),
        apply_sensor(right, case.sensor, rng, gain),
    )
