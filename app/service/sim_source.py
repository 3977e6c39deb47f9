"""What the tick loop steps: the simulation source contract and the service's config of it.

The simulation has one execution path: the worker of :mod:`app.service.sim_worker` (a
``spawn`` process in the service; tests inject a launcher that runs the same worker loop in
their process). Its source is *paced* (:class:`PacedSource`): it keeps the schedule itself,
its ``step()`` blocks until the tick for its next deadline is released and returns a
:class:`PacedTick` (the state, the images read lazily, the schedule); ``pause()`` stops that
schedule.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from app.service.records import RawFrame, SimState
from app.sim.sim_config import SimConfig

if TYPE_CHECKING:
    from app.geometry.calibration import StereoCalibration
    from app.sim.docking import DockingConfig


class PacedTick(RawFrame, Protocol):
    """A tick released by a paced source at its deadline.

    On the machine's monotonic clock (s): ``deadline_s`` (the deadline it serves),
    ``released_s`` (when the source released it: its result available), ``received_s`` (when
    this process had it; ``None`` if not measured); ``missed_deadlines``: the deadlines the
    source skipped just before this one; ``extra_timings_ms``: e.g. ``sim``, the worker's own
    compute time."""

    @property
    def state(self) -> SimState: ...
    @property
    def deadline_s(self) -> float: ...
    @property
    def released_s(self) -> float: ...
    @property
    def received_s(self) -> float | None: ...
    @property
    def missed_deadlines(self) -> int: ...
    @property
    def extra_timings_ms(self) -> Mapping[str, float]: ...


@runtime_checkable
class PacedSource(Protocol):
    """A source that keeps the schedule (``paced``): ``step()`` waits for its next tick."""

    paced: bool

    @property
    def done(self) -> bool: ...

    def step(self) -> PacedTick: ...

    def pause(self) -> None: ...


SourceFactory = Callable[[SimConfig, "StereoCalibration | None"], PacedSource]


class SourceRestarted(RuntimeError):
    """Raised by ``step()`` of a source whose backend was lost and has been rebuilt from its
    config (e.g. a crashed simulation worker process): this step failed (an error is counted)
    and the next one starts a new run (``TickLoop.run`` is incremented)."""


class SourceUnavailable(RuntimeError):
    """A source could not be built because its backend is unavailable (not a refused config)."""


def docking_config(config: SimConfig) -> DockingConfig:
    """The :class:`app.sim.docking.DockingConfig` for a service :class:`SimConfig`."""
    from app.sim.docking import DockingConfig

    return DockingConfig(
        plant=config.plant,
        turbulence=config.turbulence,
        seed=config.seed,
        closure_speed_mps=config.closure_speed_mps,
        tick_hz=config.tick_hz,
        vision=config.vision,
        matcher=config.matcher,
        noise_sigma=config.noise_sigma,
        clutter=config.clutter,
        led_dropout=tuple(config.led_dropout),
        led_count=config.drogue.led_count,
        ring_radius_m=config.drogue.ring_radius_mm / 1000.0,
        led_diameter_mm=config.drogue.led_diameter_mm,
        hose_model=config.hose_model,
    )
