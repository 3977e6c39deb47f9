"""The design model: a receiver linearised about its trim, with what a design needs besides
the matrices (trim values, input names, limits and lags).

Coordinates (every plant speaks them, :mod:`app.sim.plant`): the state is the perturbation
about straight-and-level trim ``x = [u, v, w, p, q, r, φ, θ, ψ, x, y, z]`` — body-axis velocity
over the ground (m/s), body rates (rad/s), Euler angles (rad, 3-2-1) and the centre-of-gravity
position in the tanker frame (m; x forward, y right, z down; the tanker flies at the trim ground
speed); the input is the deviation from trim of the four commands in ``input_names``; the third
input is the air's velocity (gusts, wake; m/s, tanker axes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from app.types import FloatArray


@dataclass(frozen=True)
class ActuatorLimits:
    """Position (lower, upper) relative to nothing (absolute) and rate limits per input."""

    lower: tuple[float, float, float, float] = (
        0.0,
        -np.deg2rad(25),
        -np.deg2rad(25),
        -np.deg2rad(25),
    )
    upper: tuple[float, float, float, float] = (1.0, np.deg2rad(25), np.deg2rad(25), np.deg2rad(25))
    rate: tuple[float, float, float, float] = (1.0, np.deg2rad(60), np.deg2rad(60), np.deg2rad(60))


@dataclass(frozen=True)
class LinearModel:
    """``ẋ = A x + B δ + E g`` about a trim (continuous time, the coordinates of the module
    docstring) with what a design needs besides: the trim values, the input names and limits,
    and each input's lag (s; the engine's spool-up on the throttle, servos on the surfaces)
    which the matrices do not contain."""

    a: FloatArray  # (12, 12)
    b: FloatArray  # (12, 4)
    e: FloatArray  # (12, 3), air velocity in tanker axes (m/s)
    x_trim: FloatArray  # (12,) absolute trim state (u, v, w m/s, …; position 0)
    u_trim: FloatArray  # (4,) absolute trim inputs
    input_names: tuple[str, str, str, str]
    limits: ActuatorLimits
    input_lag_s: tuple[float, float, float, float]
    airspeed_mps: float  # true airspeed at trim (the tanker's speed)

    @property
    def theta0(self) -> float:
        """Trim pitch angle (rad)."""
        return float(self.x_trim[7])

    def discretise(self, dt: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Zero-order-hold ``(A_d, B_d, E_d)`` at step ``dt`` (s)."""
        n, m, k = 12, self.b.shape[1], self.e.shape[1]
        big = np.zeros((n + m + k, n + m + k))
        big[:n, :n] = self.a
        big[:n, n : n + m] = self.b
        big[:n, n + m :] = self.e
        ed = expm(big * dt)
        return ed[:n, :n], ed[:n, n : n + m], ed[:n, n + m :]
