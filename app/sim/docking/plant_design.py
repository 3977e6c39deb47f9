"""The receiver plant of a docking run: its trim and the controller designed on its
linearisation (:func:`plant_design`, cached), and the plant actually flown
(:func:`make_plant`: the design model, a perturbed aircraft, or JSBSim's A-4)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from app.control.design import (
    A4_WEIGHTS,
    AEROSONDE_WEIGHTS,
    ControllerDesign,
    design_controller,
)
from app.sim.docking.config import DockingConfig
from app.sim.imperfections import ImperfectionDraw, Imperfections
from app.sim.jsbsim_plant import JsbsimCondition, JsbsimPlant
from app.sim.plant import LinearPlant, ReceiverPlant, TrimPoint
from app.sim.receiver import FlightCondition, LinearReceiver, perturbed_params

LINEAR_AIRFRAME = "Aerosonde (the controller's linear design model)"
JSBSIM_FUEL_CAPACITY_LBS = 3000.0  # the A-4's one tank (JSBSim A4.xml), full in the design
# the least fuel a receiver comes to the tanker with (lb; ours): with an empty tank the J52
# flames out and the A-4 has no trim (FGTrim fails)
JSBSIM_RESERVE_FUEL_LBS = 300.0


@dataclass(frozen=True)
class PlantDesign:
    """A plant's trim and the controller designed on its linearisation."""

    design: ControllerDesign
    trim: TrimPoint
    airframe: str
    receiver: LinearReceiver | None  # the linear plant's nonlinear Aerosonde (perturbed copies)


@lru_cache(maxsize=8)
def plant_design(
    plant: str,
    tick_hz: float,
    probe: tuple[float, float, float],
    linear_condition: tuple[float, float, float],
    jsbsim_condition: JsbsimCondition,
) -> PlantDesign:
    """Trim, linearise and design (cached): ``linear_condition`` = (airspeed m/s, density
    kg/m³, altitude m) of the Aerosonde; ``jsbsim_condition`` the A-4's."""
    dt = 1.0 / tick_hz
    if plant == "linear":
        airspeed, density, altitude = linear_condition
        rec = LinearReceiver(condition=FlightCondition(airspeed_mps=airspeed, air_density=density))
        design = design_controller(rec.linear_model(), dt, probe, AEROSONDE_WEIGHTS)
        return PlantDesign(design, rec.trim_point(altitude), LINEAR_AIRFRAME, rec)
    fdm = JsbsimPlant(jsbsim_condition, tick_hz)
    design = design_controller(fdm.model, dt, probe, A4_WEIGHTS)
    return PlantDesign(design, fdm.trim, fdm.airframe, None)


def design_for(config: DockingConfig) -> PlantDesign:
    """:func:`plant_design` of a configuration (its plant, tick, probe and condition)."""
    return plant_design(
        config.plant,
        float(config.tick_hz),
        config.geometry().probe_tip_body_m,
        (config.airspeed_mps, config.air_density, config.altitude_m),
        config.jsbsim_condition(),
    )


def describe_plant(config: DockingConfig) -> dict[str, Any]:
    """``plant``, ``airframe`` and ``trim`` (TrimPoint fields) of a configuration, as
    ``simulate --json`` and ``summary.json`` report them."""
    pd = design_for(config)
    return {"plant": config.plant, "airframe": pd.airframe, "trim": pd.trim.to_dict()}


def make_plant(
    config: DockingConfig,
    pd: PlantDesign,
    imp: Imperfections,
    d: ImperfectionDraw,
    dt: float,
) -> ReceiverPlant:
    """The plant flown this run (``dt``: the tick, s). Linear: the design model itself unless
    perturbed; then the perturbed aircraft, trimmed and linearised on its own (``offset``
    carries the difference between the trims). JSBSim: the FDM at the design's condition —
    with the imperfections lighter than the design (fuel burned; the design is at full fuel)
    by up to twice the preset's mass fraction of its weight, never below a reserve (the A-4's
    tank sits at its CG, so the CG does not move)."""
    m = pd.design
    if config.plant == "jsbsim":
        fuel = None
        if imp.mass_frac > 0:
            full = JSBSIM_FUEL_CAPACITY_LBS
            burned = (1.0 + imp.mass_frac - d.mass_scale) * pd.trim.weight_lbs
            fuel = float(np.clip(full - burned, JSBSIM_RESERVE_FUEL_LBS, full))
        return JsbsimPlant(config.jsbsim_condition(fuel), config.tick_hz, m.model)
    if imp.aero_frac == 0 and imp.mass_frac == 0 or pd.receiver is None:
        return LinearPlant(m.model, dt, pd.airframe, pd.trim, (m.ad, m.bd, m.ed))
    rec = LinearReceiver(
        params=perturbed_params(pd.receiver.params, d.aero_scale, d.mass_scale, d.inertia_scale),
        condition=pd.receiver.condition,
    )
    ad, bd, ed = rec.discretise(dt)
    dx = m.model.x_trim - rec.x_trim  # design − plant trim (positions: 0)
    du = m.model.u_trim - rec.u_trim
    offset = np.asarray(ad @ dx + bd @ du - dx)
    return LinearPlant(rec.linear_model(), dt, pd.airframe, pd.trim, (ad, bd, ed), offset)
