"""Parameters of the multi-body hose, its drogue and its reel (SI units; sources in
``docs/models.md``, "Multi-body hose").

Defaults: the flight-scale set of the public lumped-hose AAR simulator RflySimAAR
(``HoseDrogue_Parameter.m``, commonly traced to Ro & Kamman, JGCD 33(1), 2010): hose 15 m,
4.1 kg/m, outer radius 0.0336 m; drogue 29.5 kg, radius 0.305 m, C_d 0.8; hose cross-flow
C_n 1.2 (the same project's cylinder table, sub-critical cross-flow Reynolds number). The
tangential (skin-friction) coefficient 0.004 is that project's ``C_f = 0.0464 Re^-1/6`` at the
Reynolds numbers of refuelling (10⁶–10⁷). Axial stiffness, its damping and the reel's law are
ours (documented estimates).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

GRAVITY = 9.80665


def _positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


@dataclass(frozen=True)
class HoseParams:
    """The hose: trailed length at full trail, linear mass, outer diameter, cross-flow drag
    coefficients (normal ``½ρ d C_n (U sin φ)²`` and tangential ``½ρ π d C_t (U cos φ)²`` per
    metre), axial stiffness EA (N) with a damping ratio on one segment's axial mode, and the
    number of segments (nodes = segments + 1, the reel exit first)."""

    length_m: float = 15.0
    mass_per_m_kg: float = 4.1
    diameter_m: float = 0.0672
    cd_normal: float = 1.2
    cd_tangential: float = 0.004
    axial_stiffness_n: float = 5.0e5
    axial_damping_ratio: float = 0.3
    segments: int = 20

    def __post_init__(self) -> None:
        for name in ("length_m", "mass_per_m_kg", "diameter_m", "axial_stiffness_n"):
            _positive(name, getattr(self, name))
        for name in ("cd_normal", "cd_tangential", "axial_damping_ratio"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be a finite number ≥ 0, got {v!r}")
        if not (isinstance(self.segments, int) and 2 <= self.segments <= 400):
            raise ValueError(f"segments must be an integer in 2–400, got {self.segments!r}")


@dataclass(frozen=True)
class DrogueParams:
    """The drogue (basket and coupling) as a point mass with drag ``½ρ C_d A |u| u``."""

    mass_kg: float = 29.5
    cd: float = 0.8
    radius_m: float = 0.305

    def __post_init__(self) -> None:
        for name in ("mass_kg", "cd", "radius_m"):
            _positive(name, getattr(self, name))

    @property
    def area_m2(self) -> float:
        return math.pi * self.radius_m**2


@dataclass(frozen=True)
class ReelParams:
    """The hose drum unit's tension-controlled take-up (ours: a documented estimate).

    The reel holds the hose at full trail against its stop while the tension at the reel exit
    is above ``setpoint_fraction`` × the trail tension; below it the reel takes up at a commanded
    speed ``gain`` × (tension − set point) (m/s per N; negative: take-up), reached with the
    first-order ``response_time_s``, limited to ``max_speed_mps``, down to ``max_take_up_m``."""

    setpoint_fraction: float = 0.8
    gain_mps_per_n: float = 0.01
    response_time_s: float = 0.1
    max_speed_mps: float = 4.0
    max_take_up_m: float = 6.0

    def __post_init__(self) -> None:
        for name in ("gain_mps_per_n", "response_time_s", "max_speed_mps", "max_take_up_m"):
            _positive(name, getattr(self, name))
        if not (0.0 < self.setpoint_fraction < 1.0):
            raise ValueError(f"setpoint_fraction must be in (0, 1), got {self.setpoint_fraction!r}")


@dataclass(frozen=True)
class CouplingParams:
    """The reception coupling: it latches when the probe head enters at a closure inside the
    latch window (m/s; ≤ 5 kt, slower does not latch — ``app.sim.docking.outcomes``) and lets go
    when the hose pulls the coupling off the probe (forward) harder than ``release_load_n``
    (ours: a placeholder of the order of the drogue's drag, no published figure held here).
    A hose that goes slack while latched is a whip when its tension then exceeds
    ``whip_tension_factor`` × the trail tension."""

    min_closure_mps: float = 1.0
    max_closure_mps: float = 2.6
    release_load_n: float = 4000.0
    whip_tension_factor: float = 1.5
    stiffness_n_per_m: float = 2.0e4
    damping_n_s_per_m: float = 1500.0

    def __post_init__(self) -> None:
        if not (0.0 <= self.min_closure_mps < self.max_closure_mps):
            raise ValueError("the latch window must satisfy 0 ≤ min < max closure")
        _positive("release_load_n", self.release_load_n)
        for name in ("whip_tension_factor", "stiffness_n_per_m", "damping_n_s_per_m"):
            _positive(name, getattr(self, name))
