"""The guidance's own model of the drogue: its lateral/vertical swing and the receiver's bow
wave on it — the *nominal* catalogue values of the hose type the tanker trails, never the flown
drogue's (the simulation may disperse those; the guidance must not know them).

The swing is a damped oscillator ``d̈ + 2ζω ḋ + ω² d = F/m`` (lateral y, vertical z;
:func:`app.control.drogue_swing.predict_swing_offset`); the bow wave a force
``F₀ exp(−s/ℓ)`` away from the nose axis and up (bias ε), ``s`` the axial distance
nose → drogue (:func:`app.control.bow_wave.bow_force_n`).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DrogueModel:
    """Nominal swing and bow-wave parameters (SI units; names carry them)."""

    omega_rad_s: float  # the swing's natural frequency
    damping_ratio: float  # its damping ratio ζ
    effective_mass_kg: float  # the drogue plus its share of the hose
    bow_force_n: float  # F₀, the bow wave's force with the nose at the drogue
    bow_length_m: float  # ℓ, its decay length along the nose axis
    bow_up_bias_m: float  # ε, the upward bias of its direction
    rest_m: tuple[float, float, float]  # the drogue's a-priori rest position (tanker frame)

    def __post_init__(self) -> None:
        for name in ("omega_rad_s", "effective_mass_kg", "bow_length_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        if not 0 <= self.damping_ratio < 1:
            raise ValueError(f"damping_ratio must be in [0, 1), got {self.damping_ratio!r}")
