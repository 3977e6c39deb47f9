"""Multi-body (lumped-mass) hose with its drogue, reel and coupling.

A standalone model with an API for the closed loop: :class:`MultibodyHose` (one tick at a
time, with the air-field, drogue-force and probe hooks), :class:`Coupling` (latch, release,
whip report), :func:`steady_shape` and :func:`swing_modes`. ``docs/models.md`` ("Multi-body
hose") has the equations, parameters, sources and validation figures.
"""

from app.sim.hose.atmosphere import FlowCondition, flow_from_kcas
from app.sim.hose.contact import Coupling, CouplingReport, SlackSample, push_in, push_in_path
from app.sim.hose.model import (
    AirField,
    FrozenGust,
    HoseTick,
    MultibodyHose,
    combined,
    wake_field,
)
from app.sim.hose.params import CouplingParams, DrogueParams, HoseParams, ReelParams
from app.sim.hose.steady import SteadyShape, SwingMode, SwingModes, steady_shape, swing_modes

__all__ = [
    "AirField",
    "CouplingReport",
    "Coupling",
    "CouplingParams",
    "DrogueParams",
    "FlowCondition",
    "FrozenGust",
    "HoseParams",
    "HoseTick",
    "MultibodyHose",
    "ReelParams",
    "SlackSample",
    "SteadyShape",
    "SwingMode",
    "SwingModes",
    "combined",
    "flow_from_kcas",
    "push_in",
    "push_in_path",
    "steady_shape",
    "swing_modes",
    "wake_field",
]
