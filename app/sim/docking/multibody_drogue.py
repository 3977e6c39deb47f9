"""The multi-body hose (:mod:`app.sim.hose`) with the interface the docking loop flies a drogue by.

:class:`MultibodyDrogue` wraps a :class:`~app.sim.hose.model.MultibodyHose` so that
:class:`~app.sim.docking.simulation.DockingSimulation` flies it where it flies the reduced-order
:class:`~app.sim.hose_drogue.HoseDrogue` (``DockingConfig.hose_model = "multibody"``): the
drogue's rest position ``eq_m`` (the steady shape's), its position and velocity, the normal of
its opening (the last segment's direction), the hose's nodes, the receiver's bow wave on it, one
free tick driven by the Dryden gust (carried aft along the hose from the reel exit:
:class:`~app.sim.hose.model.FrozenGust`) and the tanker's wake
(:func:`~app.sim.hose.model.wake_field`, the strengths of the run's draw). At capture the
coupling latches (:class:`~app.sim.hose.contact.Coupling`: a spring-damper to the probe's
point) instead of welding the drogue to the probe; while latched the hose follows through the
reel, and the coupling reports the contact's peak tension, slack and any whip, and lets go
above its release load.

Tanker frame (x forward, y right, z down; m, m/s, N), the reel exit at the origin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.sim.hose import (
    Coupling,
    CouplingParams,
    CouplingReport,
    DrogueParams,
    FlowCondition,
    FrozenGust,
    HoseParams,
    HoseTick,
    MultibodyHose,
    ReelParams,
    combined,
    wake_field,
)
from app.sim.hose.model import AirField
from app.sim.hose_drogue import bow_wave_force
from app.types import FloatArray

#: the gust's ring covers the hose at full trail plus this much (m)
GUST_SPAN_MARGIN_M = 10.0
#: after the latch the coupling's point moves from where the drogue sat relative to the probe
#: head at contact (off-centre by the radial miss, up to the rim) to the probe's point over this
#: time (s): the basket's funnel guiding the head into the coupling during the push-in (a
#: coupling point on the probe at once would be a step of up to 0.26 m into its 2·10⁴ N/m spring)
CENTRING_S = 0.5


@dataclass(frozen=True)
class MultibodyDrogueParams:
    """The flown hose, drogue, reel and coupling (this run's draw: truth, for logs and tests;
    the guidance never reads it), the flight condition, the bow wave (N, m) and the tanker's
    wake along the hose (downwash m/s, sidewash m/s per m)."""

    flow: FlowCondition
    hose: HoseParams
    drogue: DrogueParams
    reel: ReelParams
    coupling: CouplingParams
    bow_force_n: float
    bow_length_m: float = 1.5
    bow_up_bias_m: float = 0.3
    wake_downwash_mps: float = 0.0
    wake_sidewash_per_m: float = 0.0


class MultibodyDrogue:
    """The multi-body hose's drogue as the docking loop flies it (module docstring)."""

    def __init__(self, params: MultibodyDrogueParams, dt: float) -> None:
        self.params = params
        self.hose = MultibodyHose(params.flow, params.hose, params.drogue, params.reel)
        self.coupling = Coupling(self.hose, params.coupling)
        self.eq_m: FloatArray = self.hose.steady.nodes_m[-1].copy()
        self.gust = FrozenGust(
            params.flow.airspeed_mps, dt, params.hose.length_m + GUST_SPAN_MARGIN_M
        )
        air: AirField = self.gust
        if params.wake_downwash_mps != 0.0 or params.wake_sidewash_per_m != 0.0:
            air = combined(
                self.gust, wake_field(params.wake_downwash_mps, params.wake_sidewash_per_m)
            )
        self.air = air
        self.last_tick: HoseTick | None = None
        self.contacted = False
        self.peak_contact_tension_n = math.nan  # the latched contact's peak so far (N)
        self._offset = np.zeros(3)  # the drogue's offset from the probe head at contact (m)
        self._since = 0.0  # time since the contact (s)

    # --- what the loop reads -------------------------------------------------------------
    @property
    def position_m(self) -> FloatArray:
        return self.hose.drogue_m

    @property
    def velocity_mps(self) -> FloatArray:
        return self.hose.drogue_velocity_mps

    def normal(self) -> FloatArray:
        """Unit normal of the drogue's opening, aft towards the receiver."""
        return self.hose.normal()

    def hose_nodes_m(self) -> FloatArray:
        """The hose's nodes now (reel exit first, drogue last; m)."""
        return self.hose.nodes_m

    @property
    def tension_n(self) -> float:
        """The highest segment tension of the last tick (N; the trail tension before any)."""
        if self.last_tick is None:
            return float(self.hose.trail_tension_n)
        return self.last_tick.peak_tension_n

    @property
    def payout_m(self) -> float:
        """The reel's payout (m; the hose length at full trail)."""
        return self.hose.payout_m

    def bow_wave_force(self, nose_m: FloatArray, nose_axis: FloatArray) -> FloatArray:
        """Force (N) of the receiver's bow wave on the drogue (:func:`~app.sim.hose_drogue.
        bow_wave_force`, the run's strength)."""
        p = self.params
        return bow_wave_force(
            self.position_m, nose_m, nose_axis, p.bow_force_n, p.bow_length_m, p.bow_up_bias_m
        )

    # --- one tick ------------------------------------------------------------------------
    def step(self, dt: float, gust_mps: FloatArray, force_n: FloatArray | None = None) -> None:
        """One free tick: the Dryden gust ``gust_mps`` (m/s, met at the reel exit now) carried
        along the hose, the wake, and ``force_n`` (N) on the drogue."""
        self.gust.push(np.asarray(gust_mps, float))
        self.last_tick = self.coupling.step(dt, self.hose.drogue_m, self.air, force_n)

    def latch(self, probe_m: FloatArray, closure_mps: float) -> None:
        """Contact: the probe head entered the coupling at ``closure_mps`` with its point at
        ``probe_m``; the coupling latches if the closure is inside its window."""
        self.contacted = True
        self._offset = self.hose.drogue_m - np.asarray(probe_m, float)
        self._since = 0.0
        self.coupling.contact(closure_mps, self.hose.drogue_m)

    def ride(self, dt: float, probe_m: FloatArray, gust_mps: FloatArray) -> None:
        """One latched tick: the probe at ``probe_m`` at its end (the coupling follows it while
        it holds; once released the drogue flies free)."""
        self.gust.push(np.asarray(gust_mps, float))
        latched = self.hose.latched
        self._since += dt
        centring = max(0.0, 1.0 - self._since / CENTRING_S)
        point = np.asarray(probe_m, float) + centring * self._offset
        tick = self.last_tick = self.coupling.step(dt, point, self.air)
        if latched:
            peak = self.peak_contact_tension_n
            self.peak_contact_tension_n = (
                tick.peak_tension_n if math.isnan(peak) else max(peak, tick.peak_tension_n)
            )

    # --- the run's report ----------------------------------------------------------------
    def contact_report(self) -> CouplingReport | None:
        """The contact's report (peak tension, slack, whip, release); None before a contact."""
        return self.coupling.report() if self.contacted else None
