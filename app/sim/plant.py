"""The receiver plant the docking simulation flies: one interface, two implementations.

Every plant speaks the design model's coordinates (:mod:`app.control.linear_model`): the
perturbation state about straight-and-level trim, the deviation of the four commands from
trim, the air's velocity in tanker axes.

* :class:`LinearPlant` — the linear model ``x⁺ = A_d x + B_d δ + E_d g + c`` at the tick
  (zero-order hold). **This is a design model**: the LQR and the observer are designed on the
  very same matrices, so a run on it says how the controller does on its own assumptions,
  nothing more. Kept for fast unit tests and as a secondary row of the docking tables.
* :class:`~app.sim.jsbsim_plant.JsbsimPlant` — JSBSim's nonlinear 6-DoF FDM, integrated by
  JSBSim at ≥ 120 Hz every tick (the default; :mod:`app.sim.jsbsim_plant`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from app.control.linear_model import LinearModel
from app.types import FloatArray

PLANTS = ("jsbsim", "linear")
# the plant of DockingConfig, the CLI and the service's simulated stream when none is named
DEFAULT_PLANT: Literal["jsbsim", "linear"] = "jsbsim"


@dataclass(frozen=True)
class TrimPoint:
    """The flight condition and trim of a plant (as reported in ``summary.json``)."""

    altitude_ft: float
    kcas: float  # calibrated airspeed, kt
    tas_mps: float  # true airspeed, m/s
    alpha_deg: float
    theta_deg: float
    throttle: float  # command, 0–1
    weight_lbs: float
    air_density_kgm3: float
    mach: float

    def to_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in self.__dict__.items()}


class ReceiverPlant(Protocol):
    """What the docking simulation needs of a receiver plant."""

    name: str  # "jsbsim" | "linear"
    airframe: str  # e.g. "A-4 Skyhawk (JSBSim A4)"
    trim: TrimPoint

    @property
    def model(self) -> LinearModel:
        """The plant's own linearisation about its trim."""
        ...

    def reset(self, x0: FloatArray) -> FloatArray:
        """Start at trim + ``x0`` (only the position may be non-zero for every plant);
        returns the state."""
        ...

    def step(self, u_dev: FloatArray, air_mps: FloatArray) -> FloatArray:
        """Advance one tick with the deflections ``u_dev`` (deviation from trim) and the air's
        velocity ``air_mps`` (tanker axes); returns the new state."""
        ...


class LinearPlant:
    """The linear model at the tick: ``x⁺ = A_d x + B_d δ + E_d g + c`` (module docstring).

    ``offset`` c carries the difference between this plant's trim and the design model's when
    the plant is a perturbed copy of it (:mod:`app.sim.imperfections`)."""

    name = "linear"

    def __init__(
        self,
        model: LinearModel,
        dt: float,
        airframe: str,
        trim: TrimPoint,
        discrete: tuple[FloatArray, FloatArray, FloatArray] | None = None,
        offset: FloatArray | None = None,
    ) -> None:
        self.model = model
        self.airframe = airframe
        self.trim = trim
        self.dt = float(dt)
        self.ad, self.bd, self.ed = discrete if discrete is not None else model.discretise(dt)
        self.offset = np.zeros(12) if offset is None else np.asarray(offset, dtype=np.float64)
        self.x = np.zeros(12)

    def reset(self, x0: FloatArray) -> FloatArray:
        self.x = np.asarray(x0, dtype=np.float64).copy()
        return self.x

    def step(self, u_dev: FloatArray, air_mps: FloatArray) -> FloatArray:
        self.x = self.ad @ self.x + self.bd @ np.asarray(u_dev) + self.ed @ np.asarray(air_mps)
        if self.offset.any():
            self.x = self.x + self.offset
        return self.x
