"""The LED id convention, shared by the renderer, the pipeline, the scene and the tests.

LED k (k = 0..N−1, id k+1) sits at the angle θ_k = phase + roll + k·360°/N around the ring,
measured clockwise from the top as seen by the cameras: 0° is the camera's up direction (−y)
projected on the ring plane (:func:`app.geometry.circle_fit.plane_basis`). With the default
phase of 36° and N = 5, LED 1 is the first LED clockwise from 12 o'clock at roll 0 (paper
Table 5's labels).

Identical LEDs give the roll only modulo 360°/N. At acquisition (no track) the pipeline takes
the roll in [−180°/N, +180°/N): ids are the physical ids while |roll| < 180°/N (36° for five
LEDs). While tracking, the roll is continued from the previous frame (the nearest of the N
candidates), so the ids stay with the same physical LEDs through any roll as long as the
drogue turns by less than 180°/N between frames.
"""

from __future__ import annotations

import numpy as np

DEFAULT_PHASE_DEG = 36.0


def wrap_deg(angle_deg: float, period_deg: float) -> float:
    """``angle_deg`` wrapped to [−period/2, period/2)."""
    return (angle_deg + 0.5 * period_deg) % period_deg - 0.5 * period_deg


def roll_from_offset(
    offset_deg: float,
    count: int,
    phase_deg: float = DEFAULT_PHASE_DEG,
    prior_roll_deg: float | None = None,
) -> float:
    """Drogue roll (deg) from the slot offset (angle of any LED slot, deg).

    Without a prior, the roll in [−180°/N, 180°/N); with one, the candidate (roll + k·360°/N)
    nearest to it (unwrapped, so it can grow past ±180°)."""
    spacing = 360.0 / count
    base = float(offset_deg) - float(phase_deg)
    if prior_roll_deg is None:
        return wrap_deg(base, spacing)
    return base + spacing * round((float(prior_roll_deg) - base) / spacing)


def led_ids_for_angles(
    angles_deg: np.ndarray, roll_deg: float, count: int, phase_deg: float = DEFAULT_PHASE_DEG
) -> np.ndarray:
    """Ids (1..N) of LEDs at these ring angles (deg) for the given roll."""
    spacing = 360.0 / count
    k = np.rint((np.asarray(angles_deg, dtype=np.float64) - phase_deg - roll_deg) / spacing)
    return (np.mod(k, count) + 1).astype(np.int64)
