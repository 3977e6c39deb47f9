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

import math
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from app.control.envelope import FlightData
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

    def flight_data(self) -> FlightData:
        """α, load factor, bank, pitch, KCAS and altitude now (the envelope monitor's view)."""
        ...

    def set_speedbrake(self, norm: float) -> None:
        """Command the speed brakes (0 in … 1 out), where the airframe has them."""
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
        self._w_dot = 0.0

    def reset(self, x0: FloatArray) -> FloatArray:
        self.x = np.asarray(x0, dtype=np.float64).copy()
        self._w_dot = 0.0
        return self.x

    def set_speedbrake(self, norm: float) -> None:
        """The design model has no speed brakes: nothing to do."""

    def flight_data(self) -> FlightData:
        """From the perturbation state about the model's trim: α = atan(w/u) of the body
        velocity, load factor ``cos θ cos φ + (u q − ẇ)/g``, KCAS scaled with the speed
        (small perturbations: the design model's own approximations)."""
        xa = np.asarray(self.model.x_trim, float) + self.x
        u, w, q, phi, theta = xa[0], xa[2], xa[4], xa[6], xa[7]
        speed = float(np.linalg.norm(xa[0:3]))
        trim_speed = float(np.linalg.norm(np.asarray(self.model.x_trim, float)[0:3])) or 1.0
        return FlightData(
            alpha_deg=math.degrees(math.atan2(w, u)),
            load_factor_g=math.cos(theta) * math.cos(phi) + (u * q - self._w_dot) / 9.80665,
            bank_deg=math.degrees(phi),
            pitch_deg=math.degrees(theta),
            kcas=self.trim.kcas * speed / trim_speed,
            altitude_m=self.trim.altitude_ft * 0.3048 - float(self.x[11]),
        )

    def step(self, u_dev: FloatArray, air_mps: FloatArray) -> FloatArray:
        w_before = float(self.x[2])
        self.x = self.ad @ self.x + self.bd @ np.asarray(u_dev) + self.ed @ np.asarray(air_mps)
        if self.offset.any():
            self.x = self.x + self.offset
        self._w_dot = (float(self.x[2]) - w_before) / self.dt
        return self.x
