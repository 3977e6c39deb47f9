"""Compiled loops of the first-order error bounds of :mod:`app.geometry.uncertainty` (numba,
cached on disk; compiling them all takes ~13 s on first use): per point and camera, the
Jacobians of the ideal projections (eqs. 4–5) and of the undistortion (inverse of eq. 7) and
the triangulated point's covariance and gain; the closed-form Jacobians of the plane + circle
fit (§5.2); the χ² statistic of a lock's residuals; a lock's terms in one call; and the
quantile of the generalised χ² behind the protection levels. The formulas are documented with
the functions that call these loops in :mod:`app.geometry.uncertainty`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from app.geometry.circle_fit_kernels import plane_axes

# :func:`lock_kernel`'s status
LOCK_OK, LOCK_BAD_SIGMA_LEFT, LOCK_BAD_SIGMA_RIGHT, LOCK_BAD_POINTS, LOCK_DEGENERATE = range(5)

_MINOR_ROWS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])  # rows kept per minor


# ---- stereo: per-point Jacobians, measurement covariance, gains -------------------------
@njit(cache=True, nogil=True)
def _distort(
    dist: np.ndarray, x: float, y: float
) -> tuple[float, float, float, float, float]:  # pragma: no cover - compiled
    """Eq. 7 (OpenCV's k1, k2, p1, p2, k3) at normalised (x, y): (x_d, y_d, ∂x_d/∂x,
    ∂x_d/∂y = ∂y_d/∂x, ∂y_d/∂y)."""
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r²
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    jxx = radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x
    jxy = 2.0 * x * y * dr + 2.0 * p1 * x + 2.0 * p2 * y
    jyy = radial + 2.0 * y * y * dr + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, jxx, jxy, jyy


@njit(cache=True, nogil=True)
def _camera_terms(
    K: np.ndarray, dist: np.ndarray, P: np.ndarray, X: np.ndarray, px: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """One point in one camera: (J 2×3 = ∂(ideal px)/∂X (px/mm), D 2×2 = ∂(distorted px)/
    ∂(ideal px) at the measured pixel, r 2 = measured pixel undistorted − projection of X)."""
    h0 = P[0, 0] * X[0] + P[0, 1] * X[1] + P[0, 2] * X[2] + P[0, 3]
    h1 = P[1, 0] * X[0] + P[1, 1] * X[1] + P[1, 2] * X[2] + P[1, 3]
    w = P[2, 0] * X[0] + P[2, 1] * X[1] + P[2, 2] * X[2] + P[2, 3]
    u, v = h0 / w, h1 / w
    J = np.empty((2, 3))
    for j in range(3):
        J[0, j] = (P[0, j] - u * P[2, j]) / w
        J[1, j] = (P[1, j] - v * P[2, j]) / w
    fx, g, u0, fy, v0 = K[0, 0], K[0, 1], K[0, 2], K[1, 1], K[1, 2]
    # undistort the measured pixel: K⁻¹ (eq. 2), then Newton on eq. 7 from X's projection
    yt = (px[1] - v0) / fy
    xt = (px[0] - u0 - g * yt) / fx
    y = (v - v0) / fy
    x = (u - u0 - g * y) / fx
    for _ in range(20):
        xd, yd, jxx, jxy, jyy = _distort(dist, x, y)
        det = jxx * jyy - jxy * jxy
        dx = (jyy * (xd - xt) - jxy * (yd - yt)) / det
        dy = (jxx * (yd - yt) - jxy * (xd - xt)) / det
        x -= dx
        y -= dy
        if abs(dx) + abs(dy) < 1e-15:
            break
    _, _, jxx, jxy, jyy = _distort(dist, x, y)
    # D = K₂ · ∂(x_d, y_d)/∂(x, y) · K₂⁻¹ with K₂ = [[fx, γ], [0, fy]]
    a00, a01 = fx * jxx + g * jxy, fx * jxy + g * jyy
    a10, a11 = fy * jxy, fy * jyy
    D = np.empty((2, 2))
    D[0, 0] = a00 / fx
    D[0, 1] = a01 / fy - a00 * g / (fx * fy)
    D[1, 0] = a10 / fx
    D[1, 1] = a11 / fy - a10 * g / (fx * fy)
    r = np.empty(2)
    r[0] = fx * x + g * y + u0 - u
    r[1] = fy * y + v0 - v
    return J, D, r


@njit(cache=True, nogil=True)
def _left_null(J: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Unit a (4) with aᵀJ = 0 for a 4×3 J: the signed 3×3 minors."""
    a = np.empty(4)
    for i in range(4):
        r0, r1, r2 = _MINOR_ROWS[i, 0], _MINOR_ROWS[i, 1], _MINOR_ROWS[i, 2]
        m = (
            J[r0, 0] * (J[r1, 1] * J[r2, 2] - J[r1, 2] * J[r2, 1])
            - J[r0, 1] * (J[r1, 0] * J[r2, 2] - J[r1, 2] * J[r2, 0])
            + J[r0, 2] * (J[r1, 0] * J[r2, 1] - J[r1, 1] * J[r2, 0])
        )
        a[i] = m if i % 2 == 0 else -m
    return a / np.sqrt(a @ a)


@njit(cache=True, nogil=True)
def _mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """a·b for small matrices (a loop beats a BLAS call at these sizes)."""
    out = np.zeros((a.shape[0], b.shape[1]))
    for i in range(a.shape[0]):
        for k in range(a.shape[1]):
            aik = a[i, k]
            for j in range(b.shape[1]):
                out[i, j] += aik * b[k, j]
    return out


@njit(cache=True, nogil=True)
def _inv2(m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Inverse of a 2×2 matrix."""
    det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    inv = np.empty((2, 2))
    inv[0, 0], inv[0, 1] = m[1, 1] / det, -m[0, 1] / det
    inv[1, 0], inv[1, 1] = -m[1, 0] / det, m[0, 0] / det
    return inv


@njit(cache=True, nogil=True)
def _inv3(m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Inverse of a 3×3 matrix (adjugate / determinant)."""
    inv = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            a, b = (j + 1) % 3, (j + 2) % 3
            c, d = (i + 1) % 3, (i + 2) % 3
            inv[i, j] = m[a, c] * m[b, d] - m[a, d] * m[b, c]
    det = m[0, 0] * inv[0, 0] + m[0, 1] * inv[1, 0] + m[0, 2] * inv[2, 0]
    return inv / det


@njit(cache=True, nogil=True)
def _stereo_terms(
    K_l: np.ndarray,
    dist_l: np.ndarray,
    P_l: np.ndarray,
    K_r: np.ndarray,
    dist_r: np.ndarray,
    P_r: np.ndarray,
    left_px: np.ndarray,
    right_px: np.ndarray,
    X: np.ndarray,
    sigma_l: np.ndarray,
    sigma_r: np.ndarray,
    weighted: bool,
    point_cov: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """:func:`stereo_kernel`; without ``point_cov`` the unweighted Σ_X is left unset (a
    caller that builds its own from the gains)."""
    n = X.shape[0]
    cov = np.empty((n, 3, 3))
    gain = np.empty((n, 3, 4))
    C = np.zeros((n, 4, 4))
    null = np.empty((n, 4))
    epi = np.empty(n)
    J = np.empty((4, 3))
    W = np.zeros((4, 4))
    for p in range(n):
        Jl, Dl, rl = _camera_terms(K_l, dist_l, P_l, X[p], left_px[p])
        Jr, Dr, rr = _camera_terms(K_r, dist_r, P_r, X[p], right_px[p])
        J[0:2] = Jl
        J[2:4] = Jr
        for cam in range(2):
            D = Dl if cam == 0 else Dr
            s2 = sigma_l[p] ** 2 if cam == 0 else sigma_r[p] ** 2
            A = _inv2(D)  # ∂(ideal px)/∂(distorted px)
            o = 2 * cam
            for i in range(2):
                for j in range(2):
                    C[p, o + i, o + j] = s2 * (A[i, 0] * A[j, 0] + A[i, 1] * A[j, 1])
                    W[o + i, o + j] = (D[0, i] * D[0, j] + D[1, i] * D[1, j]) / s2
        if weighted:
            JtW = _mm(J.T.copy(), W)
            info_inv = _inv3(_mm(JtW, J))
            gain[p] = _mm(info_inv, JtW)
            cov[p] = info_inv
        else:
            B = _mm(_inv3(_mm(J.T.copy(), J)), J.T.copy())
            gain[p] = B
            if point_cov:
                cov[p] = _mm(_mm(B, C[p]), B.T.copy())
        a = _left_null(J)
        null[p] = a
        epi[p] = a[0] * rl[0] + a[1] * rl[1] + a[2] * rr[0] + a[3] * rr[1]
    return cov, gain, C, null, epi


@njit(cache=True, nogil=True)
def stereo_kernel(
    K_l: np.ndarray,
    dist_l: np.ndarray,
    P_l: np.ndarray,
    K_r: np.ndarray,
    dist_r: np.ndarray,
    P_r: np.ndarray,
    left_px: np.ndarray,
    right_px: np.ndarray,
    X: np.ndarray,
    sigma_l: np.ndarray,
    sigma_r: np.ndarray,
    weighted: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    """Per point: (Σ_X 3×3 mm², gain B 3×4 with δX = B·δx, C 4×4 ideal-px covariance,
    unit a 4 with aᵀJ = 0, epipolar residual e = aᵀ·residual px)."""
    return _stereo_terms(
        K_l, dist_l, P_l, K_r, dist_r, P_r, left_px, right_px, X, sigma_l, sigma_r, weighted, True
    )


# ---- ring: Jacobians of the circle fit ----------------------------------------------------
@njit(cache=True, nogil=True)
def _circle_residuals(
    pts: np.ndarray, c: np.ndarray, nrm: np.ndarray, radius: float
) -> np.ndarray:  # pragma: no cover - compiled
    """(2N) per point: signed distance from the plane (along nrm, mm), then in-plane radial
    distance − radius (mm)."""
    n = pts.shape[0]
    out = np.empty(2 * n)
    for p in range(n):
        d = pts[p] - c
        off = d @ nrm
        q = d - off * nrm
        out[2 * p] = off
        out[2 * p + 1] = np.sqrt(q @ q) - radius
    return out


@njit(cache=True, nogil=True)
def _fit_jacobians(
    pts: np.ndarray, c: np.ndarray, nrm: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """(∂θ/∂p 7×3N, ∂ρ/∂p 2N×3N, A 2N×6) of the plane + circle fit at points ON the circle
    (c, unit nrm, radius): θ = (centre, normal signed like nrm, radius), ρ the points'
    residuals from their own refitted circle, A = ∂ρ/∂ψ the fit's design matrix (below). NaN
    Jacobians when the points do not define a circle.

    At zero residual the fit is first-order the least-squares solution of the linearised
    residuals (the TLS plane is the least-squares plane of the off-plane offsets; Kåsa +
    Gauss–Newton in it the least-squares circle of the radial distances; the plane's tilt
    moves the radial distances at second order only). With u_k the unit radial of point k,
    (e1, e2) in-plane axes and ψ = (δc 3, tilt t1, t2, δr):
    off_k = n·δp_k − n·δc + r·(t1 u_k·e1 + t2 u_k·e2), radial_k = u_k·δp_k − u_k·δc − δr,
    i.e. ρ = A ψ + B δp; the fit takes ψ = −(AᵀA)⁻¹AᵀB δp, and ∂ρ/∂p = B + A ∂ψ/∂p =
    (I − A(AᵀA)⁻¹Aᵀ) B: the residuals are orthogonal to A's 6 columns whatever δp.
    (Tested against central differences of :func:`~app.geometry.circle_fit.fit_circle_3d`.)
    """
    n = pts.shape[0]
    e1, e2 = plane_axes(nrm)
    A = np.zeros((2 * n, 6))
    B = np.zeros((2 * n, 3 * n))
    for k in range(n):
        u = (pts[k] - c) / radius
        for i in range(3):
            A[2 * k, i] = -nrm[i]
            A[2 * k + 1, i] = -u[i]
            B[2 * k, 3 * k + i] = nrm[i]
            B[2 * k + 1, 3 * k + i] = u[i]
        A[2 * k, 3] = radius * (u @ e1)
        A[2 * k, 4] = radius * (u @ e2)
        A[2 * k + 1, 5] = -1.0
    jt = np.full((7, 3 * n), np.nan)
    jr = np.full((2 * n, 3 * n), np.nan)
    ata = A.T @ A
    # a singular system (collinear points, fewer than 3): no circle, NaN Jacobians
    if (
        n < 3
        or not np.all(np.isfinite(ata))
        or abs(np.linalg.det(ata)) < 1e-12 * max(1.0, radius) ** 8
    ):
        return jt, jr, A
    G = -np.linalg.solve(ata, A.T @ B)  # ∂ψ/∂p, 6×3N
    jt[0:3] = G[0:3]
    for i in range(3):
        jt[3 + i] = e1[i] * G[3] + e2[i] * G[4]
    jt[6] = G[5]
    jr[:] = B + A @ G
    return jt, jr, A


@njit(cache=True, nogil=True)
def ring_terms(
    pts: np.ndarray, c: np.ndarray, nrm: np.ndarray, radius: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """(∂θ/∂p 7×3N, ∂ρ/∂p 2N×3N, the design matrix A 2N×6) of the circle fit (see
    :func:`_fit_jacobians`), linearised at
    the points' closest points on the circle: the model's estimate of the true configuration.
    There the residuals have exactly 2N − 6 dof; at the measured points the fit's response to
    a point sliding along the ring is not zero (∝ its residual), a noise-induced term that
    first-order theory does not have (it made the 8 m ring's centre covariance ~25 % high and
    the consistency test's null space ill-defined). NaN when there is no such circle."""
    n = pts.shape[0]
    on = np.empty((n, 3))
    for k in range(n):
        d = pts[k] - c
        q = d - (d @ nrm) * nrm
        on[k] = c + radius * q / np.sqrt(q @ q)
    return _fit_jacobians(on, c, nrm, radius)


# ---- consistency: the residuals' covariance and the χ² statistic --------------------------
@njit(cache=True, nogil=True)
def _residual_cov(
    a: np.ndarray, gain: np.ndarray, C: np.ndarray, jr: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """cov(y) = Σ_k M_k C_k M_kᵀ of y = (N epipolar, 2N circle residuals): M_k (3N×4) has
    a_kᵀ in row k and ∂ρ/∂p_k · B_k below."""
    n = a.shape[0]
    m = 3 * n
    S = np.zeros((m, m))
    Mk = np.empty((m, 4))
    for k in range(n):
        Mk[:n] = 0.0
        Mk[k] = a[k]
        for r in range(2 * n):
            for j in range(4):
                Mk[n + r, j] = (
                    jr[r, 3 * k] * gain[k, 0, j]
                    + jr[r, 3 * k + 1] * gain[k, 1, j]
                    + jr[r, 3 * k + 2] * gain[k, 2, j]
                )
        MC = _mm(Mk, C[k])
        for i in range(m):
            for j in range(m):
                acc = 0.0
                for q in range(4):
                    acc += MC[i, q] * Mk[j, q]
                S[i, j] += acc
    return S


@njit(cache=True, nogil=True)
def residual_system(
    a: np.ndarray,
    gain: np.ndarray,
    C: np.ndarray,
    epi: np.ndarray,
    X: np.ndarray,
    c: np.ndarray,
    nrm: np.ndarray,
    radius: float,
    jr: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """(cov(y) 3N×3N, y 3N) of :func:`~app.geometry.uncertainty.fit_consistency`: the N
    epipolar residuals (px), then each point's off-plane and radial residuals (mm)."""
    S = _residual_cov(a, gain, C, jr)
    y = np.concatenate((epi, _circle_residuals(X, c, nrm, radius)))
    return S, y


@njit(cache=True, nogil=True)
def _cholesky_quadratic(
    S: np.ndarray, y: np.ndarray, min_pivot: float
) -> float:  # pragma: no cover
    """yᵀ S⁻¹ y of a symmetric positive-definite S by its Cholesky factor (S = LLᵀ, then
    ‖L⁻¹y‖²); NaN when a squared pivot falls below ``min_pivot`` (S not safely definite)."""
    m = y.shape[0]
    L = np.zeros((m, m))
    for j in range(m):
        d = S[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d >= min_pivot:
            return np.nan
        d = math.sqrt(d)
        L[j, j] = d
        for i in range(j + 1, m):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / d
    T = 0.0
    w = np.empty(m)
    for i in range(m):
        acc = y[i]
        for k in range(i):
            acc -= L[i, k] * w[k]
        w[i] = acc / L[i, i]
        T += w[i] * w[i]
    return T


@njit(cache=True, nogil=True)
def _eigen_chi2(St: np.ndarray, yt: np.ndarray, dof: int) -> float:  # pragma: no cover
    """ytᵀ St⁺ yt on the top ``dof`` eigen-directions of St (the general formulation)."""
    lam, vec = np.linalg.eigh(St)
    m = yt.shape[0]
    T = 0.0
    for j in range(m - dof, m):
        proj = 0.0
        for i in range(m):
            proj += vec[i, j] * yt[i]
        T += proj * proj / lam[j]
    return T


# a squared Cholesky pivot of the unit-diagonal system below this: the eigen-formulation
# decides (a kept direction nearly as flat as the null space)
_MIN_PIVOT = 1e-8


@njit(cache=True, nogil=True)
def chi2_kernel(
    a: np.ndarray,
    gain: np.ndarray,
    C: np.ndarray,
    epi: np.ndarray,
    X: np.ndarray,
    c: np.ndarray,
    nrm: np.ndarray,
    radius: float,
    jr: np.ndarray,
    design: np.ndarray,
) -> float:  # pragma: no cover - compiled
    """T = yᵀ cov(y)⁺ y of :func:`~app.geometry.uncertainty.fit_consistency` on the top
    3N − 6 directions of cov(y) (unit-free: y and cov(y) scaled by cov(y)'s diagonal).

    cov(y) = Σ_k M_k C_k M_kᵀ has rank 3N − 6 and its null space is known in closed form:
    the circle residuals are orthogonal to the fit's design matrix A (``design``, 2N×6; see
    :func:`_fit_jacobians`), so the null space is A's columns in the circle rows (scaled as
    y). With U an orthonormal basis of it, (S + UUᵀ)⁻¹ = S⁺ + UUᵀ, so
    T = zᵀ (S + UUᵀ)⁻¹ z with z = y − UUᵀy: one Cholesky solve instead of an
    eigendecomposition, equal to the truncated eigen-sum to rounding (tested); a system too
    flat for it falls back on that sum (:func:`_eigen_chi2`)."""
    n = X.shape[0]
    S, y = residual_system(a, gain, C, epi, X, c, nrm, radius, jr)
    dof = 3 * n - 6
    if n == 3:  # the circle passes through the 3 points: only the epipolar residuals remain
        S, y = S[:n, :n].copy(), y[:n].copy()
    m = len(y)
    scale = np.sqrt(np.diag(S))
    St = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            St[i, j] = S[i, j] / (scale[i] * scale[j])
    yt = y / scale
    if m > dof:  # the null space: A's columns in the circle rows, orthonormalised
        U = np.zeros((m, m - dof))
        for j in range(m - dof):
            for r in range(2 * n):
                U[n + r, j] = design[r, j] * scale[n + r]
            for q in range(j):  # modified Gram–Schmidt, twice for orthogonality to rounding
                for _ in range(2):
                    dot = 0.0
                    for i in range(m):
                        dot += U[i, q] * U[i, j]
                    for i in range(m):
                        U[i, j] -= dot * U[i, q]
            nrm2 = 0.0
            for i in range(m):
                nrm2 += U[i, j] * U[i, j]
            inv = 1.0 / math.sqrt(nrm2)
            for i in range(m):
                U[i, j] *= inv
        z = yt.copy()
        for j in range(m - dof):
            dot = 0.0
            for i in range(m):
                dot += U[i, j] * yt[i]
            for i in range(m):
                z[i] -= dot * U[i, j]
        Sp = St.copy()
        for i in range(m):
            for j in range(m):
                acc = 0.0
                for q in range(m - dof):
                    acc += U[i, q] * U[j, q]
                Sp[i, j] += acc
    else:
        z, Sp = yt, St
    T = _cholesky_quadratic(Sp, z, _MIN_PIVOT)
    if math.isnan(T) and np.all(np.isfinite(St)) and np.all(np.isfinite(yt)):
        return _eigen_chi2(St, yt, dof)
    return T


# ---- a lock's terms in one call ------------------------------------------------------------
@njit(cache=True, nogil=True)
def _largest_eigenvalue_sym3(m: np.ndarray) -> float:  # pragma: no cover - compiled
    """λ_max of a symmetric 3×3 matrix in closed form (the trigonometric solution of the
    characteristic cubic; equal to ``np.linalg.eigvalsh(m)[-1]`` to rounding, tested); NaN
    when ``m`` is not finite."""
    a00, a11, a22 = m[0, 0], m[1, 1], m[2, 2]
    a01, a02, a12 = m[0, 1], m[0, 2], m[1, 2]
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    if not math.isfinite(p1 + q):
        return np.nan
    d0, d1, d2 = a00 - q, a11 - q, a22 - q
    p2 = d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * p1
    if p2 == 0.0:  # a multiple of the identity
        return q
    p = math.sqrt(p2 / 6.0)
    # r = det((m − q·I) / p) / 2, in [−1, 1] up to rounding
    det = d0 * (d1 * d2 - a12 * a12) - a01 * (a01 * d2 - a12 * a02) + a02 * (a01 * a12 - d1 * a02)
    r = det / (2.0 * p * p * p)
    r = min(1.0, max(-1.0, r))
    return q + 2.0 * p * math.cos(math.acos(r) / 3.0)


@njit(cache=True, nogil=True)
def lock_kernel(
    K_l: np.ndarray,
    dist_l: np.ndarray,
    P_l: np.ndarray,
    K_r: np.ndarray,
    dist_r: np.ndarray,
    P_r: np.ndarray,
    left_px: np.ndarray,
    right_px: np.ndarray,
    X: np.ndarray,
    sigma_l: np.ndarray,
    sigma_r: np.ndarray,
    systematic_px: float,
    c: np.ndarray,
    normal: np.ndarray,
    radius: float,
) -> tuple[int, np.ndarray, np.ndarray, float, np.ndarray]:  # pragma: no cover - compiled
    """(status, point covariances N×3×3 and centre covariance 3×3 with σ² + systematic² per
    image, mm²; the χ² statistic with σ alone; the largest eigenvalue of each point's
    covariance, then of the centre's, mm²). The inputs are checked here, in the order the
    caller reports them: ``status`` is :data:`LOCK_BAD_SIGMA_LEFT` / ``_RIGHT`` (a σ not
    positive and finite; nothing computed), :data:`LOCK_BAD_POINTS` (fewer than 3 points or
    one not finite; nothing computed), :data:`LOCK_DEGENERATE` (the centre covariance or the
    statistic not finite: no circle through the points) or :data:`LOCK_OK`. ``normal``: the
    circle's, of any length (made unit here)."""
    n = X.shape[0]
    x, y, z = normal[0], normal[1], normal[2]
    norm = math.sqrt(x * x + y * y + z * z)
    nrm = np.empty(3)
    for i in range(3):
        nrm[i] = normal[i] / norm
    empty = np.empty((0, 3, 3))
    for k in range(n):
        if not (0.0 < sigma_l[k] < np.inf):
            return LOCK_BAD_SIGMA_LEFT, empty, np.empty((3, 3)), np.nan, np.empty(0)
    for k in range(n):
        if not (0.0 < sigma_r[k] < np.inf):
            return LOCK_BAD_SIGMA_RIGHT, empty, np.empty((3, 3)), np.nan, np.empty(0)
    if n < 3 or not np.all(np.isfinite(X)):
        return LOCK_BAD_POINTS, empty, np.empty((3, 3)), np.nan, np.empty(0)
    # (the point covariances are built below from the gains, with the systematic term)
    _, gain, C, a, epi = _stereo_terms(
        K_l, dist_l, P_l, K_r, dist_r, P_r, left_px, right_px, X, sigma_l, sigma_r, False, False
    )
    # C_k = σ² A Aᵀ per image: with σ² + systematic² it scales by (σ² + s²)/σ² per block
    s2 = systematic_px * systematic_px
    cov = np.empty((n, 3, 3))
    Cb = np.zeros((4, 4))
    for k in range(n):
        fl = (sigma_l[k] * sigma_l[k] + s2) / (sigma_l[k] * sigma_l[k])
        fr = (sigma_r[k] * sigma_r[k] + s2) / (sigma_r[k] * sigma_r[k])
        Cb[0:2, 0:2] = C[k, 0:2, 0:2] * fl
        Cb[2:4, 2:4] = C[k, 2:4, 2:4] * fr
        cov[k] = _mm(_mm(gain[k], Cb), gain[k].T.copy())
    jt, jr, design = ring_terms(X, c, nrm, radius)
    centre = np.zeros((3, 3))
    for k in range(X.shape[0]):
        jk = jt[0:3, 3 * k : 3 * k + 3].copy()
        centre += _mm(_mm(jk, cov[k]), jk.T.copy())
    lam = np.empty(n + 1)
    for k in range(n):
        lam[k] = _largest_eigenvalue_sym3(cov[k])
    lam[n] = _largest_eigenvalue_sym3(centre)
    if not (np.all(np.isfinite(jr)) and np.all(np.isfinite(centre))):
        return LOCK_DEGENERATE, cov, centre, np.nan, lam
    T = chi2_kernel(a, gain, C, epi, X, c, nrm, radius, jr, design)
    return (LOCK_OK if math.isfinite(T) else LOCK_DEGENERATE), cov, centre, T, lam


# ---- protection level: the generalised χ² quantile --------------------------------------
@njit(cache=True, nogil=True)
def _tail(
    x: float, lam: np.ndarray, u2: np.ndarray, c2: np.ndarray, w: np.ndarray
) -> tuple[float, float]:  # pragma: no cover - compiled
    """P(Σ λᵢ zᵢ² > x) = E_ω[S₃(x / ωᵀΛω)] and its derivative in x (λ descending)."""
    tot, dtot = 0.0, 0.0
    for j in range(w.shape[0]):
        g = lam[0] * u2[j] + (1.0 - u2[j]) * (lam[1] * c2[j] + lam[2] * (1.0 - c2[j]))
        if g <= 0.0:
            continue
        t = x / g
        if t > 1400.0:
            continue
        e = math.exp(-0.5 * t)
        tot += w[j] * (math.erfc(math.sqrt(0.5 * t)) + math.sqrt(2.0 * t / math.pi) * e)
        dtot -= w[j] * math.sqrt(t / (2.0 * math.pi)) * e / g
    return tot, dtot


@njit(cache=True, nogil=True)
def pl_kernel(
    lams: np.ndarray,
    x0: np.ndarray,
    p: float,
    q1: float,
    q3: float,
    u2: np.ndarray,
    c2: np.ndarray,
    w: np.ndarray,
) -> np.ndarray:  # pragma: no cover - compiled
    """Radius r with P(‖e‖ > r) = p per row of descending eigenvalues: safeguarded Newton on
    log P in x = r² from x0, bracketed by the λ₁·χ²₁ and λ₁·χ²₃ quantiles."""
    out = np.empty(lams.shape[0])
    lp = math.log(p)
    for i in range(lams.shape[0]):
        lam = lams[i]
        if lam[0] <= 0.0:
            out[i] = 0.0
            continue
        lo, hi = lam[0] * q1, lam[0] * q3
        x = min(max(x0[i], lo), hi)
        for _ in range(60):
            s, ds = _tail(x, lam, u2, c2, w)
            if s <= 0.0:  # far beyond the quantile
                hi = x
                x = 0.5 * (lo + hi)
                continue
            f = math.log(s) - lp
            if abs(f) < 1e-10:  # P within 1e-10 (relative) of p
                break
            if f > 0.0:
                lo = x
            else:
                hi = x
            xn = x - f * s / ds
            if not lo < xn < hi:
                xn = 0.5 * (lo + hi)
            x = xn
        out[i] = math.sqrt(x)
    return out
