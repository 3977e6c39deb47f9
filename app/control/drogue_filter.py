"""Kalman filter on the drogue position measured by the navigation pipeline (tanker frame, m).

Constant-velocity model per axis with white-acceleration process noise (σ_a, m/s²); measurement
noise from the stereo geometry (supplied per measurement). Outliers are rejected by innovation
gating: normalised innovation squared ``νᵀ S⁻¹ ν`` above the χ²(3) threshold (default 99.9 %,
16.27). Three consecutive rejections mean the filter (not the measurements) is wrong — it lagged a
manoeuvre — and it is re-seeded from the measurement, keeping its velocity. Without accepted measurements the filter coasts (predicts only); :attr:`coast_time_s`
tells the guidance how long, so it can command a back-off after a bounded time.

A far stereo fix's error along the line of sight — the tanker frame's x, fore and aft — is
mostly a *bias*: a calibration the navigation doubts shifts every disparity alike, and the
depth error grows as Z² (harsh: a drogue 21.7 m away read at 56.7 m). Fifty such fixes a second
taken as independent average their noise away but not their bias, and a filter fed them walks
onto it (seen: 10 m in 1.6 s, the rejoin then closing at 5–7 m/s). The drogue is tethered —
its fore-aft position moves by the swing's ``L (1 − cos θ)``, centimetres —, so a fix whose
fore-aft σ exceeds ``fore_aft_fix_sigma_max_m`` updates the cross-stream axes only (y, z:
its marginal, gated at χ²(2)); the fore-aft estimate waits for the nearer fixes.
"""

from __future__ import annotations

from collections import deque
from functools import lru_cache

import numpy as np

from app.types import FloatArray

CHI2_3_999 = 16.266
CHI2_2_999 = 13.816
_H = np.hstack([np.eye(3), np.zeros((3, 3))])  # position from the state (x y z vx vy vz)
_CROSS = [1, 2]  # the cross-stream axes (y, z)
_H_CROSS = _H[_CROSS]
# (x, P, initialised, ever_initialised, coast_time_s, consecutive_rejections)
_Snapshot = tuple[FloatArray, FloatArray, bool, bool, float, int]


@lru_cache(maxsize=16)
def _transition(dt: float, accel_sigma: float) -> tuple[FloatArray, FloatArray]:
    """The constant-velocity model's transition F and process noise Q over ``dt`` (s) for a
    white acceleration of ``accel_sigma`` (m/s²): the loop predicts at a fixed tick, so both
    are made once (read-only)."""
    f = np.eye(6)
    f[:3, 3:] = dt * np.eye(3)
    q1 = accel_sigma**2 * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
    q = np.asarray(np.kron(q1, np.eye(3)), dtype=np.float64)
    f.setflags(write=False)
    q.setflags(write=False)
    return f, q


class DrogueFilter:
    def __init__(
        self,
        accel_sigma: float = 2.5,
        gate: float = CHI2_3_999,
        reseed_after: int = 3,
        history: int = 0,
        hold_after_s: float = float("inf"),
        fore_aft_fix_sigma_max_m: float = float("inf"),
    ) -> None:
        self.accel_sigma = accel_sigma
        self.gate = gate
        self.reseed_after = reseed_after
        # states after each of the last ``history`` predictions, for delayed measurements
        self.history = history
        # coasting longer than this, the estimate stops extrapolating (velocity zeroed): a lost
        # drogue is held where it was last seen instead of drifting away with a stale velocity
        self.hold_after_s = hold_after_s
        # fixes knowing the fore-aft position worse than this (σ, m) update y, z only
        self.fore_aft_fix_sigma_max_m = fore_aft_fix_sigma_max_m
        self._hist: deque[_Snapshot] = deque(maxlen=history + 1 if history else 1)
        self._hist_dt: deque[float] = deque(maxlen=history + 1 if history else 1)
        self.consecutive_rejections = 0
        self.reseeds = 0
        self.x = np.zeros(6)
        self.P = np.eye(6) * 1e3
        self.initialised = False
        self.ever_initialised = False
        self.coast_time_s = 0.0
        self.rejected = 0

    def reset(self) -> None:
        self.__init__(  # type: ignore[misc]
            self.accel_sigma,
            self.gate,
            self.reseed_after,
            self.history,
            self.hold_after_s,
            self.fore_aft_fix_sigma_max_m,
        )

    def _snapshot(self) -> _Snapshot:
        return (
            self.x.copy(),
            self.P.copy(),
            self.initialised,
            self.ever_initialised,
            self.coast_time_s,
            self.consecutive_rejections,
        )

    def _restore(self, s: _Snapshot) -> None:
        x, p, init, ever, coast, rej = s
        self.x, self.P = x.copy(), p.copy()
        self.initialised, self.ever_initialised = init, ever
        self.coast_time_s, self.consecutive_rejections = coast, rej

    @property
    def position(self) -> FloatArray:
        return self.x[:3].copy()

    @property
    def velocity(self) -> FloatArray:
        return self.x[3:].copy()

    def predict(self, dt: float) -> None:
        self._predict(dt)
        if self.history:
            self._hist.append(self._snapshot())
            self._hist_dt.append(dt)

    def update_delayed(self, z: FloatArray, r: FloatArray, age_ticks: int) -> bool:
        """Fuse a measurement taken ``age_ticks`` predictions ago (its exposure time): the
        state of then is restored, updated, and propagated again to now — exactly what a
        filter that had the measurement in time would hold. Needs ``history >= age_ticks``
        (older measurements are fused as if current)."""
        if age_ticks <= 0 or age_ticks >= len(self._hist):
            return self.update(z, r)
        hist = list(self._hist)
        dts = list(self._hist_dt)
        self._restore(hist[-1 - age_ticks])
        ok = self.update(z, r)
        # replay the predictions since the exposure, rewriting their snapshots
        keep = len(hist) - age_ticks
        while len(self._hist) > keep:
            self._hist.pop()
            self._hist_dt.pop()
        self._hist[-1] = self._snapshot()
        for dt in dts[keep:]:
            self.predict(dt)
        return ok

    def _predict(self, dt: float) -> None:
        if not self.initialised:
            self.coast_time_s += dt
            return
        f, q = _transition(float(dt), float(self.accel_sigma))
        self.x = f @ self.x
        self.P = f @ self.P @ f.T + q
        self.coast_time_s += dt
        if self.coast_time_s > self.hold_after_s:
            self.x[3:] = 0.0  # hold the last seen position (see hold_after_s)

    def _reseed(self, z: FloatArray, r: FloatArray, axes: list[int]) -> None:
        """The position on ``axes`` from the fix ``z`` (covariance ``r``), the velocity
        estimate kept (its variance reset to 1 m²/s²), both uncorrelated with the rest; a
        position axis the fix does not inform keeps its estimate and variance."""
        for i in axes + [3, 4, 5]:
            self.P[i, :] = 0.0
            self.P[:, i] = 0.0
        self.x[axes] = z[axes]
        self.P[np.ix_(axes, axes)] = r[np.ix_(axes, axes)]
        self.P[3:, 3:] = np.eye(3) * 1.0
        self.consecutive_rejections = 0
        self.coast_time_s = 0.0

    def update(self, z: FloatArray, r: FloatArray) -> bool:
        """Fuse a position measurement ``z`` (m) with covariance ``r``; False if gated out."""
        z = np.asarray(z, float)
        if not self.initialised:
            self.x = np.concatenate([z, np.zeros(3)])
            self.P = np.zeros((6, 6))
            self.P[:3, :3] = r
            self.P[3:, 3:] = np.eye(3) * 1.0
            self.initialised = self.ever_initialised = True
            self.coast_time_s = 0.0
            return True
        r = np.asarray(r, float)
        axes, h, r_used, gate = [0, 1, 2], _H, r, self.gate
        if float(r[0, 0]) > self.fore_aft_fix_sigma_max_m**2:  # cross-stream only
            axes, h, r_used = _CROSS, _H_CROSS, r[np.ix_(_CROSS, _CROSS)]
            gate = self.gate * CHI2_2_999 / CHI2_3_999
        nu = z[axes] - h @ self.x
        s = h @ self.P @ h.T + r_used
        nis = float(nu @ np.linalg.solve(s, nu))
        if nis > gate:
            self.rejected += 1
            self.consecutive_rejections += 1
            # persistent disagreement means the filter, not the measurement, is wrong (it lagged
            # a manoeuvre): re-seed the axes the fix informs from it, keeping the velocity
            if self.consecutive_rejections >= self.reseed_after:
                self._reseed(z, r, axes)
                self.reseeds += 1
                return True
            return False
        self.consecutive_rejections = 0
        k = self.P @ h.T @ np.linalg.inv(s)
        self.x = self.x + k @ nu
        self.P = (np.eye(6) - k @ h) @ self.P
        self.coast_time_s = 0.0
        return True
