"""Flight imperfections of the docking loop: seeded, documented, off by default.

:class:`Imperfections` holds the parameters (presets ``none`` / ``standard`` / ``harsh``,
:data:`PRESETS`); :func:`draw` turns them into one run's concrete values
(:class:`ImperfectionDraw`) from the run's seed, on random streams of their own, so that the
``none`` preset leaves every other random draw — and therefore every result — unchanged.
Sources and rationale of each value: ``docs/models.md`` ("Imperfections").

* **Camera latency** ``latency_s``: exposure → result. The frame is rendered at the exposure
  instant; its drogue measurement reaches the filter ``latency_s`` later, stamped with the
  exposure time; :meth:`app.control.drogue_filter.DrogueFilter.update_delayed` fuses it at
  that time and propagates it to now.
* **Dropped / duplicated frames**: a two-state (Gilbert–Elliott) channel — a burst of drops
  starts with probability ``drop_prob`` per frame and lasts a geometric number of frames of
  mean ``drop_burst_mean``; independently a delivered frame is, with ``duplicate_prob``, the
  previous frame again (same image, so the same measurement) stamped as new.
* **Plant ≠ design**: the simulated receiver's aerodynamic derivatives are each scaled by
  ``1 + U(−aero_frac, aero_frac)``, mass and inertias by ``1 + U(−mass_frac, mass_frac)``;
  it is trimmed and linearised on its own (the controller keeps the design model, gains and
  trim); the plant's actuators have a first-order lag ``actuator_lag_s`` (design: none) and
  rate limits × ``actuator_rate_scale``.
* **Calibration error**: the tracker uses a calibration perturbed from the one that renders:
  a rotation of the right camera of ``calib_rot_deg`` about a random axis, focal lengths ×
  ``1 + N(0, calib_focal_frac)``, principal points + ``N(0, calib_pp_px)`` (each camera).
* **INS errors**: per-run constant biases (rates ``ins_gyro_bias_rad_s``, attitude
  ``ins_att_bias_rad``, position ``ins_pos_bias_m``, 1σ each axis) plus a position random walk
  (``ins_pos_walk_m_sqrt_s``, m/√s), on top of the white noise.
* **Hose and drogue**: the flown hose's length, linear mass and cross-flow drag and the
  drogue's mass and drag coefficient are each scaled by ``1 + U(−hose_frac, hose_frac)`` (the
  guidance keeps the nominal hose type's model and identifies the swing online:
  :mod:`app.control.swing_identifier`).
* **Tanker wake and bow wave**: the bow-wave force on the drogue is scaled by
  ``U(bow_scale)``; the receiver flies through a steady tanker downwash of strength
  ``U(0, wake_downwash_mps)`` (m/s, down) that grows as it closes on the tanker
  (:func:`wake_downwash`), plus a lateral gradient (sidewash) of ``±wake_sidewash_per_m``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import numpy as np

from app.geometry.calibration import CameraIntrinsics, StereoCalibration
from app.types import FloatArray

STREAM = 0x696D70  # second seed word of the imperfections' random streams ("imp")


@dataclass(frozen=True)
class Imperfections:
    """Imperfection parameters (units in the names; fractions are relative, 1σ or ± bounds)."""

    name: str = "none"
    latency_s: float = 0.0
    drop_prob: float = 0.0
    drop_burst_mean: float = 1.0
    duplicate_prob: float = 0.0
    aero_frac: float = 0.0  # ± uniform on each aerodynamic derivative
    mass_frac: float = 0.0  # ± uniform on mass and each inertia
    actuator_lag_s: float = 0.0
    actuator_rate_scale: float = 1.0
    calib_rot_deg: float = 0.0
    calib_focal_frac: float = 0.0
    calib_pp_px: float = 0.0
    ins_gyro_bias_rad_s: float = 0.0
    ins_att_bias_rad: float = 0.0
    ins_pos_bias_m: float = 0.0
    ins_pos_walk_m_sqrt_s: float = 0.0
    bow_scale: tuple[float, float] = (1.0, 1.0)
    wake_downwash_mps: float = 0.0
    wake_sidewash_per_m: float = 0.0
    hose_frac: float = 0.0  # ± uniform on hose length, mass, drag and drogue mass, drag

    def validate(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "name":
                continue
            vals = v if isinstance(v, tuple) else (v,)
            for x in vals:
                if not (isinstance(x, int | float) and math.isfinite(x) and x >= 0):
                    raise ValueError(f"imperfection {f.name} must be finite and >= 0, got {v!r}")
        if not (0 <= self.drop_prob < 1 and 0 <= self.duplicate_prob < 1):
            raise ValueError("drop_prob and duplicate_prob must be in [0, 1)")
        if self.drop_burst_mean < 1:
            raise ValueError("drop_burst_mean must be >= 1 frame")
        if self.aero_frac >= 1 or self.mass_frac >= 1 or self.hose_frac >= 1:
            raise ValueError("aero_frac, mass_frac and hose_frac must be < 1")
        if self.actuator_rate_scale <= 0:
            raise ValueError("actuator_rate_scale must be > 0")
        if self.bow_scale[0] > self.bow_scale[1]:
            raise ValueError("bow_scale must be (low, high) with low <= high")

    @property
    def active(self) -> bool:
        return self != replace(NONE, name=self.name)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["bow_scale"] = list(self.bow_scale)
        return d


NONE = Imperfections()
STANDARD = Imperfections(
    name="standard",
    latency_s=0.04,
    drop_prob=0.03,
    drop_burst_mean=2.0,
    duplicate_prob=0.02,
    aero_frac=0.2,
    mass_frac=0.1,
    actuator_lag_s=0.03,
    actuator_rate_scale=0.8,
    calib_rot_deg=0.1,
    calib_focal_frac=0.003,
    calib_pp_px=0.5,
    ins_gyro_bias_rad_s=0.002,
    ins_att_bias_rad=0.0017,  # 0.1°
    ins_pos_bias_m=0.05,
    ins_pos_walk_m_sqrt_s=0.005,
    bow_scale=(0.5, 1.5),
    wake_downwash_mps=1.0,
    wake_sidewash_per_m=0.05,
    hose_frac=0.3,
)
HARSH = Imperfections(
    name="harsh",
    latency_s=0.08,
    drop_prob=0.08,
    drop_burst_mean=4.0,
    duplicate_prob=0.05,
    aero_frac=0.3,
    mass_frac=0.15,
    actuator_lag_s=0.06,
    actuator_rate_scale=0.6,
    calib_rot_deg=0.15,
    calib_focal_frac=0.005,
    calib_pp_px=0.75,
    ins_gyro_bias_rad_s=0.005,
    ins_att_bias_rad=0.0052,  # 0.3°
    ins_pos_bias_m=0.15,
    ins_pos_walk_m_sqrt_s=0.015,
    bow_scale=(0.5, 2.0),
    wake_downwash_mps=2.0,
    wake_sidewash_per_m=0.1,
    hose_frac=0.3,
)
PRESETS: dict[str, Imperfections] = {"none": NONE, "standard": STANDARD, "harsh": HARSH}


def resolve(value: str | Imperfections) -> Imperfections:
    """A preset name or an :class:`Imperfections` → validated :class:`Imperfections`."""
    if isinstance(value, Imperfections):
        value.validate()
        return value
    if value not in PRESETS:
        raise ValueError(f"imperfections must be one of {tuple(PRESETS)}, got {value!r}")
    return PRESETS[value]


# ------------------------------------------------------------------------------ one run
# the hose and drogue quantities ``hose_frac`` disperses (factors in ImperfectionDraw.hose_scale)
HOSE_FACTORS = ("hose_length", "hose_mass", "hose_drag", "drogue_mass", "drogue_drag")


@dataclass
class ImperfectionDraw:
    """One run's concrete imperfections (drawn from the run's seed)."""

    aero_scale: dict[str, float] = field(default_factory=dict)  # derivative → factor
    mass_scale: float = 1.0
    inertia_scale: tuple[float, float, float, float] = (1.0, 1.0, 1.0, 1.0)  # Jx Jy Jz Jxz
    ins_bias: FloatArray = field(default_factory=lambda: np.zeros(9))  # p q r φ θ ψ x y z
    bow_scale: float = 1.0
    wake_downwash_mps: float = 0.0
    wake_sidewash_per_m: float = 0.0
    calib_rot_axis: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    calib_focal: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # δfx δfy L, R (frac)
    calib_pp_px: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # δu0 δv0 L, R
    hose_scale: dict[str, float] = field(default_factory=lambda: dict.fromkeys(HOSE_FACTORS, 1.0))

    def to_dict(self) -> dict[str, Any]:
        return {
            "aero_scale": dict(self.aero_scale),
            "mass_scale": self.mass_scale,
            "inertia_scale": list(self.inertia_scale),
            "ins_bias": self.ins_bias.tolist(),
            "bow_scale": self.bow_scale,
            "wake_downwash_mps": self.wake_downwash_mps,
            "wake_sidewash_per_m": self.wake_sidewash_per_m,
            "hose_scale": dict(self.hose_scale),
        }


AERO_DERIVATIVES = (
    "c_l_alpha",
    "c_l_q",
    "c_l_de",
    "c_d_alpha",
    "c_d_de",
    "c_m_alpha",
    "c_m_q",
    "c_m_de",
    "c_y_beta",
    "c_y_da",
    "c_y_dr",
    "c_ell_beta",
    "c_ell_p",
    "c_ell_r",
    "c_ell_da",
    "c_ell_dr",
    "c_n_beta",
    "c_n_p",
    "c_n_r",
    "c_n_da",
    "c_n_dr",
)


def draw(imp: Imperfections, seed: int) -> ImperfectionDraw:
    """The run's values; the same for the same (preset, seed); own random stream."""
    rng = np.random.default_rng([int(seed), STREAM, 1])
    out = ImperfectionDraw()
    a, m = imp.aero_frac, imp.mass_frac
    out.aero_scale = {k: 1.0 + float(rng.uniform(-a, a)) for k in AERO_DERIVATIVES}
    out.mass_scale = 1.0 + float(rng.uniform(-m, m))
    out.inertia_scale = tuple(1.0 + float(v) for v in rng.uniform(-m, m, 4))  # type: ignore[assignment]
    sig = np.array(
        [imp.ins_gyro_bias_rad_s] * 3 + [imp.ins_att_bias_rad] * 3 + [imp.ins_pos_bias_m] * 3
    )
    out.ins_bias = rng.normal(0.0, 1.0, 9) * sig
    out.bow_scale = float(rng.uniform(*imp.bow_scale))
    out.wake_downwash_mps = float(rng.uniform(0.0, imp.wake_downwash_mps))
    out.wake_sidewash_per_m = float(rng.uniform(-1.0, 1.0) * imp.wake_sidewash_per_m)
    axis = rng.normal(size=3)
    out.calib_rot_axis = axis / np.linalg.norm(axis)
    out.calib_focal = tuple(float(v) for v in rng.normal(0.0, imp.calib_focal_frac, 4))  # type: ignore[assignment]
    out.calib_pp_px = tuple(float(v) for v in rng.normal(0.0, imp.calib_pp_px, 4))  # type: ignore[assignment]
    # the hose's own stream, so that adding it left every earlier draw unchanged
    hose_rng = np.random.default_rng([int(seed), STREAM, 2])
    h = imp.hose_frac
    out.hose_scale = {k: 1.0 + float(hose_rng.uniform(-h, h)) for k in HOSE_FACTORS}
    return out


def _rotation(axis: FloatArray, angle_rad: float) -> FloatArray:
    """Rodrigues: rotation by ``angle_rad`` about the unit ``axis``."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.asarray(np.eye(3) + math.sin(angle_rad) * k + (1 - math.cos(angle_rad)) * k @ k)


def perturbed_calibration(
    calib: StereoCalibration, imp: Imperfections, d: ImperfectionDraw
) -> StereoCalibration:
    """The calibration the navigation believes (the renderer keeps ``calib``)."""
    if imp.calib_rot_deg == 0 and imp.calib_focal_frac == 0 and imp.calib_pp_px == 0:
        return calib

    def cam(c: CameraIntrinsics, i: int) -> CameraIntrinsics:
        k = c.K.copy()
        k[0, 0] *= 1.0 + d.calib_focal[2 * i]
        k[1, 1] *= 1.0 + d.calib_focal[2 * i + 1]
        k[0, 2] += d.calib_pp_px[2 * i]
        k[1, 2] += d.calib_pp_px[2 * i + 1]
        return CameraIntrinsics(K=k, dist=c.dist.copy())

    rot = _rotation(d.calib_rot_axis, math.radians(imp.calib_rot_deg))
    return StereoCalibration(
        image_size=calib.image_size,
        left=cam(calib.left, 0),
        right=cam(calib.right, 1),
        R=rot @ calib.R,
        T=calib.T.copy(),
    )


# m: the tanker's wing semi-span order (a KC-135's is ≈ 20 m), where its tip vortices sit
SIDEWASH_SPAN_M = 20.0


def wake_downwash(d: ImperfectionDraw, cg_m: FloatArray) -> FloatArray:
    """Steady tanker-wake velocity (m/s, tanker axes) at the receiver's CG ``cg_m``.

    Downwash ``W·L²/(L² + x²)`` (L = 20 m: full strength close behind the tanker, half at
    20 m back) plus a sidewash ``k_y·y / (1 + (y/B)²)`` (``k_y`` m/s per m of lateral offset
    near the centreline, B = ``SIDEWASH_SPAN_M``): a placeholder for the tanker's wing-vortex
    field, with uncertain strength (module docstring). The sidewash peaks at ``k_y·B/2`` a
    semi-span out and dies away beyond the vortices; a sidewash growing without bound with
    the offset (the first placeholder) pushed a receiver drifting sideways in a break-away
    ever further out (≈ 10 m/s at 130 m).
    """
    x = float(cg_m[0])
    y = float(cg_m[1])
    w = d.wake_downwash_mps * 400.0 / (400.0 + x * x)
    side = d.wake_sidewash_per_m * y / (1.0 + (y / SIDEWASH_SPAN_M) ** 2)
    return np.array([0.0, side, w])


class FrameChannel:
    """Dropped (bursty) and duplicated camera frames; own random stream."""

    def __init__(self, imp: Imperfections, seed: int) -> None:
        self.imp = imp
        self.rng = np.random.default_rng([int(seed), STREAM, 2])
        self.in_burst = False
        self.dropped = 0
        self.duplicated = 0

    def next(self) -> str:
        """``"ok"``, ``"drop"`` or ``"duplicate"`` for the next frame."""
        imp = self.imp
        if imp.drop_prob == 0 and imp.duplicate_prob == 0:
            return "ok"
        u_drop, u_dup = self.rng.random(2)
        if self.in_burst:
            self.in_burst = bool(u_drop >= 1.0 / imp.drop_burst_mean)
        else:
            self.in_burst = bool(u_drop < imp.drop_prob)
        if self.in_burst:
            self.dropped += 1
            return "drop"
        if u_dup < imp.duplicate_prob:
            self.duplicated += 1
            return "duplicate"
        return "ok"


class InsErrors:
    """Bias + position random walk added to the own-state measurement (own random stream)."""

    def __init__(self, imp: Imperfections, d: ImperfectionDraw, seed: int, dt: float) -> None:
        self.bias = d.ins_bias.copy()
        self.walk = np.zeros(3)
        self.step_sigma = imp.ins_pos_walk_m_sqrt_s * math.sqrt(dt)
        self.rng = np.random.default_rng([int(seed), STREAM, 3])

    def error(self) -> FloatArray:
        """The error of this tick's measurement (p q r φ θ ψ x y z); advances the walk."""
        if self.step_sigma > 0:
            self.walk = self.walk + self.rng.normal(0.0, self.step_sigma, 3)
        e = self.bias.copy()
        e[6:] += self.walk
        return e
