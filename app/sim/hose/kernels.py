"""Compiled loops of the lumped-mass hose (numba): the forces on the nodes and the substepped
integration of one tick (:mod:`app.sim.hose.model` holds the state and calls these).

Layout: ``pos``, ``vel``, ``air`` are ``(n + 1, 3)`` arrays in the tanker frame (x forward,
y right, z down; m, m/s); row 0 is the reel exit (moved by nobody here), row ``n`` the drogue.
``air`` is the air's velocity at each node (the free stream ``(−V, 0, 0)`` plus gusts and wake).
``hp`` packs the hose and drogue scalars (indices ``HP_*``), ``rp`` the reel's (``RP_*``).

Per segment j (node j−1 → j, rest length ℓ = payout / n, tangent t̂): tension
``T = max(0, (EA/ℓ)(|d| − ℓ) + c ḋ·t̂)`` when stretched, 0 when slack (a hose does not push),
``c = 2 ζ √((EA/ℓ) λ ℓ)``; cross-flow drag with the relative air ``u = air − v`` at the
segment's midpoint split into ``u_t = (u·t̂) t̂`` and ``u_n = u − u_t``:
``½ρ d C_n ℓ |u_n| u_n + ½ρ π d C_t ℓ |u_t| u_t``, half to each end node; weight ``m g ẑ``.
Node masses λℓ (the drogue node: ½λℓ + m_d, its drag ``½ρ C_d A |u| u`` and an external force).

Integration: semi-implicit (symplectic) Euler, ``v += h a(x, v); x += h v``, with ``h`` below the
stability limit of the stiffest axial mode (:func:`substep_limit_s`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.sim.hose.atmosphere import FlowCondition
from app.sim.hose.params import GRAVITY, DrogueParams, HoseParams
from app.types import FloatArray

HP_LAMBDA, HP_DIAMETER, HP_CN, HP_CT, HP_RHO, HP_EA, HP_ZETA = 0, 1, 2, 3, 4, 5, 6
HP_DROGUE_MASS, HP_DROGUE_CDA, HP_GRAVITY = 7, 8, 9
HP_SIZE = 10
RP_SETPOINT, RP_GAIN, RP_TAU, RP_VMAX, RP_LMIN, RP_LMAX = 0, 1, 2, 3, 4, 5
RP_SIZE = 6
# stats of one tick (out array of advance): peak tension, its segment, min tension, most slack
# segments at once, peak forward pull of the coupling on the probe, peak coupling load
ST_PEAK_T, ST_PEAK_SEG, ST_MIN_T, ST_SLACK, ST_PULL, ST_LOAD = 0, 1, 2, 3, 4, 5
ST_SIZE = 6


def pack_hose(flow: FlowCondition, hose: HoseParams, drogue: DrogueParams) -> FloatArray:
    """The ``hp`` array of the kernels."""
    hp = np.zeros(HP_SIZE)
    hp[HP_LAMBDA] = hose.mass_per_m_kg
    hp[HP_DIAMETER] = hose.diameter_m
    hp[HP_CN] = hose.cd_normal
    hp[HP_CT] = hose.cd_tangential
    hp[HP_RHO] = flow.air_density_kgm3
    hp[HP_EA] = hose.axial_stiffness_n
    hp[HP_ZETA] = hose.axial_damping_ratio
    hp[HP_DROGUE_MASS] = drogue.mass_kg
    hp[HP_DROGUE_CDA] = drogue.cd * drogue.area_m2
    hp[HP_GRAVITY] = GRAVITY
    return hp


def substep_limit_s(hp: FloatArray, rest_m: float) -> float:
    """A stable step (s) of the semi-implicit Euler for segments of rest length ``rest_m``:
    half the limit ``h ω_max < 2(√(1+ζ²) − ζ)`` of the highest axial mode of the chain
    (ω_max = 2√(k/m), stiffness-proportional damping ζ_max = 2ζ)."""
    k = hp[HP_EA] / rest_m
    m = hp[HP_LAMBDA] * rest_m
    w_max = 2.0 * math.sqrt(k / m)
    z = min(2.0 * hp[HP_ZETA], 0.99)
    return 0.5 * 2.0 * (math.sqrt(1.0 + z * z) - z) / w_max


@njit(cache=True, nogil=True)
def forces(
    pos: FloatArray,
    vel: FloatArray,
    air: FloatArray,
    f_drogue: FloatArray,
    rest: float,
    hp: FloatArray,
    force: FloatArray,
    tension: FloatArray,
) -> None:
    """Total force on every node (N, ``force``) and each segment's tension (N, ``tension``)."""
    n = pos.shape[0] - 1
    lam = hp[HP_LAMBDA]
    k = hp[HP_EA] / rest
    c = 2.0 * hp[HP_ZETA] * math.sqrt(k * lam * rest)
    qn = 0.5 * hp[HP_RHO] * hp[HP_DIAMETER] * hp[HP_CN] * rest
    qt = 0.5 * hp[HP_RHO] * math.pi * hp[HP_DIAMETER] * hp[HP_CT] * rest
    g = hp[HP_GRAVITY]
    for i in range(n + 1):
        m = lam * rest
        if i == n:
            m = 0.5 * lam * rest + hp[HP_DROGUE_MASS]
        force[i, 0] = 0.0
        force[i, 1] = 0.0
        force[i, 2] = m * g
    for j in range(1, n + 1):
        dx = pos[j, 0] - pos[j - 1, 0]
        dy = pos[j, 1] - pos[j - 1, 1]
        dz = pos[j, 2] - pos[j - 1, 2]
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        tx, ty, tz = dx / length, dy / length, dz / length
        t_j = 0.0
        if length > rest:
            rate = (
                (vel[j, 0] - vel[j - 1, 0]) * tx
                + (vel[j, 1] - vel[j - 1, 1]) * ty
                + (vel[j, 2] - vel[j - 1, 2]) * tz
            )
            t_j = k * (length - rest) + c * rate
            if t_j < 0.0:
                t_j = 0.0
        tension[j - 1] = t_j
        # relative air at the midpoint
        ux = 0.5 * (air[j, 0] + air[j - 1, 0] - vel[j, 0] - vel[j - 1, 0])
        uy = 0.5 * (air[j, 1] + air[j - 1, 1] - vel[j, 1] - vel[j - 1, 1])
        uz = 0.5 * (air[j, 2] + air[j - 1, 2] - vel[j, 2] - vel[j - 1, 2])
        ut = ux * tx + uy * ty + uz * tz
        nx, ny, nz = ux - ut * tx, uy - ut * ty, uz - ut * tz
        un = math.sqrt(nx * nx + ny * ny + nz * nz)
        fx = qn * un * nx + qt * abs(ut) * ut * tx
        fy = qn * un * ny + qt * abs(ut) * ut * ty
        fz = qn * un * nz + qt * abs(ut) * ut * tz
        force[j - 1, 0] += 0.5 * fx + t_j * tx
        force[j - 1, 1] += 0.5 * fy + t_j * ty
        force[j - 1, 2] += 0.5 * fz + t_j * tz
        force[j, 0] += 0.5 * fx - t_j * tx
        force[j, 1] += 0.5 * fy - t_j * ty
        force[j, 2] += 0.5 * fz - t_j * tz
    ux = air[n, 0] - vel[n, 0]
    uy = air[n, 1] - vel[n, 1]
    uz = air[n, 2] - vel[n, 2]
    q = 0.5 * hp[HP_RHO] * hp[HP_DROGUE_CDA] * math.sqrt(ux * ux + uy * uy + uz * uz)
    force[n, 0] += q * ux + f_drogue[0]
    force[n, 1] += q * uy + f_drogue[1]
    force[n, 2] += q * uz + f_drogue[2]


@njit(cache=True, nogil=True)
def node_masses(n: int, rest: float, hp: FloatArray, out: FloatArray) -> None:
    for i in range(n + 1):
        out[i] = hp[HP_LAMBDA] * rest
    out[n] = 0.5 * hp[HP_LAMBDA] * rest + hp[HP_DROGUE_MASS]


@njit(cache=True, nogil=True)
def advance(
    pos: FloatArray,
    vel: FloatArray,
    air: FloatArray,
    f_drogue: FloatArray,
    reel: FloatArray,
    hp: FloatArray,
    rp: FloatArray,
    reel_active: bool,
    dt: float,
    nsub: int,
    latched: bool,
    probe_start: FloatArray,
    probe_end: FloatArray,
    coupling: FloatArray,
    tension: FloatArray,
    stats: FloatArray,
) -> None:
    """One tick of ``dt`` in ``nsub`` substeps (state arrays updated in place).

    ``reel`` = (payout m, payout rate m/s). With ``latched`` the drogue node is held to the
    probe's point (moving linearly from ``probe_start`` to ``probe_end`` over the tick) by the
    coupling's spring-damper ``coupling`` = (N/m, N s/m), and ``stats`` collects the coupling's
    loads; ``stats`` always gets the tick's tension extremes (indices ``ST_*``)."""
    n = pos.shape[0] - 1
    h = dt / nsub
    force = np.empty_like(pos)
    mass = np.empty(n + 1)
    stats[ST_PEAK_T] = 0.0
    stats[ST_PEAK_SEG] = 0.0
    stats[ST_MIN_T] = np.inf
    stats[ST_SLACK] = 0.0
    stats[ST_PULL] = -np.inf
    stats[ST_LOAD] = 0.0
    pv0 = (probe_end[0] - probe_start[0]) / dt
    pv1 = (probe_end[1] - probe_start[1]) / dt
    pv2 = (probe_end[2] - probe_start[2]) / dt
    for s in range(nsub):
        rest = reel[0] / n
        forces(pos, vel, air, f_drogue, rest, hp, force, tension)
        node_masses(n, rest, hp, mass)
        slack = 0
        for j in range(n):
            tj = tension[j]
            if tj > stats[ST_PEAK_T]:
                stats[ST_PEAK_T] = tj
                stats[ST_PEAK_SEG] = j
            if tj < stats[ST_MIN_T]:
                stats[ST_MIN_T] = tj
            if tj <= 0.0:
                slack += 1
        if slack > stats[ST_SLACK]:
            stats[ST_SLACK] = slack
        if latched:
            # the coupling on the probe: a stiff spring-damper to the probe's point
            frac = (s + 0.5) / nsub
            cx = coupling[0] * (probe_start[0] + frac * (probe_end[0] - probe_start[0]) - pos[n, 0])
            cy = coupling[0] * (probe_start[1] + frac * (probe_end[1] - probe_start[1]) - pos[n, 1])
            cz = coupling[0] * (probe_start[2] + frac * (probe_end[2] - probe_start[2]) - pos[n, 2])
            cx += coupling[1] * (pv0 - vel[n, 0])
            cy += coupling[1] * (pv1 - vel[n, 1])
            cz += coupling[1] * (pv2 - vel[n, 2])
            force[n, 0] += cx
            force[n, 1] += cy
            force[n, 2] += cz
            # the drogue pulls the probe forward (off the coupling) with −c·x̂
            if -cx > stats[ST_PULL]:
                stats[ST_PULL] = -cx
            load = math.sqrt(cx * cx + cy * cy + cz * cz)
            if load > stats[ST_LOAD]:
                stats[ST_LOAD] = load
        for i in range(1, n + 1):
            for a in range(3):
                vel[i, a] += h * force[i, a] / mass[i]
        for i in range(1, n + 1):
            for a in range(3):
                pos[i, a] += h * vel[i, a]
        if reel_active:
            cmd = rp[RP_GAIN] * (tension[0] - rp[RP_SETPOINT])
            if cmd > rp[RP_VMAX]:
                cmd = rp[RP_VMAX]
            elif cmd < -rp[RP_VMAX]:
                cmd = -rp[RP_VMAX]
            reel[1] += h * (cmd - reel[1]) / rp[RP_TAU]
            reel[0] += h * reel[1]
            if reel[0] >= rp[RP_LMAX]:
                reel[0] = rp[RP_LMAX]
                if reel[1] > 0.0:
                    reel[1] = 0.0
            elif reel[0] <= rp[RP_LMIN]:
                reel[0] = rp[RP_LMIN]
                if reel[1] < 0.0:
                    reel[1] = 0.0
