"""The two drogues of a run: the one flown (this run's draw of the hose and drogue,
:mod:`app.sim.imperfections`) and the guidance's nominal model of the hose type (what the
guidance knows; it identifies the flown swing online, :mod:`app.control.swing_identifier`).
Both at the plant's flight condition (its trim: air density, true airspeed)."""

from __future__ import annotations

from app.control.drogue_model import DrogueModel
from app.sim.docking.config import DockingConfig
from app.sim.hose_drogue import HoseDrogue, HoseDrogueParams
from app.sim.imperfections import ImperfectionDraw


def flown_drogue(
    config: DockingConfig, air_density_kgm3: float, tas_mps: float, draw: ImperfectionDraw
) -> HoseDrogue:
    """This run's hose and drogue: the nominal set scaled by the draw's hose factors, and the
    bow wave's strength by its ``bow_scale``."""
    hs = draw.hose_scale
    return HoseDrogue(
        HoseDrogueParams(
            hose_length_m=HoseDrogueParams.hose_length_m * hs["hose_length"],
            hose_mass_per_m=HoseDrogueParams.hose_mass_per_m * hs["hose_mass"],
            drogue_mass_kg=HoseDrogueParams.drogue_mass_kg * hs["drogue_mass"],
            drogue_cd=HoseDrogueParams.drogue_cd * hs["drogue_drag"],
            air_density=air_density_kgm3,
            airspeed_mps=tas_mps,
            drogue_radius_m=config.ring_radius_m,
            bow_force_n=config.bow_wave_force_n * draw.bow_scale,
        )
    )


def nominal_drogue_model(
    config: DockingConfig, air_density_kgm3: float, tas_mps: float
) -> DrogueModel:
    """The guidance's model: the nominal hose type at this flight condition (never this
    run's draw)."""
    return HoseDrogueParams(
        air_density=air_density_kgm3,
        airspeed_mps=tas_mps,
        drogue_radius_m=config.ring_radius_m,
        bow_force_n=config.bow_wave_force_n,
    ).guidance_model()
