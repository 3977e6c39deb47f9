"""Run-time assurance (simplex) for the docking loop: the flown state's envelope, the
separation from the tanker and the hose, and the monitor that hands control to the recovery
law (:mod:`app.control.recovery`) before a bound is crossed.

Two sets of bounds:

* :class:`EnvelopeBounds` — the monitor's. Crossing one needs a recovery: the performance
  controller is switched off, the recovery law flies, and the run is a ``departure``
  (:mod:`app.sim.docking.outcomes`). They sit inside the flight-test limits the acceptance
  watches from JSBSim (α −2…12°, load factor −0.5…3 g, bank ±60°, 150 m of height lost,
  180–290 KCAS), so that the recovery starts before a limit is reached.
* :class:`SeparationBounds` — the receiver's clearance from the tanker (a keep-out plane
  behind the hose exit) and from the hose (its static line, deflected with the drogue): below
  ``*_break_away_m`` the guidance breaks away; below ``*_keep_out_m`` the run is
  ``keep_out``.

A-4 defaults and their sources: refuelling is flown within a few degrees of trim α (3.55° at
15 000 ft / 230 KCAS), near 1 g and a few degrees of bank (../shared/notes/gnc.md,
"Envelope during refuelling"); the A-4's stall is at α ≈ 15–17° (JSBSim's A4 aero tables);
the monitor's margins to the flight-test limits are ours (docs/control.md, "Safety").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from app.types import FloatArray


@dataclass(frozen=True)
class FlightData:
    """What the monitor reads of the flown aircraft (the plant's own values: JSBSim's
    properties for the A-4)."""

    alpha_deg: float
    load_factor_g: float  # normal load factor, +1 in level flight
    bank_deg: float
    pitch_deg: float
    kcas: float
    altitude_m: float

    def finite(self) -> bool:
        return all(math.isfinite(v) for v in self.__dict__.values())


@dataclass(frozen=True)
class EnvelopeBounds:
    """The monitor's envelope (A-4 defaults; module docstring)."""

    alpha_min_deg: float = -1.0
    alpha_max_deg: float = 10.0
    load_factor_min_g: float = 0.0
    load_factor_max_g: float = 2.5
    bank_max_deg: float = 45.0
    pitch_max_deg: float = 20.0
    pitch_min_deg: float = -15.0
    kcas_min: float = 195.0
    kcas_max: float = 275.0
    height_loss_max_m: float = 100.0

    def validate(self) -> None:
        for name, v in self.__dict__.items():
            if not math.isfinite(v):
                raise ValueError(f"envelope bound {name} must be finite, got {v!r}")
        if not (self.alpha_min_deg < self.alpha_max_deg and self.kcas_min < self.kcas_max):
            raise ValueError("envelope bounds: each minimum must be below its maximum")
        if not self.load_factor_min_g < 1.0 < self.load_factor_max_g:
            raise ValueError("envelope bounds: the load factor range must contain 1 g")


@dataclass(frozen=True)
class SeparationBounds:
    """Clearances (m) from the tanker and the hose (module docstring)."""

    # the tanker's keep-out plane lies this far behind the hose exit (the hose is 15 m long;
    # the tanker's structure ends at the hose exit)
    tanker_plane_aft_m: float = 6.0
    tanker_break_away_m: float = 3.0
    tanker_keep_out_m: float = 0.0
    # the receiver's nose from the hose's line, leaving out the last ``hose_end_skip_m`` at
    # the drogue (where the probe is meant to be)
    hose_end_skip_m: float = 2.0
    hose_break_away_m: float = 1.5
    hose_keep_out_m: float = 0.5
    # the probe tip above the drogue's centre (m): above it the receiver climbs into the hose
    tip_above_drogue_break_away_m: float = 1.5
    tip_above_drogue_gap_m: float = 5.0  # … when closer than this behind it (m)


@dataclass(frozen=True)
class Separation:
    """The receiver's clearance now (m)."""

    tanker_m: float  # nose aft of the tanker's keep-out plane
    hose_m: float  # nose from the hose line
    tip_above_drogue_m: float  # probe tip above the drogue centre (negative: below)
    gap_m: float  # probe tip behind the drogue centre


def point_to_polyline_m(point: FloatArray, nodes: FloatArray) -> float:
    """Distance (m) from a point to a polyline (nodes in order, ≥ 2)."""
    p = np.asarray(point, float)
    a, b = nodes[:-1], nodes[1:]
    ab = b - a
    t = np.clip(
        np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12), 0, 1
    )
    closest = a + t[:, None] * ab
    return float(np.min(np.linalg.norm(closest - p, axis=1)))


def separation(
    nose_m: FloatArray,
    tip_m: FloatArray,
    drogue_m: FloatArray,
    hose_nodes_m: FloatArray,
    bounds: SeparationBounds,
) -> Separation:
    """Clearances of the nose and probe tip (tanker frame, m; hose nodes from the exit to the
    drogue)."""
    nodes = np.asarray(hose_nodes_m, float)
    seg = np.linalg.norm(np.diff(nodes, axis=0), axis=1)
    from_end = np.concatenate([np.cumsum(seg[::-1])[::-1], [0.0]])
    keep = nodes[from_end >= bounds.hose_end_skip_m]
    hose = point_to_polyline_m(nose_m, keep) if len(keep) >= 2 else math.inf
    tanker = float(-bounds.tanker_plane_aft_m - nose_m[0])
    above = float(drogue_m[2] - tip_m[2])  # z down
    return Separation(tanker, hose, above, float(drogue_m[0] - tip_m[0]))


@dataclass
class EnvelopeExtremes:
    """The run's extremes of the monitored quantities (reported with its outcome)."""

    alpha_min_deg: float = math.inf
    alpha_max_deg: float = -math.inf
    load_factor_min_g: float = math.inf
    load_factor_max_g: float = -math.inf
    bank_max_deg: float = 0.0
    kcas_min: float = math.inf
    kcas_max: float = -math.inf
    height_lost_m: float = 0.0
    min_tanker_separation_m: float = math.inf
    min_hose_separation_m: float = math.inf

    def add(self, f: FlightData, start_altitude_m: float, sep: Separation | None) -> None:
        self.alpha_min_deg = min(self.alpha_min_deg, f.alpha_deg)
        self.alpha_max_deg = max(self.alpha_max_deg, f.alpha_deg)
        self.load_factor_min_g = min(self.load_factor_min_g, f.load_factor_g)
        self.load_factor_max_g = max(self.load_factor_max_g, f.load_factor_g)
        self.bank_max_deg = max(self.bank_max_deg, abs(f.bank_deg))
        self.kcas_min = min(self.kcas_min, f.kcas)
        self.kcas_max = max(self.kcas_max, f.kcas)
        self.height_lost_m = max(self.height_lost_m, start_altitude_m - f.altitude_m)
        if sep is not None:
            self.min_tanker_separation_m = min(self.min_tanker_separation_m, sep.tanker_m)
            self.min_hose_separation_m = min(self.min_hose_separation_m, sep.hose_m)

    def to_dict(self) -> dict[str, float | None]:
        return {k: (float(v) if math.isfinite(v) else None) for k, v in self.__dict__.items()}


@dataclass
class EnvelopeMonitor:
    """Checks each tick's flight data against :class:`EnvelopeBounds` (a recovery, hence a
    departure) and the separation against :class:`SeparationBounds` (a break-away, or a
    keep-out violation)."""

    bounds: EnvelopeBounds = field(default_factory=EnvelopeBounds)
    separation_bounds: SeparationBounds = field(default_factory=SeparationBounds)

    def envelope_violation(self, f: FlightData, start_altitude_m: float) -> str | None:
        """Why a recovery is needed now (None: inside the envelope)."""
        b = self.bounds
        if not f.finite():
            return "flight state not finite (diverged)"
        checks = (
            (f.alpha_deg < b.alpha_min_deg, f"α {f.alpha_deg:.1f}° below {b.alpha_min_deg}°"),
            (f.alpha_deg > b.alpha_max_deg, f"α {f.alpha_deg:.1f}° above {b.alpha_max_deg}°"),
            (
                f.load_factor_g < b.load_factor_min_g,
                f"load factor {f.load_factor_g:.2f} g below {b.load_factor_min_g} g",
            ),
            (
                f.load_factor_g > b.load_factor_max_g,
                f"load factor {f.load_factor_g:.2f} g above {b.load_factor_max_g} g",
            ),
            (abs(f.bank_deg) > b.bank_max_deg, f"bank {f.bank_deg:.1f}° beyond ±{b.bank_max_deg}°"),
            (f.pitch_deg > b.pitch_max_deg, f"pitch {f.pitch_deg:.1f}° above {b.pitch_max_deg}°"),
            (f.pitch_deg < b.pitch_min_deg, f"pitch {f.pitch_deg:.1f}° below {b.pitch_min_deg}°"),
            (f.kcas < b.kcas_min, f"airspeed {f.kcas:.0f} KCAS below {b.kcas_min}"),
            (f.kcas > b.kcas_max, f"airspeed {f.kcas:.0f} KCAS above {b.kcas_max}"),
            (
                start_altitude_m - f.altitude_m > b.height_loss_max_m,
                f"{start_altitude_m - f.altitude_m:.0f} m of height lost (> {b.height_loss_max_m} m)",
            ),
        )
        return next((why for crossed, why in checks if crossed), None)

    def break_away_reason(self, sep: Separation) -> str | None:
        """Why the guidance must break away for clearance (None: clear)."""
        s = self.separation_bounds
        if sep.tanker_m < s.tanker_break_away_m:
            return f"too close to the tanker ({sep.tanker_m:.1f} m from its keep-out plane)"
        if sep.hose_m < s.hose_break_away_m:
            return f"too close to the hose ({sep.hose_m:.2f} m)"
        if (
            sep.tip_above_drogue_m > s.tip_above_drogue_break_away_m
            and sep.gap_m < s.tip_above_drogue_gap_m
        ):
            return f"probe {sep.tip_above_drogue_m:.1f} m above the drogue"
        return None

    def keep_out_violation(self, sep: Separation) -> str | None:
        s = self.separation_bounds
        if sep.tanker_m < s.tanker_keep_out_m:
            return "inside the tanker's keep-out zone"
        if sep.hose_m < s.hose_keep_out_m:
            return f"nose {sep.hose_m:.2f} m from the hose (keep-out {s.hose_keep_out_m} m)"
        return None
