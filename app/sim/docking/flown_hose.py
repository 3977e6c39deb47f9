"""The hose and drogue the docking loop flies (``DockingConfig.hose_model``), built from the
configuration, the plant's trim and the run's draw, and what the loop reports of it.

:func:`flown_drogue`: "reduced" — :class:`~app.sim.hose_drogue.HoseDrogue` (a second-order
swing on a static shape, welded to the probe at contact); "multibody" —
:class:`~app.sim.docking.multibody_drogue.MultibodyDrogue` (the lumped-mass hose with its reel
and coupling). Either is dispersed by the run's ``hose_scale`` (hose length, mass and drag, the
drogue's mass and drag) and ``bow_scale``; the guidance's own model of the drogue stays the
nominal one (:func:`nominal_drogue_model`; it identifies the flown swing online). :func:`hose_state` is the tick's record of the
hose, :func:`contact_report` the multi-body hose's contact (peak tension, whip, release).
"""

from __future__ import annotations

import math
from dataclasses import replace

from app.model.drogue import DrogueModel
from app.sim.docking.config import DockingConfig
from app.sim.docking.multibody_drogue import MultibodyDrogue, MultibodyDrogueParams
from app.sim.docking.results import HoseState
from app.sim.hose import (
    CouplingParams,
    CouplingReport,
    DrogueParams,
    FlowCondition,
    HoseParams,
    ReelParams,
)
from app.sim.hose_drogue import HoseDrogue, HoseDrogueParams
from app.sim.imperfections import ImperfectionDraw

FlownDrogue = HoseDrogue | MultibodyDrogue


def flown_drogue(
    cfg: DockingConfig,
    air_density_kgm3: float,
    airspeed_mps: float,
    draw: ImperfectionDraw,
    dt: float,
) -> FlownDrogue:
    """This run's hose and drogue (``cfg.hose_model``) at the trim's density (kg/m³) and true
    airspeed (m/s), dispersed by the run's ``draw``; ``dt`` the loop's tick (s)."""
    hs = draw.hose_scale
    bow_n = cfg.bow_wave_force_n * draw.bow_scale
    if cfg.hose_model == "multibody":
        hose, drogue = HoseParams(), DrogueParams(radius_m=cfg.ring_radius_m)
        return MultibodyDrogue(
            MultibodyDrogueParams(
                flow=FlowCondition(air_density_kgm3, airspeed_mps),
                hose=replace(
                    hose,
                    length_m=hose.length_m * hs["hose_length"],
                    mass_per_m_kg=hose.mass_per_m_kg * hs["hose_mass"],
                    cd_normal=hose.cd_normal * hs["hose_drag"],
                    cd_tangential=hose.cd_tangential * hs["hose_drag"],
                ),
                drogue=replace(
                    drogue,
                    mass_kg=drogue.mass_kg * hs["drogue_mass"],
                    cd=drogue.cd * hs["drogue_drag"],
                ),
                reel=ReelParams(),
                coupling=CouplingParams(
                    min_closure_mps=cfg.min_closure_mps, max_closure_mps=cfg.max_closure_mps
                ),
                bow_force_n=bow_n,
                wake_downwash_mps=draw.wake_downwash_mps,
                wake_sidewash_per_m=draw.wake_sidewash_per_m,
            ),
            dt,
        )
    return HoseDrogue(
        HoseDrogueParams(
            hose_length_m=HoseDrogueParams.hose_length_m * hs["hose_length"],
            hose_mass_per_m=HoseDrogueParams.hose_mass_per_m * hs["hose_mass"],
            drogue_mass_kg=HoseDrogueParams.drogue_mass_kg * hs["drogue_mass"],
            drogue_cd=HoseDrogueParams.drogue_cd * hs["drogue_drag"],
            air_density=air_density_kgm3,
            airspeed_mps=airspeed_mps,
            drogue_radius_m=cfg.ring_radius_m,
            bow_force_n=bow_n,
        )
    )


def hose_state(drogue: FlownDrogue) -> HoseState:
    """The flown hose now: its nodes; the multi-body hose's tension, payout, contact peak."""
    if not isinstance(drogue, MultibodyDrogue):
        return HoseState(nodes_m=drogue.hose_nodes_m())
    peak = drogue.peak_contact_tension_n
    return HoseState(
        nodes_m=drogue.hose_nodes_m(),
        tension_n=drogue.tension_n,
        payout_m=drogue.payout_m,
        contact_peak_tension_n=None if math.isnan(peak) else peak,
    )


def contact_report(drogue: FlownDrogue) -> CouplingReport | None:
    """The multi-body hose's contact (None before one, and for the reduced model)."""
    return drogue.contact_report() if isinstance(drogue, MultibodyDrogue) else None


def nominal_drogue_model(
    cfg: DockingConfig, air_density_kgm3: float, airspeed_mps: float
) -> DrogueModel:
    """The guidance's model: the nominal hose type (reduced-order, undispersed) at this flight
    condition — never this run's draw nor the multi-body hose's parameters."""
    return HoseDrogueParams(
        air_density=air_density_kgm3,
        airspeed_mps=airspeed_mps,
        drogue_radius_m=cfg.ring_radius_m,
        bow_force_n=cfg.bow_wave_force_n,
    ).guidance_model()
