"""The multi-body hose in flight: state, one tick of integration, the air along the hose.

:class:`MultibodyHose` holds the nodes of the lumped-mass hose (reel exit first, drogue last;
tanker frame x forward, y right, z down; m, m/s), the reel's payout and its rate, and whether the
coupling rides on a probe. :meth:`MultibodyHose.step` advances one tick of the docking loop with
the compiled kernels (:mod:`app.sim.hose.kernels`: semi-implicit Euler in substeps below the
stiffest axial mode's limit); the hooks of a tick are

* ``air``: an :data:`AirField`, the air's velocity disturbance (gusts, the tanker's wake) at the
  nodes, added to the free stream ``(−V, 0, 0)``; :class:`FrozenGust` carries a Dryden gust
  sampled at the reel exit aft along the hose at the airspeed (Taylor's frozen field);
* ``drogue_force_n``: any other force on the drogue (the receiver's bow wave);
* ``probe``: while latched, the probe's position at the end of the tick (the drogue follows).

The reel runs the law of :class:`app.sim.hose.params.ReelParams`, its set point taken from the
trail tension of the steady shape at the flight condition.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.sim.hose.atmosphere import FlowCondition
from app.sim.hose.kernels import (
    RP_GAIN,
    RP_LMAX,
    RP_LMIN,
    RP_SETPOINT,
    RP_SIZE,
    RP_TAU,
    RP_VMAX,
    ST_LOAD,
    ST_MIN_T,
    ST_PEAK_SEG,
    ST_PEAK_T,
    ST_PULL,
    ST_SIZE,
    ST_SLACK,
    advance,
    pack_hose,
    substep_limit_s,
)
from app.sim.hose.params import DrogueParams, HoseParams, ReelParams
from app.sim.hose.steady import SteadyShape, steady_shape
from app.types import FloatArray

#: air velocity disturbance (m/s, tanker frame) at points ``(k, 3)`` (m) and time (s)
AirField = Callable[[FloatArray, float], FloatArray]


class FrozenGust:
    """A gust field convected aft at the airspeed: the gust pushed each tick (sampled at the
    reel exit) reaches a point ``x`` metres aft of it ``x / V`` seconds later (linear
    interpolation between ticks; before the first sample, the first)."""

    def __init__(self, airspeed_mps: float, dt: float, span_m: float = 40.0) -> None:
        self.airspeed = airspeed_mps
        self.dt = dt
        self.size = int(math.ceil(span_m / airspeed_mps / dt)) + 2
        self.history = np.zeros((self.size, 3))  # a ring: the newest at ``self.head``
        self.head = 0
        self.count = 0

    def push(self, gust_mps: FloatArray) -> None:
        self.head = (self.head + 1) % self.size
        self.history[self.head] = gust_mps
        if self.count == 0:
            self.history[:] = self.history[self.head]
        self.count += 1

    def __call__(self, points_m: FloatArray, t_s: float) -> FloatArray:
        lag = np.clip(-points_m[:, 0] / (self.airspeed * self.dt), 0.0, self.size - 2.0)
        k = lag.astype(np.int64)
        frac = (lag - k)[:, None]
        newer = self.history[(self.head - k) % self.size]
        older = self.history[(self.head - k - 1) % self.size]
        return np.asarray((1.0 - frac) * newer + frac * older)


def combined(*fields: AirField) -> AirField:
    """One air field from several (their sum): e.g. a :class:`FrozenGust` and the tanker's
    wake (:func:`wake_field`)."""

    def total(points_m: FloatArray, t_s: float) -> FloatArray:
        out = np.zeros((len(points_m), 3))
        for f in fields:
            out += f(points_m, t_s)
        return out

    return total


def wake_field(downwash_mps: float, sidewash_per_m: float, scale_m: float = 20.0) -> AirField:
    """The tanker's wake as the closed loop models it at the receiver
    (:func:`app.sim.imperfections.wake_downwash`: downwash ``W ℓ²/(ℓ² + x²)`` plus a sidewash
    ``k_y y``), applied at every node of the hose."""

    def wake(points_m: FloatArray, t_s: float) -> FloatArray:
        x = points_m[:, 0]
        out = np.zeros((len(points_m), 3))
        out[:, 1] = sidewash_per_m * points_m[:, 1]
        out[:, 2] = downwash_mps * scale_m**2 / (scale_m**2 + x * x)
        return out

    return wake


@dataclass(frozen=True)
class HoseTick:
    """What one tick did: the extremes of the segment tensions over its substeps (N; the
    segment of the peak, 0 at the reel), the most segments slack at once, the reel, and while
    latched the coupling's forward pull on the probe and its load (N; NaN when not latched)."""

    t_s: float
    peak_tension_n: float
    peak_segment: int
    min_tension_n: float
    slack_segments: int
    payout_m: float
    payout_rate_mps: float
    coupling_pull_n: float
    coupling_load_n: float


class MultibodyHose:
    """The lumped-mass hose with its drogue and reel (module docstring)."""

    def __init__(
        self,
        flow: FlowCondition,
        hose: HoseParams | None = None,
        drogue: DrogueParams | None = None,
        reel: ReelParams | None = None,
        reel_active: bool = True,
    ) -> None:
        self.flow = flow
        self.hose = hose or HoseParams()
        self.drogue = drogue or DrogueParams()
        self.reel = reel or ReelParams()
        self.reel_active = reel_active
        self.hp = pack_hose(flow, self.hose, self.drogue)
        self.steady: SteadyShape = steady_shape(flow, self.hose, self.drogue)
        self.trail_tension_n = self.steady.reel_tension_n
        self.rp = np.zeros(RP_SIZE)
        self.rp[RP_SETPOINT] = self.reel.setpoint_fraction * self.trail_tension_n
        self.rp[RP_GAIN] = self.reel.gain_mps_per_n
        self.rp[RP_TAU] = self.reel.response_time_s
        self.rp[RP_VMAX] = self.reel.max_speed_mps
        self.rp[RP_LMAX] = self.hose.length_m
        self.rp[RP_LMIN] = self.hose.length_m - self.reel.max_take_up_m
        if self.rp[RP_LMIN] <= 0.0:
            raise ValueError("the reel's take-up must be shorter than the hose")
        n = self.hose.segments
        self.h_max = substep_limit_s(self.hp, self.rp[RP_LMIN] / n)
        self.free_air = np.array([-flow.airspeed_mps, 0.0, 0.0])
        self._tension = np.zeros(n)
        self._stats = np.zeros(ST_SIZE)
        self.reset()

    def reset(self) -> None:
        """Back to the steady shape at full trail, at rest, unlatched."""
        self.pos = self.steady.nodes_m.copy()
        self.vel = np.zeros_like(self.pos)
        self.reel_state = np.array([self.hose.length_m, 0.0])
        self._tension[:] = self.steady.tensions_n
        self.latched = False
        self._probe_m = np.zeros(3)
        self._coupling = np.zeros(2)
        self.t = 0.0

    # --- what the loop reads -------------------------------------------------------------
    @property
    def nodes_m(self) -> FloatArray:
        return np.asarray(self.pos.copy())

    @property
    def drogue_m(self) -> FloatArray:
        return np.asarray(self.pos[-1].copy())

    @property
    def drogue_velocity_mps(self) -> FloatArray:
        return np.asarray(self.vel[-1].copy())

    @property
    def tensions_n(self) -> FloatArray:
        """Segment tensions at the end of the last substep (reel first; N)."""
        return np.asarray(self._tension.copy())

    @property
    def reel_tension_n(self) -> float:
        return float(self._tension[0])

    @property
    def payout_m(self) -> float:
        return float(self.reel_state[0])

    def normal(self) -> FloatArray:
        """Unit normal of the drogue's opening, aft towards the receiver: the last segment's
        direction."""
        d = self.pos[-1] - self.pos[-2]
        return np.asarray(d / np.linalg.norm(d))

    # --- the coupling --------------------------------------------------------------------
    def latch(
        self, probe_m: FloatArray, stiffness_n_per_m: float, damping_n_s_per_m: float
    ) -> None:
        """The coupling rides on the probe, now at ``probe_m``, from now on: the drogue is held
        to the probe's point by a spring-damper (the coupling's and the basket's compliance)."""
        self.latched = True
        self._probe_m = np.asarray(probe_m, float).copy()
        self._coupling = np.array([stiffness_n_per_m, damping_n_s_per_m])

    def release(self) -> None:
        self.latched = False

    # --- one tick ------------------------------------------------------------------------
    def substeps(self, dt: float) -> int:
        return max(1, int(math.ceil(dt / self.h_max - 1e-9)))

    def step(
        self,
        dt: float,
        air: AirField | None = None,
        drogue_force_n: FloatArray | None = None,
        probe_m: FloatArray | None = None,
    ) -> HoseTick:
        """Advance ``dt`` seconds (module docstring for the hooks). ``probe_m`` (the probe's
        position at the end of the tick) is required while latched and ignored otherwise."""
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"dt must be > 0, got {dt!r}")
        n = self.hose.segments
        air_v = np.tile(self.free_air, (n + 1, 1))
        if air is not None:
            air_v += np.asarray(air(self.pos, self.t), float).reshape(n + 1, 3)
        f_d = np.zeros(3) if drogue_force_n is None else np.asarray(drogue_force_n, float)
        if not (np.isfinite(air_v).all() and f_d.shape == (3,) and np.isfinite(f_d).all()):
            raise ValueError("the air field and the drogue force must be finite (3-vectors)")
        if self.latched:
            if probe_m is None:
                raise ValueError("a latched hose needs the probe's position each tick")
            start = self._probe_m.copy()
            end = np.asarray(probe_m, float).copy()
            if end.shape != (3,) or not np.isfinite(end).all():
                raise ValueError(f"the probe's position must be a finite 3-vector, got {probe_m!r}")
            self._probe_m = end
        else:
            start = end = self.pos[-1].copy()
        advance(
            self.pos,
            self.vel,
            air_v,
            f_d,
            self.reel_state,
            self.hp,
            self.rp,
            self.reel_active,
            dt,
            self.substeps(dt),
            self.latched,
            start,
            end,
            self._coupling,
            self._tension,
            self._stats,
        )
        self.t += dt
        st = self._stats
        return HoseTick(
            t_s=self.t,
            peak_tension_n=float(st[ST_PEAK_T]),
            peak_segment=int(st[ST_PEAK_SEG]),
            min_tension_n=float(st[ST_MIN_T]),
            slack_segments=int(st[ST_SLACK]),
            payout_m=float(self.reel_state[0]),
            payout_rate_mps=float(self.reel_state[1]),
            coupling_pull_n=float(st[ST_PULL]) if self.latched else math.nan,
            coupling_load_n=float(st[ST_LOAD]) if self.latched else math.nan,
        )
