"""Reference trajectory generation (paper §6.1, RTGM of Fig. 13 / Algorithm 3).

Phases: ``approach`` (probe tip held ``gap`` metres behind the estimated drogue, the gap shrinking
at the closure speed, laterally following the drogue estimate), ``final`` (the last metre, where the
breakaway checks run), ``contact`` (the tick the probe enters the drogue), ``station_keeping``
(refuelling: hold the contact point pushed in by a few centimetres, the paper's 8–20 s stage) and
``backoff`` (open the gap at the back-off speed, then retry). The commanded gap keeps shrinking past
zero by ``overshoot_m`` so the probe actually crosses the drogue plane at closure speed.
All positions in the tanker frame (m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.types import FloatArray

PHASES = (
    "approach",
    "final",
    "contact",
    "station_keeping",
    "backoff",
    "breakaway",  # the run-time assurance's recovery law flies (app.control.recovery)
    "rejoin",  # back from the break-away's standoff to the pre-contact position
    "stabilise",  # the first approach's stabilisation at the pre-contact position
)


@dataclass
class GuidanceConfig:
    closure_speed_mps: float = 1.2
    final_gap_m: float = 1.0
    overshoot_m: float = 0.5
    backoff_gap_m: float = 4.0
    backoff_speed_mps: float = 1.5
    push_in_m: float = 0.3
    push_in_time_s: float = 2.0
    # timed closure: the gap closes to this standoff (m) and holds there until the guidance
    # commits (``update(..., commit=True)``), then closes to contact without stopping;
    # None: no standoff
    standoff_gap_m: float | None = None
    standoff_slowdown_s: float = 0.8
    # the commanded gap's rate changes at most this fast (m/s²; None: at once). A receiver's
    # engine spools at a limited rate: a step in the closure speed asks for more thrust than
    # it can build, and the throttle then runs to its limit and the closure overshoots
    accel_limit_mps2: float | None = None
    # after a break-away: climb back to the drogue's height and close to this gap (m; the
    # pre-contact position, 3–4.5 m in practice) at ``rejoin_speed_mps``
    rejoin_gap_m: float = 5.0
    rejoin_speed_mps: float = 1.5
    # farther than ``rejoin_far_m`` beyond the pre-contact gap the rejoin closes at
    # ``rejoin_far_speed_mps`` (the break-away's drop-back carries the receiver 20–30 m aft;
    # at 1 m/s all the way the rejoin alone took ≈ 25 s of a 90 s run)
    rejoin_far_m: float = 10.0
    rejoin_far_speed_mps: float = 2.0
    rejoin_accel_mps2: float = 0.3  # the most each rejoin rate changes per second
    rejoin_dwell_s: float = 3.0  # stabilised at the pre-contact position this long, then close


REJOIN_CREEP_MPS = 0.05  # the rejoin's slowest closing speed near its end (m/s)
# each rejoin rate slows into its end at this fraction of ``rejoin_accel_mps2`` (the rest is
# the margin that lets the rate-limited speed follow the braking curve without overshooting)
REJOIN_BRAKE_FRACTION = 0.8


class ReferenceGenerator:
    def __init__(self, config: GuidanceConfig, start_gap_m: float) -> None:
        self.cfg = config
        self.reset(start_gap_m)

    def reset(self, start_gap_m: float) -> None:
        self.phase = "approach" if start_gap_m > self.cfg.final_gap_m else "final"
        self.gap_cmd = float(start_gap_m)
        self.contact_point: FloatArray | None = None
        self.contact_time = 0.0
        self.backoffs = 0
        self.committed = False
        self.gap_rate = 0.0  # m/s, the commanded gap's rate (negative: closing)
        self.rejoin_below_m = 0.0  # rejoin: the reference's height below the drogue (m)
        self.rejoin_side_m = 0.0  # rejoin: the reference's offset to the drogue's right (m)
        self.rejoin_dwell = 0.0  # s at the pre-contact position
        self._rejoin_v = np.zeros(3)  # m/s: the gap's, the height's and the side's closing speed

    @property
    def holding(self) -> bool:
        """At the standoff, waiting for the guidance's commit."""
        s = self.cfg.standoff_gap_m
        return (
            s is not None
            and not self.committed
            and self.phase in ("approach", "final")
            and self.gap_cmd <= s
        )

    def _shaped_rate(self, dt: float, wanted_rate: float) -> float:
        """Replace this tick's gap step (``wanted_rate``, already applied to ``gap_cmd``) by
        one whose rate moves towards it at no more than ``accel_limit_mps2``."""
        assert self.cfg.accel_limit_mps2 is not None
        self.gap_cmd -= wanted_rate * dt
        dv = self.cfg.accel_limit_mps2 * dt
        self.gap_rate = float(np.clip(wanted_rate, self.gap_rate - dv, self.gap_rate + dv))
        self.gap_cmd += self.gap_rate * dt
        return self.gap_rate

    def start_rejoin(self, gap_m: float, below_m: float, side_m: float = 0.0) -> None:
        """Take over from the break-away at ``gap_m`` behind, ``below_m`` below and ``side_m``
        to the right of the drogue (the reference starts where the probe is and moves back at
        a bounded speed)."""
        self.phase = "rejoin"
        self.gap_cmd = float(gap_m)
        self.rejoin_below_m = max(float(below_m), 0.0)
        self.rejoin_side_m = float(side_m)
        self.rejoin_dwell = 0.0
        self._rejoin_v = np.zeros(3)  # m/s: the gap's, the height's and the side's closing speed
        self.gap_rate = 0.0
        self.committed = False

    def start_stabilise(self, gap_m: float) -> None:
        """The first approach as field practice flies it: close to the pre-contact position
        (``rejoin_gap_m`` behind the drogue), stabilise there ``rejoin_dwell_s``, then
        approach — the rejoin's motion (:meth:`_rejoin_step`) from ``gap_m`` behind, on the
        drogue's line."""
        self.start_rejoin(gap_m, 0.0, 0.0)
        self.phase = "stabilise"

    def _rejoin_step(self, dt: float) -> tuple[float, float, float]:
        """One tick of the rejoin; returns the rates (m/s) of the gap, of the height below
        and of the offset to the side. Each closes at up to its speed (fore-aft: the far
        speed while far), slowing into the end on its braking curve ``√(2 a d)`` (``a`` =
        ``REJOIN_BRAKE_FRACTION`` × ``rejoin_accel_mps2``, ``d`` the distance left), and each
        rate changes at most ``rejoin_accel_mps2``: the reference's velocity (the LQR's
        feed-forward) never steps — a step at the hand-back gave a pitch transient that
        crossed the monitor's α bound. (A slowing as distance / 2 s overshot the end under
        the rate limit and hunted about it for ≈ 10 s.)"""
        c = self.cfg
        remaining = np.array(
            [self.gap_cmd - c.rejoin_gap_m, self.rejoin_below_m, self.rejoin_side_m]
        )
        far = remaining[0] > c.rejoin_far_m
        v_max = np.array(
            [
                c.rejoin_far_speed_mps if far else c.rejoin_speed_mps,
                c.rejoin_speed_mps,
                c.rejoin_speed_mps,
            ]
        )
        braking = np.sqrt(2.0 * REJOIN_BRAKE_FRACTION * c.rejoin_accel_mps2 * np.abs(remaining))
        slowing = np.maximum(braking, REJOIN_CREEP_MPS)
        wanted = np.sign(remaining) * np.minimum(v_max, slowing)
        dv = c.rejoin_accel_mps2 * dt
        self._rejoin_v = np.clip(wanted, self._rejoin_v - dv, self._rejoin_v + dv)
        step = self._rejoin_v * dt
        done = np.abs(step) >= np.abs(remaining)  # (the creep speed gets there)
        step[done] = remaining[done]
        self._rejoin_v[done] = 0.0
        self.gap_cmd -= step[0]
        self.rejoin_below_m -= step[1]
        self.rejoin_side_m -= step[2]
        if bool(np.all(np.abs(remaining - step) < 1e-9)):
            self.rejoin_dwell += dt
            if self.rejoin_dwell >= c.rejoin_dwell_s:
                self.phase = "approach"
        rate = -step / dt
        return float(rate[0]), float(rate[1]), float(rate[2])

    def start_backoff(self) -> None:
        self.phase = "backoff"
        self.backoffs += 1
        self.committed = False

    def mark_contact(self, tip_m: FloatArray) -> None:
        self.phase = "contact"
        self.contact_point = np.asarray(tip_m, float).copy()
        self.contact_time = 0.0

    def update(
        self,
        dt: float,
        drogue_pos: FloatArray,
        drogue_vel: FloatArray,
        lock: bool,
        commit: bool = True,
    ) -> tuple[FloatArray, FloatArray]:
        """Advance one tick; return probe-tip reference position (m) and velocity (m/s).
        ``commit``: at the standoff (``standoff_gap_m``), close now (else hold the gap)."""
        c = self.cfg
        if self.phase in ("contact", "station_keeping"):
            assert self.contact_point is not None
            self.phase = "station_keeping"
            self.contact_time += dt
            frac = min(self.contact_time / c.push_in_time_s, 1.0)
            ref = self.contact_point + np.array([c.push_in_m * frac, 0.0, 0.0])
            vel = np.array([c.push_in_m / c.push_in_time_s if frac < 1 else 0.0, 0.0, 0.0])
            return ref, vel
        gap_rate = 0.0
        below = side = below_rate = side_rate = 0.0
        if self.phase in ("rejoin", "stabilise"):
            gap_rate, below_rate, side_rate = self._rejoin_step(dt)
            below, side = self.rejoin_below_m, self.rejoin_side_m
        elif self.phase == "backoff":
            if self.gap_cmd < c.backoff_gap_m:
                self.gap_cmd += c.backoff_speed_mps * dt
                gap_rate = c.backoff_speed_mps
            elif lock:
                self.phase = "approach"
        elif self.holding and not (commit and lock):
            pass  # hold at the standoff until the guidance commits
        elif self.gap_cmd > -c.overshoot_m and lock:  # close only while the drogue is tracked
            if self.holding:
                self.committed = True
            if c.standoff_gap_m is not None and not self.committed:
                # slow down into the standoff: the closure speed, or the remaining distance
                # over the deceleration's time constant (a receiver cannot stop at once)
                rest = max(self.gap_cmd - c.standoff_gap_m, 0.0)
                speed = min(c.closure_speed_mps, max(rest / c.standoff_slowdown_s, 0.15))
                step = min(speed * dt, rest)
                self.gap_cmd -= step
                gap_rate = -step / dt
            else:
                self.gap_cmd -= c.closure_speed_mps * dt
                gap_rate = -c.closure_speed_mps
        if c.accel_limit_mps2 is not None:
            gap_rate = self._shaped_rate(dt, gap_rate)
        else:
            self.gap_rate = gap_rate
        if self.phase in ("approach", "final"):
            self.phase = "final" if self.gap_cmd <= c.final_gap_m else "approach"
        ref = np.asarray(drogue_pos, float) - np.array([self.gap_cmd, -side, -below])
        vel = np.asarray(drogue_vel, float) - np.array([gap_rate, -side_rate, -below_rate])
        return ref, vel
