"""Contact, latch and release of the coupling on the multi-body hose, as a model-level API.

:class:`Coupling` wraps a :class:`~app.sim.hose.model.MultibodyHose`: :meth:`Coupling.contact`
latches when the probe head enters at a closure inside the latch window
(:class:`~app.sim.hose.params.CouplingParams`, 1.0–2.6 m/s: ≤ 5 kt, slower does not latch);
after that the drogue follows the probe (a prescribed trajectory, one position per tick) and the
hose follows through the reel. The coupling lets go when the hose pulls it forward off the probe
harder than the release load. Each run reports its peak hose tension, its slack and any whip
(:class:`CouplingReport`): a whip is a hose that went slack while latched (a segment shorter than
its rest length: no tension) and then snapped taut above ``whip_tension_factor`` × the trail
tension. :func:`push_in` flies the usual contact: the probe arrives along the flight path at the
contact closure, pushes the drogue in by 1.5–3 m, stops and holds.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from app.sim.hose.model import AirField, HoseTick, MultibodyHose
from app.sim.hose.params import CouplingParams
from app.types import FloatArray


@dataclass(frozen=True)
class SlackSample:
    """The hose's slack region at the end of a tick: arc positions from the reel exit (m) of
    its first and last slack segment (start of the first, end of the last)."""

    t_s: float
    start_m: float
    end_m: float


@dataclass(frozen=True)
class CouplingReport:
    """One contact (module docstring). Tensions in N, times in s, lengths in m; ``released_t_s``
    NaN when the coupling held; ``peak_tension_at_m`` the arc position (from the reel exit) of
    the segment that carried the peak."""

    latched: bool
    reason: str
    contact_closure_mps: float
    trail_tension_n: float
    peak_tension_n: float
    peak_tension_at_m: float
    min_tension_n: float
    slack_time_s: float
    max_slack_segments: int
    slack_wave: tuple[SlackSample, ...]
    whip: bool
    released: bool
    released_t_s: float
    peak_coupling_pull_n: float
    peak_coupling_load_n: float
    max_take_up_m: float


class Coupling:
    """Latch, ride, release (module docstring)."""

    def __init__(self, hose: MultibodyHose, params: CouplingParams | None = None) -> None:
        self.hose = hose
        self.params = params or CouplingParams()
        self.t_contact = math.nan
        self.closure = math.nan
        self.reason = "no contact"
        self.released = False
        self.released_t = math.nan
        self._slack_seen = False
        self._whip = False
        self._peak = 0.0
        self._peak_at = math.nan
        self._min = math.inf
        self._slack_time = 0.0
        self._max_slack = 0
        self._wave: list[SlackSample] = []
        self._pull = -math.inf
        self._load = 0.0
        self._min_payout = hose.payout_m

    def contact(self, closure_mps: float, probe_m: FloatArray) -> bool:
        """The probe head enters the coupling at ``closure_mps``, its point now at ``probe_m``:
        latch if inside the window."""
        p = self.params
        self.closure = float(closure_mps)
        self.t_contact = self.hose.t
        if not p.min_closure_mps <= closure_mps <= p.max_closure_mps:
            self.reason = (
                f"closure {closure_mps:.2f} m/s outside the latch window "
                f"{p.min_closure_mps}–{p.max_closure_mps} m/s"
            )
            return False
        self.reason = "latched"
        self.hose.latch(probe_m, p.stiffness_n_per_m, p.damping_n_s_per_m)
        return True

    def step(
        self,
        dt: float,
        probe_m: FloatArray,
        air: AirField | None = None,
        drogue_force_n: FloatArray | None = None,
    ) -> HoseTick:
        """One tick with the probe at ``probe_m`` at its end (ignored once released)."""
        latched = self.hose.latched
        tick = self.hose.step(dt, air, drogue_force_n, probe_m if latched else None)
        if not latched:
            return tick
        if tick.peak_tension_n > self._peak:
            self._peak = tick.peak_tension_n
            self._peak_at = (tick.peak_segment + 0.5) * tick.payout_m / self.hose.hose.segments
        self._min = min(self._min, tick.min_tension_n)
        self._pull = max(self._pull, tick.coupling_pull_n)
        self._load = max(self._load, tick.coupling_load_n)
        self._min_payout = min(self._min_payout, tick.payout_m)
        if tick.slack_segments > 0:
            self._slack_seen = True
            self._slack_time += dt
            self._max_slack = max(self._max_slack, tick.slack_segments)
        if self._slack_seen and tick.peak_tension_n > (
            self.params.whip_tension_factor * self.hose.trail_tension_n
        ):
            self._whip = True
        slack = np.flatnonzero(self.hose.tensions_n <= 0.0)
        if slack.size:
            seg = tick.payout_m / self.hose.hose.segments
            self._wave.append(
                SlackSample(t_s=tick.t_s, start_m=seg * slack[0], end_m=seg * (slack[-1] + 1))
            )
        if tick.coupling_pull_n > self.params.release_load_n:
            self.hose.release()
            self.released = True
            self.released_t = tick.t_s
            self.reason = (
                f"released: the hose pulled the coupling off the probe with "
                f"{tick.coupling_pull_n:.0f} N (release load {self.params.release_load_n:.0f} N)"
            )
        return tick

    def report(self) -> CouplingReport:
        h = self.hose
        latched = self.reason == "latched" or self.released
        return CouplingReport(
            latched=latched,
            reason=self.reason,
            contact_closure_mps=self.closure,
            trail_tension_n=h.trail_tension_n,
            peak_tension_n=self._peak if latched else math.nan,
            peak_tension_at_m=self._peak_at if latched else math.nan,
            min_tension_n=self._min if latched else math.nan,
            slack_time_s=self._slack_time,
            max_slack_segments=self._max_slack,
            slack_wave=tuple(self._wave),
            whip=self._whip,
            released=self.released,
            released_t_s=self.released_t,
            peak_coupling_pull_n=self._pull if latched else math.nan,
            peak_coupling_load_n=self._load if latched else math.nan,
            max_take_up_m=h.hose.length_m - self._min_payout,
        )


def push_in_path(closure_mps: float, push_in_m: float) -> Callable[[float], float]:
    """Forward distance (m) of the probe past the contact point ``t`` seconds after contact:
    the closure ``closure_mps`` at contact decays at a constant rate ``closure² / (2 push-in)``
    to rest ``push_in_m`` further forward (the receiver stops relative to the tanker)."""
    if not (closure_mps > 0.0 and push_in_m > 0.0):
        raise ValueError("the closure and the push-in must be > 0")
    decel = closure_mps**2 / (2.0 * push_in_m)
    t_stop = closure_mps / decel

    def forward(t: float) -> float:
        tau = min(max(t, 0.0), t_stop)
        return closure_mps * tau - 0.5 * decel * tau**2

    return forward


def push_in(
    hose: MultibodyHose,
    closure_mps: float,
    push_in_m: float,
    dt: float = 0.02,
    hold_s: float = 4.0,
    coupling: CouplingParams | None = None,
    air: AirField | None = None,
) -> CouplingReport:
    """The probe meets the drogue (at rest) at ``closure_mps`` along the flight path, latches if
    it may, pushes the drogue in by ``push_in_m`` (:func:`push_in_path`) and holds ``hold_s``;
    returns the contact's report."""
    c = Coupling(hose, coupling)
    axis = np.array([1.0, 0.0, 0.0])
    contact_m = hose.drogue_m
    if not c.contact(closure_mps, contact_m):
        return c.report()
    path = push_in_path(closure_mps, push_in_m)
    t_end = 2.0 * push_in_m / closure_mps + hold_s
    k = 0
    while (k + 1) * dt <= t_end + 1e-9:
        k += 1
        c.step(dt, contact_m + path(k * dt) * axis, air)
        if c.released:
            break
    return c.report()
