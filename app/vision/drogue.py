"""The drogue the navigation looks for: its LED ring, as one JSON file.

A :class:`DrogueProfile` holds what the pipeline must know of the target — the ring radius
(mm), the LED count, optionally the LEDs' angles on the ring (deg, clockwise from the top at
roll 0, :mod:`app.geometry.led_ids`), the LED diameter (mm; the appearance test's expected
blob size) and the LED colour (``green``: the green-excess detection and the colour gate;
``white``: eq. 9's grey, no colour test). Every entry point takes one: ``aar-dock process``,
``track`` and ``serve`` (``--drogue FILE``, ``AAR_DROGUE``; ``--ring-radius-mm`` /
``AAR_RING_RADIUS_MM`` set the radius alone), the simulated stream, uploads and streams; every
recording stores the one it was made with (``drogue.json`` in a frame recording, the
``drogue`` metadata record of an MCAP log) and a replay uses it.

The file::

    {"name": "24-inch basket", "ring_radius_mm": 305, "led_count": 5,
     "led_diameter_mm": 20, "colour": "green", "led_angles_deg": [36, 108, 180, 252, 324]}

(``name`` and ``led_angles_deg`` optional). The ring search assigns LEDs to evenly spaced
slots, so given angles must be evenly spaced; they fix the phase of LED 1.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal, cast

from app.geometry.led_ids import DEFAULT_PHASE_DEG, wrap_deg
from app.vision.pipeline import PipelineConfig

DrogueColour = Literal["green", "white"]
COLOURS: tuple[DrogueColour, ...] = ("green", "white")
ANGLE_TOL_DEG = 0.5  # given LED angles may depart this much from even spacing
FIELDS = ("name", "ring_radius_mm", "led_count", "led_diameter_mm", "colour", "led_angles_deg")


class DrogueProfileError(ValueError):
    """A drogue profile that cannot be used (the message names the field or the file)."""


def _positive(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise DrogueProfileError(f"{name} must be a number, got {value!r}")
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise DrogueProfileError(f"{name} must be a positive number, got {value!r}")
    return v


@dataclass(frozen=True)
class DrogueProfile:
    """The drogue's LED ring (mm, deg). Construct through :meth:`from_dict` / :meth:`load` for
    checked input; the constructor checks too (``DrogueProfileError``)."""

    ring_radius_mm: float = 75.0
    led_count: int = 5
    led_diameter_mm: float = 5.0
    colour: DrogueColour = "green"
    led_angles_deg: tuple[float, ...] | None = None
    name: str = ""

    def __post_init__(self) -> None:
        _positive(self.ring_radius_mm, "ring_radius_mm")
        _positive(self.led_diameter_mm, "led_diameter_mm")
        n = self.led_count
        if isinstance(n, bool) or not isinstance(n, int) or not 3 <= n <= 64:
            raise DrogueProfileError(f"led_count must be an integer in 3..64, got {n!r}")
        if self.colour not in COLOURS:
            raise DrogueProfileError(f"colour must be one of {COLOURS}, got {self.colour!r}")
        if self.led_diameter_mm >= self.ring_radius_mm:
            raise DrogueProfileError(
                f"led_diameter_mm ({self.led_diameter_mm:g}) must be smaller than "
                f"ring_radius_mm ({self.ring_radius_mm:g})"
            )
        if self.led_angles_deg is not None:
            self._check_angles(self.led_angles_deg)

    def _check_angles(self, angles: tuple[float, ...]) -> None:
        if len(angles) != self.led_count:
            raise DrogueProfileError(
                f"led_angles_deg has {len(angles)} angles but led_count is {self.led_count}"
            )
        for a in angles:
            if isinstance(a, bool) or not isinstance(a, int | float) or not math.isfinite(a):
                raise DrogueProfileError(f"led_angles_deg must be finite numbers, got {a!r}")
        spacing = 360.0 / self.led_count
        for k, a in enumerate(angles):
            off = wrap_deg(float(a) - float(angles[0]) - k * spacing, 360.0)
            if abs(off) > ANGLE_TOL_DEG:
                raise DrogueProfileError(
                    f"led_angles_deg: LED {k + 1} at {a:g}° is {off:+.1f}° off the even "
                    f"spacing of {spacing:g}° (the ring search needs evenly spaced LEDs)"
                )

    @property
    def phase_deg(self) -> float:
        """Angle of LED 1 at roll 0 (deg): the first given angle, else the paper's 36°."""
        if self.led_angles_deg is None:
            return DEFAULT_PHASE_DEG
        return float(self.led_angles_deg[0])

    @property
    def label(self) -> str:
        """A short description for the page, ``/healthz`` and logs."""
        ring = f"{self.ring_radius_mm:g} mm ring, {self.led_count} {self.colour} LEDs"
        return f"{self.name} ({ring})" if self.name else ring

    def with_radius(self, ring_radius_mm: float) -> DrogueProfile:
        """The same drogue with another ring radius (``--ring-radius-mm``)."""
        radius = _positive(ring_radius_mm, "ring radius (mm)")
        if radius == self.ring_radius_mm:
            return self
        # another drogue: the name no longer applies
        return replace(self, ring_radius_mm=radius, name="")

    def pipeline_config(self, base: PipelineConfig | None = None) -> PipelineConfig:
        """``base`` (default: the pipeline's defaults) set up to look for this drogue."""
        cfg = base or PipelineConfig()
        appearance = cfg.appearance
        if self.colour == "white":  # no colour to test: grey detection, no colour gate
            appearance = replace(appearance, colour_gate=False, green_ratio=0.0)
        return replace(
            cfg,
            ring_radius_mm=self.ring_radius_mm,
            led_count=self.led_count,
            led_phase_deg=self.phase_deg,
            led_diameter_mm=self.led_diameter_mm,
            colour_detect="green" if self.colour == "green" else "gray",
            appearance=appearance,
        )

    # ---- the file -------------------------------------------------------------------------
    def to_dict(self) -> dict[str, object]:
        d: dict[str, object] = {
            "name": self.name,
            "ring_radius_mm": self.ring_radius_mm,
            "led_count": self.led_count,
            "led_diameter_mm": self.led_diameter_mm,
            "colour": self.colour,
        }
        if self.led_angles_deg is not None:
            d["led_angles_deg"] = list(self.led_angles_deg)
        return d

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    def save(self, path: str | Path) -> None:
        Path(path).write_text(self.to_json() + "\n")

    @classmethod
    def from_dict(cls, data: object) -> DrogueProfile:
        """A profile from parsed JSON; ``DrogueProfileError`` naming what is wrong."""
        if not isinstance(data, dict):
            raise DrogueProfileError(
                f"a drogue profile is a JSON object, got {type(data).__name__}"
            )
        unknown = sorted(set(data) - set(FIELDS))
        if unknown:
            raise DrogueProfileError(f"unknown field(s) {unknown}; the fields are {list(FIELDS)}")
        missing = [k for k in ("ring_radius_mm", "led_count", "led_diameter_mm") if k not in data]
        if missing:
            raise DrogueProfileError(f"missing field(s) {missing}")
        angles = data.get("led_angles_deg")
        if angles is not None and not isinstance(angles, list):
            raise DrogueProfileError(f"led_angles_deg must be a list, got {angles!r}")
        name = data.get("name", "")
        if not isinstance(name, str):
            raise DrogueProfileError(f"name must be a string, got {name!r}")
        radius = _positive(data["ring_radius_mm"], "ring_radius_mm")
        diameter = _positive(data["led_diameter_mm"], "led_diameter_mm")
        return cls(
            ring_radius_mm=radius,
            led_count=cast(int, data["led_count"]),
            led_diameter_mm=diameter,
            colour=cast(DrogueColour, data.get("colour", "green")),
            led_angles_deg=None if angles is None else tuple(angles),
            name=name,
        )

    @classmethod
    def from_json(cls, text: str, source: str = "drogue profile") -> DrogueProfile:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DrogueProfileError(f"{source}: not JSON ({exc})") from None
        try:
            return cls.from_dict(data)
        except DrogueProfileError as exc:
            raise DrogueProfileError(f"{source}: {exc}") from None

    @classmethod
    def load(cls, path: str | Path) -> DrogueProfile:
        """Read a profile file; ``DrogueProfileError`` naming the file."""
        p = Path(path)
        try:
            text = p.read_text()
        except (OSError, UnicodeDecodeError) as exc:
            raise DrogueProfileError(f"{p}: cannot read the drogue profile ({exc})") from None
        return cls.from_json(text, str(p))


#: The paper's ring (§3.1, Table 5): the bundled calibration's and sample pairs' drogue, and
#: what a camera, video, push or upload assumes when no drogue is configured.
PAPER_DROGUE = DrogueProfile(75.0, 5, 5.0, "green", name="paper ring")
#: The simulated stream's drogue when none is configured: a 24-inch basket (305 mm rim) with
#: 20 mm LEDs, seen from 10 m at the start of a run.
BASKET_24IN = DrogueProfile(305.0, 5, 20.0, "green", name="24-inch basket")


def resolve_drogue(
    path: str | Path | None, ring_radius_mm: float | None, default: DrogueProfile
) -> DrogueProfile:
    """The drogue of ``--drogue FILE`` (else ``default``), its radius replaced by
    ``--ring-radius-mm`` where given; ``DrogueProfileError`` for a bad file or radius."""
    profile = DrogueProfile.load(path) if path else default
    return profile if ring_radius_mm is None else profile.with_radius(ring_radius_mm)
