"""What crosses the simulation worker's pipe: the message tuples and the calibration as a dict.

One duplex pipe between the web server's process (parent) and the worker (child); every
message is a tuple whose first item names it.

Parent → worker:

* ``("build", sid, DockingConfig, calibration dict | None)``: the validated config (checked
  in the parent, so a refused config raises there exactly as in-process) and the calibration
  (:func:`calibration_to_wire`, exact floats). Answered ``("built", sid, done)`` once the new
  simulation is built, or with an :func:`error_reply` (the previous simulation and its
  schedule are kept, so a refused config leaves the running source untouched);
* ``("run", sid, gen, period_s, first_deadline_s)``: start the worker's schedule for the
  simulation ``sid`` (run request ``gen``); refused with a ``tickerror``;
* ``("pause",)``: end the schedule (the ticks computed ahead are kept);
* ``("ping",)``: answered ``("pong", pid)``; ``("stop",)``: the worker exits.

Worker → parent, unasked, on its schedule (:data:`STREAM`):

* ``("tick", sid, gen, DockingTick without images, done, sim_ms, ring slot, stamp,
  inline images | None, deadline_s, released_s, missed_deadlines)``: the tick is pickled whole,
  so every field but its images arrives (the run-time assurance's ``rta_reason`` and the run's
  ``run_outcome`` with the rest) and the record is built from it as in-process;
* ``("tickerror", sid, gen, kind, message, traceback)``: the step raised (the schedule ends).

At start-up the worker sends ``("ready", pid, scheduling policy)``. Times are on the
machine's monotonic clock (``time.monotonic``, the same in every process).
"""

from __future__ import annotations

import logging
import traceback
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from app.geometry.calibration import StereoCalibration

log = logging.getLogger(__name__)

Message = tuple[Any, ...]
"""One message on the pipe: its kind first, then the fields listed above."""

STREAM = ("tick", "tickerror")  # what the worker sends unasked, on its schedule


def calibration_to_wire(calibration: StereoCalibration | None) -> dict[str, Any] | None:
    """A JSON-able dict of a :class:`StereoCalibration` (``None`` stays ``None``)."""
    return None if calibration is None else dict(calibration.to_dict())


def calibration_from_wire(data: dict[str, Any] | None) -> StereoCalibration | None:
    """Rebuild the calibration bit for bit (no re-validation: the parent validated it;
    ``StereoCalibration.from_dict`` would re-orthonormalise R and move it by an ulp)."""
    if data is None:
        return None
    from app.streams.frame_log import exact_calibration

    calibration: StereoCalibration = exact_calibration(data)
    return calibration


def error_reply(exc: BaseException) -> Message:
    """``("error", kind, message, traceback)`` for an exception raised in the worker."""
    return ("error", type(exc).__name__, str(exc), traceback.format_exc())


def raise_remote(reply: Message) -> None:
    """Raise an ``error`` reply in the parent: ``ValueError`` and ``TypeError`` as such (a
    refused config), anything else as a ``RuntimeError`` naming its kind."""
    _, kind, message, tb = reply
    if kind == "ValueError":
        raise ValueError(message)
    if kind == "TypeError":
        raise TypeError(message)
    if tb:
        log.debug("simulation worker traceback:\n%s", tb)
    raise RuntimeError(f"{kind}: {message}")
