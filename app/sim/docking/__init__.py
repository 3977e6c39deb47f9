"""Closed-loop probe-and-drogue docking (paper §6, Fig. 13, Algorithm 3), tick by tick.

* :mod:`~app.sim.docking.config` — the scenario (:class:`DockingConfig`), the plants' default
  guidance and the airframes' geometry;
* :mod:`~app.sim.docking.plant_design` — trim, linearisation and controller design per plant,
  and the plant flown (design model, perturbed aircraft, JSBSim's A-4);
* :mod:`~app.sim.docking.vision` — the stereo camera in the loop (render, track, measure);
* :mod:`~app.sim.docking.multibody_drogue` — the multi-body hose flown by the loop
  (``hose_model="multibody"``);
* :mod:`~app.sim.docking.guidance` — the guidance's model of the drogue's swing and bow wave;
* :mod:`~app.sim.docking.simulation` — :class:`DockingSimulation`, the closed loop's step;
* :mod:`~app.sim.docking.results` — a tick, the outcome, a per-tick log.
"""

from app.control.reference import PHASES  # the reference trajectory's phases
from app.sim.docking.config import (
    AIRFRAME_GEOMETRY,
    HOSE_MODELS,
    PLANT_GUIDANCE,
    AirframeGeometry,
    DockingConfig,
    PlantGuidance,
)
from app.sim.docking.plant_design import PlantDesign, describe_plant, design_for, plant_design
from app.sim.docking.results import DockingOutcome, DockingTick, HoseState, TickLog
from app.sim.docking.simulation import DockingSimulation

__all__ = [
    "AIRFRAME_GEOMETRY",
    "HOSE_MODELS",
    "HoseState",
    "PHASES",
    "PLANT_GUIDANCE",
    "AirframeGeometry",
    "DockingConfig",
    "DockingOutcome",
    "DockingSimulation",
    "DockingTick",
    "PlantDesign",
    "PlantGuidance",
    "TickLog",
    "describe_plant",
    "design_for",
    "plant_design",
]
