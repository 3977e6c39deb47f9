"""The receiver on JSBSim's nonlinear 6-DoF flight dynamics model (the default plant).

Airframe: the A-4 Skyhawk of JSBSim's shipped aircraft set (``A4``, a real probe-and-drogue
receiver), **nominal as shipped** — its FCS included (pitch/roll trim sums, the ±0.35 rudder
command clip, the yaw damper active above 31 kt) — gear up, at a drogue refuelling condition
(default 15 000 ft, 230 KCAS). Nothing in the aircraft file is changed: the controller commands
``fcs/throttle-cmd-norm``, ``fcs/aileron-cmd-norm``, ``fcs/elevator-cmd-norm`` and
``fcs/rudder-cmd-norm`` (normalised, −1…1; throttle 0…1) on top of FGTrim's trim (the pitch trim
stays in ``fcs/pitch-trim-cmd-norm``), and the design model is linearised through the same FCS.

Geometry of the flight: JSBSim flies a rotating WGS-84 Earth; the receiver flies north along
the meridian at the equator, where the Earth's rotation vector is parallel to the velocity
(no Coriolis force on the flight path; the centrifugal term is part of the trim). The tanker
frame is north-east-down moving north at the trim ground speed, its origin the receiver's CG at
the start (plus the start offset the simulation asks for): ``x = (φ_geod − φ₀)(M + h) −
V₀ t``, ``y = (λ − λ₀)(N + h) cos φ``, ``z = −(h − h₀)`` with WGS-84's meridian and prime
vertical radii at the equator (M = a(1 − e²), N = a).

Air: JSBSim's own turbulence is off (``atmosphere/turb-type`` 0); the simulation's frozen gust
field and the tanker's wake are written into ``atmosphere/gust-north-fps`` / ``-east-`` /
``-down-`` before every tick, so the drogue and the receiver see one field.

Each tick JSBSim integrates ``substeps`` steps of ``1 / (tick_hz · substeps)`` s, at least
``min_fdm_hz`` (120 Hz).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from app.control.envelope import FlightData
from app.control.linear_model import ActuatorLimits, LinearModel
from app.geometry.rotations import euler_to_matrix
from app.sim.plant import TrimPoint
from app.types import FloatArray

FT_M = 0.3048  # m per ft
SLUG_FT3_KG_M3 = 515.378818  # kg/m³ per slug/ft³
WGS84_A_M = 6378137.0
WGS84_E2 = 6.69437999014e-3
MERIDIAN_RADIUS_M = WGS84_A_M * (1.0 - WGS84_E2)  # at the equator
PRIME_RADIUS_M = WGS84_A_M  # at the equator
COMMANDS = (
    "fcs/throttle-cmd-norm",
    "fcs/aileron-cmd-norm",
    "fcs/elevator-cmd-norm",
    "fcs/rudder-cmd-norm",
)
INPUT_NAMES = ("throttle", "aileron", "elevator", "rudder")  # normalised commands
AIRFRAMES = {"A4": "A-4 Skyhawk (JSBSim A4, as shipped)"}
# servo rate limits (normalised travel per second): JSBSim's A-4 has none (its surfaces follow
# the command at once); ours, an estimate for hydraulic surface actuators (≈ 60 °/s on the
# 0.35 rad surfaces). The throttle is commanded no faster than the J52 spools: its thrust
# rises at ≈ 2 200–3 400 lbf/s on this FDM whatever the step (+0.05…+0.2 from trim), and one
# unit of throttle is ≈ 6 600 lbf, so ≈ 0.35 throttle/s (docs/control.md, "Engine"); the
# controller's memory of the command (app.control.lqr) then knows what the engine can give
RATE_NORM_PER_S = (0.35, 3.0, 3.0, 3.0)
SERVO_LAG_S = 0.03  # the design's servo lag on the surfaces (the lag-aware LQR)


class JsbsimUnavailable(RuntimeError):
    """JSBSim (the ``jsbsim`` package) is not installed or cannot load the aircraft."""


@dataclass(frozen=True)
class JsbsimCondition:
    """Airframe and flight condition of the JSBSim receiver."""

    aircraft: str = "A4"
    altitude_ft: float = 15000.0
    kcas: float = 230.0
    fuel_lbs: float | None = None  # None: the aircraft file's load; else the tank contents
    min_fdm_hz: float = 120.0

    def validate(self) -> None:
        if self.aircraft not in AIRFRAMES:
            raise ValueError(f"aircraft must be one of {sorted(AIRFRAMES)}, got {self.aircraft!r}")
        if not (1000.0 <= self.altitude_ft <= 40000.0):
            raise ValueError(f"altitude_ft must be in 1000–40000, got {self.altitude_ft!r}")
        if not (150.0 <= self.kcas <= 450.0):
            raise ValueError(f"kcas must be in 150–450, got {self.kcas!r}")


def substeps_for(tick_hz: float, min_fdm_hz: float = 120.0) -> int:
    """JSBSim steps per tick so that the FDM runs at ≥ ``min_fdm_hz``."""
    return max(1, math.ceil(min_fdm_hz / tick_hz - 1e-9))


SETTLE_STEPS = 30  # JSBSim steps flown at trim after FGTrim before the FDM is used


def _load(cond: JsbsimCondition, dt_fdm: float, settle: bool = True):  # type: ignore[no-untyped-def]
    """A fresh FDM of the airframe, trimmed (FGTrim full) at the condition, gear up; with
    ``settle`` flown for ``SETTLE_STEPS`` at the trim commands (right after FGTrim the
    turbine answers a throttle change at once; after a few steps it spools at its rate)."""
    try:
        import jsbsim
    except ImportError as exc:  # pragma: no cover - a core dependency
        raise JsbsimUnavailable("the jsbsim package is not installed") from exc
    jsbsim.FGJSBBase().debug_lvl = 0  # no start-up banner on stdout (simulate --json)
    fdm = jsbsim.FGFDMExec(None)
    fdm.set_debug_level(0)
    if not fdm.load_model(cond.aircraft):
        raise JsbsimUnavailable(f"JSBSim cannot load the aircraft {cond.aircraft!r}")
    fdm.set_dt(dt_fdm)
    # order matters: position first, then altitude, then the calibrated airspeed
    fdm["ic/lat-geod-deg"] = 0.0
    fdm["ic/long-gc-deg"] = 0.0
    fdm["ic/psi-true-deg"] = 0.0
    fdm["ic/h-sl-ft"] = cond.altitude_ft
    fdm["ic/vc-kts"] = cond.kcas
    fdm["ic/gamma-deg"] = 0.0
    fdm["gear/gear-cmd-norm"] = 0.0
    fdm["atmosphere/turb-type"] = 0
    if cond.fuel_lbs is not None:
        fdm["propulsion/tank/contents-lbs"] = float(cond.fuel_lbs)
    fdm.run_ic()
    fdm["propulsion/set-running"] = -1
    try:
        fdm["simulation/do_simple_trim"] = 1  # FGTrim, full (longitudinal and lateral)
    except Exception as exc:  # JSBSim's TrimFailureError (not importable by name)
        raise JsbsimUnavailable(
            f"JSBSim cannot trim the {cond.aircraft} at {cond.altitude_ft:.0f} ft, "
            f"{cond.kcas:.0f} KCAS (fuel {cond.fuel_lbs} lb): {exc}"
        ) from None
    if settle:
        for _ in range(SETTLE_STEPS):
            fdm.run()
    return fdm


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


class JsbsimPlant:
    """JSBSim's A-4 flown in the design model's coordinates (see :mod:`app.sim.plant`).

    ``reference``: the design model whose trim the state and the inputs are measured from
    (default: this plant's own linearisation). A plant at another weight than the design's
    (fuel state, :mod:`app.sim.imperfections`) trims itself at its own α and throttle; in the
    design's coordinates that is a constant offset the integrators take up."""

    name = "jsbsim"

    def __init__(
        self, condition: JsbsimCondition, tick_hz: float, reference: LinearModel | None = None
    ) -> None:
        condition.validate()
        self.condition = condition
        self.airframe = AIRFRAMES[condition.aircraft]
        self.substeps = substeps_for(tick_hz, condition.min_fdm_hz)
        self.dt = 1.0 / tick_hz
        self.dt_fdm = self.dt / self.substeps
        self.t = 0.0
        self.fdm = _load(condition, self.dt_fdm)
        f = self.fdm
        self.u_trim = np.array([f[c] for c in COMMANDS], dtype=np.float64)
        self.pitch_trim = float(f["fcs/pitch-trim-cmd-norm"])
        self.trim = TrimPoint(
            altitude_ft=float(f["position/h-sl-ft"]),
            kcas=float(f["velocities/vc-kts"]),
            tas_mps=float(f["velocities/vt-fps"]) * FT_M,
            alpha_deg=float(f["aero/alpha-deg"]),
            theta_deg=float(f["attitude/theta-deg"]),
            throttle=float(self.u_trim[0]),
            weight_lbs=float(f["inertia/weight-lbs"]),
            air_density_kgm3=float(f["atmosphere/rho-slugs_ft3"]) * SLUG_FT3_KG_M3,
            mach=float(f["velocities/mach"]),
        )
        self.ground_speed_mps = float(f["velocities/v-north-fps"]) * FT_M
        self._abs0 = self._absolute()
        self.x_trim = np.zeros(12)
        self.x_trim[0:3] = self._abs0[0:3]
        self.x_trim[6:9] = self._abs0[6:9]
        self._reference = reference
        ref = reference
        self.ref_x_trim = self.x_trim.copy() if ref is None else np.asarray(ref.x_trim, float)
        self.ref_u_trim = self.u_trim.copy() if ref is None else np.asarray(ref.u_trim, float)
        self.ref_speed_mps = self.ground_speed_mps if ref is None else float(ref.airspeed_mps)
        self.position_offset = np.zeros(12)
        self.x = self.state()

    @cached_property
    def engine_lag_s(self) -> float:
        return self._measure_engine_lag()

    @cached_property
    def model(self) -> LinearModel:
        """This plant's own linearisation about its trim (the design model)."""
        return self._linearise()

    # ------------------------------------------------------------------ state
    def _absolute(self) -> FloatArray:
        """(u, v, w m/s, p, q, r rad/s, φ, θ, ψ rad, latitude, longitude rad, altitude m)."""
        f = self.fdm
        return np.array(
            [
                f["velocities/u-fps"] * FT_M,
                f["velocities/v-fps"] * FT_M,
                f["velocities/w-fps"] * FT_M,
                f["velocities/p-rad_sec"],
                f["velocities/q-rad_sec"],
                f["velocities/r-rad_sec"],
                f["attitude/phi-rad"],
                f["attitude/theta-rad"],
                f["attitude/psi-rad"],
                f["position/lat-geod-rad"],
                f["position/long-gc-rad"],
                f["position/h-sl-ft"] * FT_M,
            ],
            dtype=np.float64,
        )

    def state(self) -> FloatArray:
        """The perturbation state from the reference trim (:mod:`app.sim.plant` coordinates)."""
        a, a0, r = self._absolute(), self._abs0, self.ref_x_trim
        x = np.empty(12)
        x[0:6] = a[0:6] - r[0:6]
        x[6] = _wrap(a[6] - r[6])
        x[7] = _wrap(a[7] - r[7])
        x[8] = _wrap(a[8] - r[8])
        h = a[11]
        x[9] = (a[9] - a0[9]) * (MERIDIAN_RADIUS_M + h) - self.ref_speed_mps * self.t
        x[10] = (a[10] - a0[10]) * (PRIME_RADIUS_M + h) * math.cos(a[9])
        x[11] = -(h - a0[11])
        return x + self.position_offset

    def trim_residual(self) -> FloatArray:
        """The body-axis accelerations now (u̇, v̇, ẇ m/s²; ṗ, q̇, ṙ rad/s²): ≈ 0 at the trim."""
        f = self.fdm
        return np.array(
            [
                f["accelerations/udot-ft_sec2"] * FT_M,
                f["accelerations/vdot-ft_sec2"] * FT_M,
                f["accelerations/wdot-ft_sec2"] * FT_M,
                f["accelerations/pdot-rad_sec2"],
                f["accelerations/qdot-rad_sec2"],
                f["accelerations/rdot-rad_sec2"],
            ],
            dtype=np.float64,
        )

    def set_speedbrake(self, norm: float) -> None:
        """The A-4's speed brakes (``fcs/speedbrake-cmd-norm``, 0…1; the aircraft file moves
        them over 1 s and adds ΔC_D 0.021 when out)."""
        self.fdm["fcs/speedbrake-cmd-norm"] = float(min(max(norm, 0.0), 1.0))

    def flight_data(self) -> FlightData:
        """The run-time assurance's view of the flown aircraft, read from JSBSim's own
        properties (α, normal load factor at the CG, bank, pitch, KCAS, altitude)."""
        f = self.fdm
        return FlightData(
            alpha_deg=float(f["aero/alpha-deg"]),
            load_factor_g=float(f["accelerations/Nz"]),
            bank_deg=float(f["attitude/phi-deg"]),
            pitch_deg=float(f["attitude/theta-deg"]),
            kcas=float(f["velocities/vc-kts"]),
            altitude_m=float(f["position/h-sl-ft"]) * FT_M,
        )

    @property
    def fdm_time_s(self) -> float:
        """JSBSim's own clock (s) since this FDM was trimmed."""
        return float(self.fdm["simulation/sim-time-sec"])

    def reset(self, x0: FloatArray) -> FloatArray:
        """Back at this plant's trim (a fresh, re-trimmed FDM when it has flown), positioned
        at ``x0``'s position; other perturbations are refused (the state returned carries
        the offset between this plant's trim and the reference's, if any)."""
        x0 = np.asarray(x0, dtype=np.float64)
        if np.any(x0[:9] != 0.0):
            raise ValueError("the JSBSim plant starts at its trim: only a position offset")
        if self.t > 0.0:
            self.fdm = _load(self.condition, self.dt_fdm)
            self._abs0 = self._absolute()
        self.t = 0.0
        self.position_offset = np.zeros(12)
        self.position_offset[9:12] = x0[9:12]
        self.x = self.state()
        return self.x

    def step(self, u_dev: FloatArray, air_mps: FloatArray) -> FloatArray:
        f = self.fdm
        u = self.ref_u_trim + np.asarray(u_dev, dtype=np.float64)
        for name, value in zip(COMMANDS, u.tolist(), strict=True):
            f[name] = value
        air = np.asarray(air_mps, dtype=np.float64) / FT_M
        f["atmosphere/gust-north-fps"] = float(air[0])
        f["atmosphere/gust-east-fps"] = float(air[1])
        f["atmosphere/gust-down-fps"] = float(air[2])
        for _ in range(self.substeps):
            f.run()
        self.t += self.dt
        self.x = self.state()
        return self.x

    # ------------------------------------------------------------------ design model
    def _measure_engine_lag(self) -> float:
        """The engine's spool-up time constant (s): the 63 % time of the thrust after a +0.05
        throttle step at the trim, measured on its own trimmed FDM (JSBSim's turbine
        seeks N2 at a limited rate; a rigid-body linearisation has no engine state)."""
        fdm = _load(self.condition, self.dt_fdm)
        t0 = float(fdm["propulsion/engine/thrust-lbs"])
        fdm["fcs/throttle-cmd-norm"] = float(self.u_trim[0]) + 0.05
        thrust = []
        for _ in range(int(round(3.0 / self.dt_fdm))):
            fdm.run()
            thrust.append(float(fdm["propulsion/engine/thrust-lbs"]) - t0)
        rise = np.asarray(thrust)
        final = rise[-1]
        if not final > 0:
            return 0.0
        k = int(np.argmax(rise >= 0.632 * final))
        return (k + 1) * self.dt_fdm

    def _linearise(self) -> LinearModel:
        """JSBSim's FGLinearization at the trim (its states Vt, α, θ, q, β, φ, p, ψ, r, lat,
        lon, alt; inputs the four normalised commands, through the FCS), converted to the
        design model's coordinates; the position rows replaced by the kinematics in metres;
        the gust input from the velocity columns (the aerodynamic forces depend on the air-
        relative velocity v_B − R_TBᵀ g, and at trim — zero rates — nothing else in those
        rows depends on v_B)."""
        import jsbsim

        # on its own FDM, right after FGTrim: FGLinearization leaves the FDM it ran on frozen
        lin = jsbsim.FGLinearization(_load(self.condition, self.dt_fdm, settle=False))
        names = tuple(lin.x_names)
        want = ("Vt", "Alpha", "Theta", "Q", "Beta", "Phi", "P", "Psi", "R")
        if names[:9] != want or tuple(lin.u_names) != ("ThtlCmd", "DaCmd", "DeCmd", "DrCmd"):
            raise JsbsimUnavailable(f"unexpected FGLinearization layout {names}")
        a_f = np.asarray(lin.system_matrix, dtype=np.float64)[:9, :9]
        b_f = np.asarray(lin.input_matrix, dtype=np.float64)[:9, :]
        x0 = np.asarray(lin.x0, dtype=np.float64)
        vt, alpha, beta = x0[0] * FT_M, x0[1], x0[4]
        # ξ = (Vt, α, θ, q, β, φ, p, ψ, r) -> s = (u, v, w, p, q, r, φ, θ, ψ): s = M ξ
        m = np.zeros((9, 9))
        ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
        m[0, 0], m[0, 1], m[0, 4] = FT_M * ca * cb, -vt * sa * cb, -vt * ca * sb
        m[1, 0], m[1, 4] = FT_M * sb, vt * cb
        m[2, 0], m[2, 1], m[2, 4] = FT_M * sa * cb, vt * ca * cb, -vt * sa * sb
        m[3, 6] = m[4, 3] = m[5, 8] = 1.0
        m[6, 5] = m[7, 2] = m[8, 7] = 1.0
        # Vt is in ft/s in FGLinearization: rows of Vṫ scale by FT_M through M
        a9 = m @ a_f @ np.linalg.inv(m)
        b9 = m @ b_f
        a = np.zeros((12, 12))
        b = np.zeros((12, 4))
        a[:9, :9] = a9
        b[:9, :] = b9
        # kinematics of the position in the tanker frame: ṗ = R_TB(φ, θ, ψ) v_B − (V₀, 0, 0)
        x_abs = self.x_trim.copy()

        def pos_dot(s: FloatArray) -> FloatArray:
            return np.asarray(euler_to_matrix(s[6], s[7], s[8]) @ s[0:3])

        for j in (0, 1, 2, 6, 7, 8):
            e = np.zeros(12)
            e[j] = 1e-6
            a[9:12, j] = (pos_dot(x_abs + e) - pos_dot(x_abs - e)) / 2e-6
        r0 = euler_to_matrix(x_abs[6], x_abs[7], x_abs[8])
        e_g = np.zeros((12, 3))
        e_g[0:6, :] = -a[0:6, 0:3] @ r0.T
        limits = ActuatorLimits(
            lower=(0.0, -1.0, -1.0 - self.pitch_trim, -0.35),
            upper=(1.0, 1.0, 1.0 - self.pitch_trim, 0.35),
            rate=RATE_NORM_PER_S,
        )
        return LinearModel(
            a=a,
            b=b,
            e=e_g,
            x_trim=self.x_trim.copy(),
            u_trim=self.u_trim.copy(),
            input_names=INPUT_NAMES,
            limits=limits,
            input_lag_s=(self.engine_lag_s, SERVO_LAG_S, SERVO_LAG_S, SERVO_LAG_S),
            airspeed_mps=self.ground_speed_mps,
        )

    def fgl_eigenvalues(self) -> NDArray[np.complex128]:
        """Eigenvalues of JSBSim's own linearisation (its 9 non-positional states), for the
        tests' comparison with :attr:`model`."""
        import jsbsim

        fdm = _load(self.condition, self.dt_fdm, settle=False)
        a_f = np.asarray(jsbsim.FGLinearization(fdm).system_matrix, dtype=np.float64)[:9, :9]
        return np.asarray(np.linalg.eigvals(a_f))
