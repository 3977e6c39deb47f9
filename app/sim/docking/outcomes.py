"""How a docking run ends: exactly one named outcome per run (:data:`OUTCOMES`), the contact
as the field defines it (:class:`ContactReport`) and the run-time assurance's hand-overs
(:class:`RtaEvent`).

Outcome classes, in order of precedence (a safety event outranks everything after it):

* ``error`` — an exception; recorded with its traceback by the campaign (never raised here);
* ``departure`` — the envelope monitor's bounds crossed (a recovery was needed), or the state
  diverged (non-finite): :mod:`app.control.envelope`;
* ``keep_out`` — the receiver inside the tanker's or the hose's keep-out zone;
* ``captured`` — the probe head entered inside the rim less its radius at a closure inside the
  latch window (1.0–2.6 m/s), and the run ended without a safety event;
* ``rim_strike`` — the probe head crossed the drogue's plane across the rim (in an attempt or
  while breaking away);
* ``missed`` — the break-aways used up, the last after a crossing outside the rim or outside
  the latch window;
* ``aborted`` — the break-aways used up otherwise, or the time ran out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from app.types import FloatArray

OUTCOMES = ("captured", "rim_strike", "missed", "aborted", "departure", "keep_out", "error")
#: closure above this at contact: the hose whips (m/s; 5 kt)
WHIP_CLOSURE_MPS = 2.6


@dataclass(frozen=True)
class RtaEvent:
    """One hand-over of the run-time assurance (``kind``: "recovery" — the recovery law takes
    over; "hand_back" — the LQR takes back)."""

    t_s: float
    kind: str
    reason: str


@dataclass(frozen=True)
class PlaneCrossing:
    """The probe tip crossing the drogue's plane: its radial miss from the drogue's centre
    (m), the closure and the lateral speed across the drogue's axis (m/s) at the crossing."""

    miss_m: float
    closure_mps: float
    lateral_mps: float


def plane_crossing(
    before: tuple[FloatArray, FloatArray, FloatArray],
    now: tuple[FloatArray, FloatArray, FloatArray],
    dt: float,
) -> PlaneCrossing | None:
    """The crossing between two ticks (each: probe tip, drogue centre, drogue normal aft; m,
    tanker frame), interpolated linearly to the instant the tip reaches the plane; None if
    the tip did not go from aft of the plane to on or past it."""
    (tip0, d0, n0), (tip, d, n) = before, now
    s_prev = float(n0 @ (tip0 - d0))
    s_now = float(n @ (tip - d))
    if not s_prev > 0.0 >= s_now:
        return None
    lam = s_prev / (s_prev - s_now)
    rel = (tip0 + lam * (tip - tip0)) - (d0 + lam * (d - d0))
    radial = rel - (rel @ n) * n
    v_rel = ((tip - tip0) - (d - d0)) / dt
    lateral = float(np.linalg.norm(v_rel - (v_rel @ n) * n))
    return PlaneCrossing(float(np.linalg.norm(radial)), (s_prev - s_now) / dt, lateral)


@dataclass
class ContactReport:
    """Each crossing of the drogue's plane, judged as the field does (module docstring)."""

    crossings: int = 0
    rim_strikes: int = 0
    capture_lateral_mps: float = math.nan
    capture_closure_mps: float = math.nan
    whip_risk: bool = False
    last_reason: str = ""

    def crossing(
        self,
        miss_m: float,
        closure_mps: float,
        lateral_mps: float,
        rim_radius_m: float,
        head_radius_m: float,
        latch_window_mps: tuple[float, float],
    ) -> str:
        """Classify one crossing: "captured", "rim_strike" or "missed" (the reason is kept
        in :attr:`last_reason`)."""
        self.crossings += 1
        lo, hi = latch_window_mps
        if closure_mps > WHIP_CLOSURE_MPS:
            self.whip_risk = True
        inner, outer = rim_radius_m - head_radius_m, rim_radius_m + head_radius_m
        if miss_m <= outer and miss_m > inner:
            self.rim_strikes += 1
            self.last_reason = f"rim strike: probe head {miss_m:.3f} m from the centre"
            return "rim_strike"
        if miss_m > outer:
            self.last_reason = (
                f"missed the drogue: probe tip {miss_m:.3f} m from the centre, "
                f"{miss_m - rim_radius_m:.3f} m outside the rim"
            )
            return "missed"
        if not lo <= closure_mps <= hi:
            self.last_reason = (
                f"closure {closure_mps:.2f} m/s outside the latch window {lo}–{hi} m/s"
            )
            return "missed"
        self.capture_lateral_mps = lateral_mps
        self.capture_closure_mps = closure_mps
        self.last_reason = "captured"
        return "captured"

    def strike_while_breaking_away(
        self, miss_m: float, rim_radius_m: float, head_radius_m: float
    ) -> str | None:
        """A crossing while breaking away (no attempt): the reason if the head struck the
        rim, else None."""
        if not rim_radius_m - head_radius_m < miss_m <= rim_radius_m + head_radius_m:
            return None
        self.rim_strikes += 1
        return f"rim strike while breaking away: probe head {miss_m:.3f} m from the centre"


@dataclass
class RunClassifier:
    """Collects a run's terminal events and gives its one outcome (module docstring)."""

    events: dict[str, str] = field(default_factory=dict)  # class → first reason
    diverged: bool = False
    aborts_used: bool = False
    last_miss: str | None = None

    def mark(self, outcome: str, reason: str) -> None:
        self.events.setdefault(outcome, reason)

    def mark_diverged(self, reason: str) -> None:
        self.diverged = True
        self.mark("departure", reason)

    def mark_aborts_used(self, aborts: int) -> None:
        self.aborts_used = True

    @property
    def terminal(self) -> bool:
        """A safety event, a rim strike or the break-aways used up: the run ends once the
        receiver is back at the safe standoff."""
        return self.aborts_used or any(
            k in self.events for k in ("departure", "keep_out", "rim_strike")
        )

    @property
    def reason(self) -> str | None:
        for k in ("departure", "keep_out", "rim_strike"):
            if k in self.events:
                return self.events[k]
        return None

    def classify(self, captured: bool, timed_out: bool) -> tuple[str, str | None]:
        """(outcome, reason)."""
        for k in ("departure", "keep_out"):
            if k in self.events:
                return k, self.events[k]
        if captured:
            return "captured", None
        if "rim_strike" in self.events:
            return "rim_strike", self.events["rim_strike"]
        if self.aborts_used and self.last_miss is not None:
            return "missed", self.last_miss
        if self.aborts_used:
            return "aborted", "break-aways used up"
        return "aborted", "time out" if timed_out else "not finished"
