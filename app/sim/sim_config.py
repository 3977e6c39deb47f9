"""The user-settable configuration of the simulated docking stream (core: no web imports).

One model for every way in: the REST API (``PUT /api/v1/sim/config``, re-exported by
:mod:`app.server.schemas`), the 3-D view's controls (:mod:`app.viz.gui`) and the tick loop.
Out-of-range values raise :class:`pydantic.ValidationError` (the API answers 422).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from app.sim.plant import DEFAULT_PLANT
from app.vision.drogue import BASKET_24IN, DrogueProfile

Turbulence = Literal["none", "light", "moderate", "severe"]
Plant = Literal["jsbsim", "linear"]
HoseModel = Literal["reduced", "multibody"]  # app.sim.docking.HOSE_MODELS
TURBULENCE_LEVELS: tuple[Turbulence, ...] = ("none", "light", "moderate", "severe")
LED_COUNT = 5

#: Request models: an unknown field (a typo such as ``"turbulance"``) or a non-finite number
#: (``NaN``, ``Infinity``) is a validation error naming the field, never silently ignored.
STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)


class SimConfig(BaseModel):
    """User-settable simulation parameters (validated ranges → 422)."""

    model_config = STRICT

    plant: Plant = Field(
        DEFAULT_PLANT,
        description="receiver plant: jsbsim (the A-4 on JSBSim's nonlinear FDM) or linear "
        "(the controller's own design model)",
    )
    turbulence: Turbulence = "light"
    seed: int = Field(0, ge=0, le=2**31 - 1)
    closure_speed_mps: float = Field(1.2, ge=0.1, le=5.0)
    noise_sigma: float = Field(2.0, ge=0.0, le=50.0, description="image noise σ (grey levels)")
    clutter: int = Field(0, ge=0, le=50, description="number of distractor lights")
    led_dropout: list[int] = Field(default_factory=list, description="LED ids (1..5) switched off")
    tick_hz: float = Field(30.0, ge=1.0, le=120.0)
    matcher: Literal["epipolar", "paper"] = "epipolar"
    vision: bool = True
    hose_model: HoseModel = Field(
        "reduced",
        description="the flown hose: reduced (a second-order swing on a static shape) or "
        "multibody (the lumped-mass hose with its reel and coupling)",
    )
    drogue: DrogueProfile = Field(
        BASKET_24IN,
        description="the drogue flown and looked for (app/vision/drogue.py; the service's "
        "AAR_DROGUE / AAR_RING_RADIUS_MM, else a 24-inch basket); not settable here",
    )

    @field_validator("led_dropout")
    @classmethod
    def _check_dropout(cls, v: list[int]) -> list[int]:
        if any(i < 1 or i > LED_COUNT for i in v):
            raise ValueError(f"LED ids must be in 1..{LED_COUNT}")
        if len(set(v)) != len(v):
            raise ValueError("LED ids must be unique")
        return sorted(v)
