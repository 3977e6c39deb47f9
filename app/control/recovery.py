"""The recovery law of the run-time assurance (and the break-away as the field flies it):
wings level, power back, pitch a little below trim — the receiver drops aft and below, away
from the hose, and stops chasing the drogue (../shared/notes/gnc.md, "Break-away").

Simple enough to check by hand. On the perturbation state from trim (φ, θ, p, q, r rad,
rad/s) with the model's control effectiveness ``L_δa = ∂ṗ/∂δa``, ``M_δe = ∂q̇/∂δe``,
``N_δr = ∂ṙ/∂δr`` (the linearisation's B matrix):

* throttle: ``δt = clip(k_v (v_c − v_x), −throttle_back, +throttle_back)`` — the receiver's
  speed relative to the tanker ``v_x`` (tanker frame, m/s) held at the drop-back profile
  ``v_c = −min(drop_back_mps, √(2 a_b d_x))``, ``d_x`` the distance still to go to
  ``standoff_aft_m + standoff_margin_aft_m`` behind the drogue (0 beyond: it keeps station):
  the speed from which a deceleration ``a_b = brake_mps2`` stops there. A step to 0 at the
  standoff let the engine's spool-up (≈ 2–3 s) carry the receiver 20–30 m past it, each metre
  flown back by the rejoin;
* elevator: ``δe = −(ω_θ² (θ − θ_c) + 2 ζ ω_θ q) / M_δe`` — a pitch attitude hold, with
  ``θ_c = −(ż_c + k_z e + k_i ∫e) / V``, ``e = ż_c − ż``: the attitude of a descent at
  ``ż_c = min(sink_mps, d_z / sink_settle_s)`` (down), ``d_z`` the height still to lose to
  ``standoff_below_m + standoff_margin_below_m`` below the drogue (0 beyond), with a PI
  correction on the sink rate ``ż`` flown (a lighter aircraft or the tanker's downwash would
  otherwise turn the descent into a climb); ``|∫e| ≤ sink_integral_max_m`` — a wound-up
  integral (a climb while the probe passes the drogue) kept the receiver sinking at 3 m/s
  for seconds after the command was 0, 10–18 m below the standoff;
* aileron: ``δa = −(ω_φ² (φ − φ_c) + 2 ζ ω_φ p) / L_δa`` with
  ``φ_c = clip(−k_ψ (ẏ − ẏ_c) / V, ±10°)`` — wings level on the tanker's track: ``ẏ / V`` is
  the receiver's track angle relative to the tanker's (small angles; ``ẏ`` its measured
  sideways speed relative to the tanker, ``V`` the airspeed), and ``ẏ_c = clip(−k_y y_o,
  ±side_return_max_mps)`` brings it slowly back to the lateral station it held when the
  take-over began (``y_o`` its offset from there, tanker frame) — the tanker's line, not the
  drogue's swing. Holding the heading alone let a gust's side velocity drift the receiver
  15–150 m sideways in a break-away, and the LQR took over with a large side velocity;
  holding the track alone still let moderate turbulence carry it ≈ 20 m aside, out of the
  cameras' view for the rejoin. No turn towards the drogue either way; ``(ÿ = g φ)`` the
  lateral loop is ``ÿ + (g k_ψ/V) ẏ + (g k_ψ k_y/V) y_o = 0``: ω ≈ 0.18 rad/s, ζ ≈ 0.9 at
  230 KCAS;
* rudder: ``δr = −(2 ζ ω_ψ r) / N_δr`` — a yaw damper;
* speed brakes (:meth:`RecoveryLaw.speedbrake`): out while short of the standoff and faster
  (forward) than the drop-back profile, in otherwise (the A-4's add ΔC_D 0.021: with the engine at idle
  the receiver then decelerates at ≈ 0.17 g instead of ≈ 0.1 g).

Each surface command is clipped to ``± max_fraction`` of its travel. The law is done
(:meth:`RecoveryLaw.settled`) when the receiver sits at the safe standoff (≥
``standoff_aft_m`` aft and ≥ ``standoff_below_m`` below the drogue), wings level, rates
small, moving with the tanker (|v_x|, |ż| < 1 m/s, and sideways |ẏ| < ``side_speed_max_mps``) and — after an envelope recovery —
back near its trim (α within ±3° of it, load factor 0.7–1.3 g).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.control.linear_model import LinearModel
from app.types import FloatArray


@dataclass(frozen=True)
class RecoveryGains:
    throttle_back: float = 0.4  # normalised throttle, the most below (or above) trim (≈ idle)
    speed_gain: float = 0.15  # throttle per m/s of speed error
    drop_back_mps: float = 8.0  # the drop-back speed relative to the tanker
    # the descent's sink rate and k_z (m/s of sink-rate error per m/s). A break-away after a
    # crossing above the drogue carries the probe 2.5–3 m past the drogue's plane before the
    # drop-back takes hold, and the hose rises forward from the drogue: at 3 m/s and k_z 2 the
    # nose came within 0.5 m of the hose in 6 of 1 200 held-out runs (170028, 170173, 390082,
    # 390166, 390212, 390310; benchmarks/replay_keep_outs.py); at 5 m/s and 3, 0.9–2.5 m
    sink_mps: float = 5.0
    sink_gain: float = 3.0
    sink_integral_per_s: float = 0.5  # k_i
    sink_integral_max_m: float = 3.0  # |∫e| (m): the integrator's clip (anti-windup)
    heading_gain: float = 4.0  # k_ψ (rad of bank per rad of track angle)
    side_position_gain: float = 0.1  # k_y (m/s of sideways speed per m of offset)
    side_return_max_mps: float = 1.0  # the most sideways speed it commands back to station
    bank_max_deg: float = 10.0
    omega_roll_rad_s: float = 2.0
    omega_pitch_rad_s: float = 2.0
    omega_yaw_rad_s: float = 1.5
    damping: float = 0.8
    max_fraction: float = 0.3  # of each command's travel
    standoff_aft_m: float = 10.0
    standoff_below_m: float = 3.0
    # the drop-back and the descent aim this far beyond the standoff (m) and slow into it:
    # at ``brake_mps2`` fore-aft (the A-4 decelerates at ≈ 1 m/s² with the speed brakes out
    # and ≈ 1.7 m/s² at idle; spooling back up is slower) and with ``sink_settle_s`` vertically
    standoff_margin_aft_m: float = 6.0
    standoff_margin_below_m: float = 2.5
    brake_mps2: float = 1.0
    sink_settle_s: float = 0.5
    side_speed_max_mps: float = 1.5  # hand back only while drifting sideways slower than this


class RecoveryLaw:
    """Hand-checkable attitude hold + power back (module docstring)."""

    def __init__(self, model: LinearModel, gains: RecoveryGains | None = None) -> None:
        self.gains = g = gains or RecoveryGains()
        b = np.asarray(model.b, float)
        self.l_da = float(b[3, 1])
        self.m_de = float(b[4, 2])
        self.n_dr = float(b[5, 3])
        if min(abs(self.l_da), abs(self.m_de), abs(self.n_dr)) < 1e-9:
            raise ValueError("the model's control effectiveness is zero on a recovery channel")
        lo = np.asarray(model.limits.lower, float) - np.asarray(model.u_trim, float)
        hi = np.asarray(model.limits.upper, float) - np.asarray(model.u_trim, float)
        self.u_max = np.minimum(np.abs(lo), np.abs(hi)) * g.max_fraction
        self.throttle_floor = float(lo[0])
        self.airspeed_mps = float(model.airspeed_mps)
        self.dt = 0.02
        self.reset()

    def reset(self, dt: float | None = None) -> None:
        """A new take-over: the sink-rate integrator empty (``dt``: the tick, s)."""
        if dt is not None:
            self.dt = float(dt)
        self.sink_error_integral = 0.0

    def command(
        self,
        x_dev: FloatArray,
        speed_mps: float,
        sink_rate_mps: float,
        aft_m: float,
        below_m: float,
        side_speed_mps: float = 0.0,
        side_offset_m: float = 0.0,
    ) -> FloatArray:
        """Command deviation from trim (throttle, aileron, elevator, rudder) for the
        perturbation state ``x_dev`` (u v w p q r φ θ ψ x y z), the speed relative to the
        tanker ``speed_mps`` (forward +), the sink rate (down +), the distances aft of and
        below the drogue (m), the sideways speed relative to the tanker (m/s, right +) and the
        sideways offset from the station held when the take-over began (m, right +)."""
        g = self.gains
        p, q, r, phi, theta = x_dev[3], x_dev[4], x_dev[5], x_dev[6], x_dev[7]
        v_c = self.drop_back_profile(aft_m)
        to_lose = max(g.standoff_below_m + g.standoff_margin_below_m - below_m, 0.0)
        zdot_c = min(g.sink_mps, to_lose / g.sink_settle_s)
        err = zdot_c - sink_rate_mps
        cap = g.sink_integral_max_m
        self.sink_error_integral = float(
            np.clip(self.sink_error_integral + err * self.dt, -cap, cap)
        )
        theta_c = -(zdot_c + g.sink_gain * err + g.sink_integral_per_s * self.sink_error_integral)
        theta_c /= self.airspeed_mps
        bank_max = math.radians(g.bank_max_deg)
        side_c = float(
            np.clip(
                -g.side_position_gain * side_offset_m, -g.side_return_max_mps, g.side_return_max_mps
            )
        )
        track = (side_speed_mps - side_c) / self.airspeed_mps  # rad, from the track wanted
        phi_c = float(np.clip(-g.heading_gain * track, -bank_max, bank_max))
        wr, wp, wy, z = g.omega_roll_rad_s, g.omega_pitch_rad_s, g.omega_yaw_rad_s, g.damping
        throttle = float(
            np.clip(g.speed_gain * (v_c - speed_mps), -g.throttle_back, g.throttle_back)
        )
        u = np.array(
            [
                max(throttle, self.throttle_floor),
                -(wr * wr * (phi - phi_c) + 2 * z * wr * p) / self.l_da,
                -(wp * wp * (theta - theta_c) + 2 * z * wp * q) / self.m_de,
                -(2 * z * wy * r) / self.n_dr,
            ]
        )
        u[1:] = np.clip(u[1:], -self.u_max[1:], self.u_max[1:])
        return u

    def drop_back_profile(self, aft_m: float) -> float:
        """The commanded speed relative to the tanker (m/s, forward +) at ``aft_m`` behind the
        drogue: ``−min(drop_back_mps, √(2 a_b d_x))`` (module docstring)."""
        g = self.gains
        to_go = max(g.standoff_aft_m + g.standoff_margin_aft_m - aft_m, 0.0)
        return -min(g.drop_back_mps, math.sqrt(2.0 * g.brake_mps2 * to_go))

    def speedbrake(self, speed_mps: float, aft_m: float) -> float:
        """Speed-brake command (0 in … 1 out) for the speed relative to the tanker and the
        distance aft of the drogue (m): out while short of the standoff and faster than the
        drop-back profile."""
        g = self.gains
        short = aft_m < g.standoff_aft_m
        return 1.0 if short and speed_mps > self.drop_back_profile(aft_m) else 0.0

    def settled(
        self,
        x_dev: FloatArray,
        speed_mps: float,
        sink_rate_mps: float,
        aft_m: float,
        below_m: float,
        alpha_from_trim_deg: float,
        load_factor_g: float,
        side_speed_mps: float = 0.0,
    ) -> bool:
        """Done (module docstring); ``side_speed_mps``: the receiver's sideways speed relative
        to the tanker (m/s)."""
        g = self.gains
        level = abs(x_dev[6]) < math.radians(5.0)
        calm = float(np.max(np.abs(x_dev[3:6]))) < math.radians(3.0)
        steady = (
            abs(speed_mps) < 1.0
            and abs(sink_rate_mps) < 1.0
            and abs(side_speed_mps) < g.side_speed_max_mps
        )
        trimmed = abs(alpha_from_trim_deg) < 3.0 and 0.7 < load_factor_g < 1.3
        at_standoff = aft_m >= g.standoff_aft_m and below_m >= g.standoff_below_m
        return at_standoff and level and calm and steady and trimmed
