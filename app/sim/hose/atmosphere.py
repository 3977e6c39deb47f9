"""The flight condition of the hose from altitude and calibrated airspeed: ISA and CAS → TAS.

International Standard Atmosphere (ICAO Doc 7488 / ISO 2533), troposphere (lapse 6.5 K/km up
to 11 km) and the isothermal layer above (to 20 km); calibrated airspeed to true airspeed with
the subsonic compressible pitot relation (impact pressure from CAS at sea level, Mach from the
impact pressure at altitude). ``tests/sim/test_hose_atmosphere.py`` checks both against
JSBSim's own atmosphere (``ic/vc-kts`` → ``velocities/vt-fps``, ``atmosphere/rho``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

FT_M = 0.3048
KT_MPS = 0.514444
G0 = 9.80665  # m/s²
R_AIR = 287.05287  # J/(kg K)
GAMMA = 1.4
T0_K, P0_PA = 288.15, 101325.0
LAPSE_K_PER_M = 0.0065
TROPOPAUSE_M = 11000.0
A0_MPS = math.sqrt(GAMMA * R_AIR * T0_K)
MAX_MACH = 0.9  # the subsonic pitot relation; refuelling is flown well below it


@dataclass(frozen=True)
class FlowCondition:
    """The free stream the hose trails in: density (kg/m³) and true airspeed (m/s)."""

    air_density_kgm3: float
    airspeed_mps: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.air_density_kgm3) and self.air_density_kgm3 > 0.0):
            raise ValueError(f"air density must be > 0 kg/m³, got {self.air_density_kgm3!r}")
        if not (math.isfinite(self.airspeed_mps) and self.airspeed_mps > 0.0):
            raise ValueError(f"airspeed must be > 0 m/s, got {self.airspeed_mps!r}")


def isa(altitude_m: float) -> tuple[float, float, float]:
    """(temperature K, pressure Pa, density kg/m³) of the ISA at a geopotential altitude
    0–20 km."""
    if not (0.0 <= altitude_m <= 20000.0):
        raise ValueError(f"altitude must be in 0–20 000 m, got {altitude_m!r}")
    if altitude_m <= TROPOPAUSE_M:
        t = T0_K - LAPSE_K_PER_M * altitude_m
        p = P0_PA * (t / T0_K) ** (G0 / (LAPSE_K_PER_M * R_AIR))
    else:
        t = T0_K - LAPSE_K_PER_M * TROPOPAUSE_M
        p11 = P0_PA * (t / T0_K) ** (G0 / (LAPSE_K_PER_M * R_AIR))
        p = p11 * math.exp(-G0 * (altitude_m - TROPOPAUSE_M) / (R_AIR * t))
    return t, p, p / (R_AIR * t)


def flow_from_kcas(altitude_ft: float, kcas: float) -> FlowCondition:
    """The ISA density and the true airspeed at ``altitude_ft`` flying ``kcas`` (calibrated
    airspeed, kt). Raises ``ValueError`` outside 0–40 000 ft, 50–450 KCAS or above Mach 0.9."""
    if not (0.0 <= altitude_ft <= 40000.0):
        raise ValueError(f"altitude must be in 0–40 000 ft, got {altitude_ft!r}")
    if not (50.0 <= kcas <= 450.0):
        raise ValueError(f"calibrated airspeed must be in 50–450 kt, got {kcas!r}")
    t, p, rho = isa(altitude_ft * FT_M)
    vc = kcas * KT_MPS
    qc = P0_PA * ((1.0 + 0.5 * (GAMMA - 1.0) * (vc / A0_MPS) ** 2) ** (GAMMA / (GAMMA - 1.0)) - 1.0)
    mach = math.sqrt(2.0 / (GAMMA - 1.0) * ((qc / p + 1.0) ** ((GAMMA - 1.0) / GAMMA) - 1.0))
    if mach >= MAX_MACH:
        raise ValueError(
            f"{kcas:.0f} KCAS at {altitude_ft:.0f} ft is Mach {mach:.2f}: above {MAX_MACH}"
        )
    return FlowCondition(air_density_kgm3=rho, airspeed_mps=mach * math.sqrt(GAMMA * R_AIR * t))
