"""The trailing hose at rest and its small swings: the steady shape of the lumped-mass model
in a uniform stream, and the linearised model's modes (numerical Jacobian, ``scipy.linalg.eig``).

Steady shape: in a uniform stream the equilibrium of the chain is found by marching from the
drogue to the reel exit. The tension vector of segment j balances every force on the nodes
beyond it, ``T_j t̂_j = Σ_{i ≥ j} F_i`` (weight, the drogue's drag, the aerodynamic load of the
segments beyond j and half of segment j's own, which depends on t̂_j: a fixed-point iteration);
the segment's length is ``ℓ (1 + T_j/EA)``; the shape is then shifted so that the reel exit sits
at the origin (a uniform stream does not depend on position). The tests check that the forces
of :func:`app.sim.hose.kernels.forces` vanish at the result.

Swing: the state (positions and velocities of the free nodes, the reel on its stop) is
linearised about the steady shape by central differences of the same forces; eigenvalues
``λ = −ζω ± iω√(1−ζ²)``. The lateral mode is the slowest oscillatory mode whose motion is mostly
sideways (y), the vertical the slowest oscillatory mode in the vertical plane.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import eig

from app.sim.hose.atmosphere import FlowCondition
from app.sim.hose.kernels import (
    HP_CN,
    HP_CT,
    HP_DIAMETER,
    HP_DROGUE_CDA,
    HP_DROGUE_MASS,
    HP_EA,
    HP_GRAVITY,
    HP_LAMBDA,
    HP_RHO,
    forces,
    node_masses,
    pack_hose,
)
from app.sim.hose.params import DrogueParams, HoseParams
from app.types import FloatArray


@dataclass(frozen=True)
class SteadyShape:
    """The hose at rest: ``nodes_m`` (n+1, 3) from the reel exit (origin, first) to the drogue
    (last), tanker frame (x forward, y right, z down); ``tensions_n`` per segment (reel first);
    ``payout_m`` the trailed length."""

    nodes_m: FloatArray
    tensions_n: FloatArray
    payout_m: float

    @property
    def reel_tension_n(self) -> float:
        return float(self.tensions_n[0])

    @property
    def drogue_m(self) -> FloatArray:
        return np.asarray(self.nodes_m[-1])


@dataclass(frozen=True)
class SwingMode:
    """One oscillatory mode: frequency (Hz, damped), damping ratio, and the shape (node
    displacements (n+1, 3), reel exit first, the largest set to 1 m)."""

    frequency_hz: float
    damping_ratio: float
    shape_m: FloatArray


@dataclass(frozen=True)
class SwingModes:
    lateral: SwingMode
    vertical: SwingMode


def _segment_aero(u: FloatArray, t: FloatArray, rest: float, hp: FloatArray) -> FloatArray:
    ut = float(u @ t)
    un = u - ut * t
    qn = 0.5 * hp[HP_RHO] * hp[HP_DIAMETER] * hp[HP_CN] * rest
    qt = 0.5 * hp[HP_RHO] * math.pi * hp[HP_DIAMETER] * hp[HP_CT] * rest
    return np.asarray(qn * np.linalg.norm(un) * un + qt * abs(ut) * ut * t)


def steady_shape(
    flow: FlowCondition,
    hose: HoseParams,
    drogue: DrogueParams,
    payout_m: float | None = None,
    wind_mps: FloatArray | None = None,
) -> SteadyShape:
    """Equilibrium of the lumped-mass hose (module docstring) at ``payout_m`` (default: full
    trail) in the free stream plus a uniform ``wind_mps`` (tanker frame)."""
    hp = pack_hose(flow, hose, drogue)
    n = hose.segments
    payout = hose.length_m if payout_m is None else float(payout_m)
    rest = payout / n
    air = np.array([-flow.airspeed_mps, 0.0, 0.0])
    if wind_mps is not None:
        air = air + np.asarray(wind_mps, float)
    g = hp[HP_GRAVITY]
    # forces beyond segment j, without segment j's own aerodynamic load (drogue first)
    beyond = np.array([0.0, 0.0, (hp[HP_DROGUE_MASS] + 0.5 * hp[HP_LAMBDA] * rest) * g])
    beyond += 0.5 * hp[HP_RHO] * hp[HP_DROGUE_CDA] * np.linalg.norm(air) * air
    rel = np.zeros((n + 1, 3))  # positions relative to the drogue
    tensions = np.zeros(n)
    for j in range(n, 0, -1):
        t = beyond / np.linalg.norm(beyond)
        for _ in range(100):
            aero = _segment_aero(air, t, rest, hp)
            vec = beyond + 0.5 * aero
            t_new = vec / np.linalg.norm(vec)
            if np.linalg.norm(t_new - t) < 1e-14:
                t = t_new
                break
            t = t_new
        aero = _segment_aero(air, t, rest, hp)
        tension = float(np.linalg.norm(beyond + 0.5 * aero))
        tensions[j - 1] = tension
        rel[j - 1] = rel[j] - rest * (1.0 + tension / hp[HP_EA]) * t
        # node j−1 (a hose node: weight λℓ) carries the rest of segment j's load
        beyond = beyond + aero
        if j > 1:
            beyond = beyond + np.array([0.0, 0.0, hp[HP_LAMBDA] * rest * g])
    nodes = rel - rel[0]
    return SteadyShape(nodes_m=nodes, tensions_n=tensions, payout_m=payout)


def _state_derivative(
    z: FloatArray, n: int, air: FloatArray, rest: float, hp: FloatArray
) -> FloatArray:
    pos = np.zeros((n + 1, 3))
    vel = np.zeros((n + 1, 3))
    pos[1:] = z[: 3 * n].reshape(n, 3)
    vel[1:] = z[3 * n :].reshape(n, 3)
    force = np.empty((n + 1, 3))
    tension = np.empty(n)
    mass = np.empty(n + 1)
    forces(pos, vel, air, np.zeros(3), rest, hp, force, tension)
    node_masses(n, rest, hp, mass)
    acc = force[1:] / mass[1:, None]
    return np.concatenate([vel[1:].ravel(), acc.ravel()])


def state_jacobian(
    flow: FlowCondition, hose: HoseParams, drogue: DrogueParams, shape: SteadyShape
) -> FloatArray:
    """Jacobian (6n × 6n) of the free nodes' state derivative about ``shape`` (positions then
    velocities, node 1 first; central differences)."""
    hp = pack_hose(flow, hose, drogue)
    n = hose.segments
    rest = shape.payout_m / n
    air = np.tile(np.array([-flow.airspeed_mps, 0.0, 0.0]), (n + 1, 1))
    z0 = np.concatenate([shape.nodes_m[1:].ravel(), np.zeros(3 * n)])
    jac = np.empty((6 * n, 6 * n))
    for k in range(6 * n):
        # steps well inside the segment's elastic stretch (a few mm; ≈ 0.01 m/s)
        eps = 1e-7 * hose.length_m if k < 3 * n else 1e-5 * flow.airspeed_mps
        zp, zm = z0.copy(), z0.copy()
        zp[k] += eps
        zm[k] -= eps
        jac[:, k] = (
            _state_derivative(zp, n, air, rest, hp) - _state_derivative(zm, n, air, rest, hp)
        ) / (2.0 * eps)
    return jac


def swing_modes(
    flow: FlowCondition, hose: HoseParams, drogue: DrogueParams, shape: SteadyShape
) -> SwingModes:
    """The slowest lateral and vertical oscillatory modes of the linearised hose."""
    n = hose.segments
    vals, vecs = eig(state_jacobian(flow, hose, drogue, shape))
    order = np.argsort(np.abs(vals))
    lateral: SwingMode | None = None
    vertical: SwingMode | None = None
    for k in order:
        lam = complex(vals[k])
        if lam.imag <= 1e-9:
            continue
        disp = vecs[: 3 * n, k].reshape(n, 3)
        energy = np.sum(np.abs(disp) ** 2, axis=0)
        share_y = float(energy[1] / np.sum(energy))
        # the real shape at the phase of the largest displacement, normalised to 1 m
        big = np.unravel_index(int(np.argmax(np.abs(disp))), disp.shape)
        real = np.real(disp * np.conj(disp[big]) / abs(disp[big]))
        shape_m = np.vstack([np.zeros(3), real / np.max(np.abs(real))])
        w = abs(lam)
        mode = SwingMode(
            frequency_hz=lam.imag / (2.0 * math.pi),
            damping_ratio=-lam.real / w,
            shape_m=shape_m,
        )
        if share_y > 0.5 and lateral is None:
            lateral = mode
        elif share_y <= 0.5 and vertical is None:
            vertical = mode
        if lateral is not None and vertical is not None:
            return SwingModes(lateral=lateral, vertical=vertical)
    raise RuntimeError("the linearised hose has no oscillatory lateral and vertical modes")
