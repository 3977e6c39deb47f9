"""What crosses the simulation worker's pipe: frozen, typed messages and the calibration.

One duplex pipe between the web server's process (parent) and the worker (child); every
message is one of the frozen records below, pickled whole (no positional tuples, no kind
strings: each side dispatches on the record's type).

Parent → worker (:data:`Request`):

* :class:`Build`: the validated :class:`DockingConfig` (checked in the parent, so a refused
  config raises there exactly as in-process) and the calibration (:func:`calibration_to_wire`,
  exact floats). Answered :class:`Built` once the new simulation is built, or with an
  :class:`ErrorReply` (the previous simulation and its schedule are kept, so a refused config
  leaves the running source untouched);
* :class:`Run`: start the worker's schedule for the simulation ``sid`` (run request ``gen``);
  refused with a :class:`TickError`;
* :class:`Pause`: end the schedule (the ticks computed ahead are kept);
* :class:`Ping`: answered :class:`Pong`; :class:`Stop`: the worker exits.

Worker → parent, unasked, on its schedule (:data:`STREAM`):

* :class:`TickMessage`: the :class:`DockingTick` without its images is pickled whole, so every
  field but its images arrives (the run-time assurance's ``rta_reason`` and the run's
  ``run_outcome`` with the rest) and the record is built from it as in-process; the images are
  in the shared-memory ring (``slot``, ``stamp``) or inline;
* :class:`TickError`: the step raised (the schedule ends).

At start-up the worker sends :class:`Ready`. Times are on the machine's monotonic clock
(``time.monotonic``, the same in every process), in seconds.
"""

from __future__ import annotations

import logging
import traceback
from dataclasses import dataclass
from typing import TYPE_CHECKING, NoReturn, TypedDict

from app.types import UInt8Array

if TYPE_CHECKING:
    from app.geometry.calibration import CameraIntrinsics, StereoCalibration
    from app.sim.docking import DockingConfig, DockingTick

log = logging.getLogger(__name__)


# ---- the calibration on the wire ----------------------------------------------------------
class WireCamera(TypedDict):
    """One camera's intrinsics as plain lists (``CameraIntrinsics.to_dict()``'s layout)."""

    K: list[list[float]]  # 3×3 camera matrix, px
    dist: list[float]  # distortion coefficients (OpenCV order), unitless


class WireCalibration(TypedDict):
    """A :class:`StereoCalibration` as plain lists of exact floats (``to_dict()``'s layout,
    JSON-able, so the upload workers key their cache on its JSON text)."""

    image_size: list[int]  # [width, height], px
    left: WireCamera
    right: WireCamera
    R: list[list[float]]  # 3×3 rotation, X_right = R · X_left + T
    T: list[float]  # (3,) translation, mm
    units: str  # always "mm"


def _camera_to_wire(camera: CameraIntrinsics) -> WireCamera:
    return {"K": camera.K.tolist(), "dist": camera.dist.tolist()}


def calibration_to_wire(calibration: StereoCalibration) -> WireCalibration:
    """The calibration as plain lists (``float.tolist()``: every bit kept)."""
    w, h = calibration.image_size
    return {
        "image_size": [int(w), int(h)],
        "left": _camera_to_wire(calibration.left),
        "right": _camera_to_wire(calibration.right),
        "R": calibration.R.tolist(),
        "T": calibration.T.tolist(),
        "units": "mm",
    }


def calibration_from_wire(data: WireCalibration) -> StereoCalibration:
    """Rebuild the calibration bit for bit (no re-validation: the parent validated it;
    ``StereoCalibration.from_dict`` would re-orthonormalise R and move it by an ulp)."""
    from app.streams.frame_log import exact_calibration

    calibration: StereoCalibration = exact_calibration(data)
    return calibration


# ---- parent → worker ----------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Build:
    """Build a new simulation ``sid`` (the parent's counter) from a validated config."""

    sid: int
    config: DockingConfig
    calibration: WireCalibration | None  # None: the simulation's default rig


@dataclass(frozen=True, slots=True)
class Run:
    """Start the worker's schedule for simulation ``sid``, run request ``gen``: deadlines
    ``period_s`` apart from ``first_deadline_s`` (monotonic clock, s)."""

    sid: int
    gen: int
    period_s: float
    first_deadline_s: float


@dataclass(frozen=True, slots=True)
class Pause:
    """End the schedule (the ticks computed ahead are kept for the next :class:`Run`)."""


@dataclass(frozen=True, slots=True)
class Ping:
    """Answered :class:`Pong` (a round trip through the pipe)."""


@dataclass(frozen=True, slots=True)
class Stop:
    """The worker exits."""


Request = Build | Run | Pause | Ping | Stop
"""What the parent sends."""


# ---- worker → parent ----------------------------------------------------------------------
@dataclass(frozen=True, slots=True)
class Ready:
    """Sent once at start-up: the worker's pid and its CPU scheduling (``"rr"``, ``"nice"``
    or ``"default"``)."""

    pid: int
    policy: str


@dataclass(frozen=True, slots=True)
class Built:
    """Simulation ``sid`` is built; ``done``: it has nothing to step."""

    sid: int
    done: bool


@dataclass(frozen=True, slots=True)
class Pong:
    """The answer to :class:`Ping`: the worker's pid."""

    pid: int


@dataclass(frozen=True, slots=True)
class ErrorReply:
    """An exception raised in the worker: its type's name, its message and its traceback
    (``""`` when none)."""

    kind: str
    message: str
    traceback: str


@dataclass(frozen=True, slots=True)
class TickMessage:
    """The tick released at a deadline of run ``gen`` of simulation ``sid``.

    ``tick``: the :class:`DockingTick` without its images (every other field); ``done``: the
    simulation finished with it; ``sim_ms``: the worker's compute time for it (ms); the images:
    in ring ``slot`` under ``stamp`` (``slot`` −1: not in the ring), or ``inline`` (left,
    right), or neither (rate-limited); ``deadline_s``: the deadline it serves, ``released_s``:
    when the worker sent it (monotonic clock, s); ``missed_deadlines``: the deadlines skipped
    just before this one."""

    sid: int
    gen: int
    tick: DockingTick
    done: bool
    sim_ms: float
    slot: int
    stamp: int
    inline: tuple[UInt8Array, UInt8Array] | None
    deadline_s: float
    released_s: float
    missed_deadlines: int


@dataclass(frozen=True, slots=True)
class TickError:
    """Run ``gen`` of simulation ``sid`` failed (its step raised, or the run was refused: a
    stale or finished simulation); the schedule ends."""

    sid: int
    gen: int
    error: ErrorReply


Reply = Ready | Built | Pong | ErrorReply | TickMessage | TickError
"""What the worker sends."""

STREAM = (TickMessage, TickError)  # what the worker sends unasked, on its schedule


def error_reply(exc: BaseException) -> ErrorReply:
    """The :class:`ErrorReply` for an exception raised in the worker (call it in the
    ``except`` block: the traceback is the one being handled)."""
    return ErrorReply(type(exc).__name__, str(exc), traceback.format_exc())


def raise_remote(error: ErrorReply) -> NoReturn:
    """Raise an error reply in the parent: ``ValueError``, ``TypeError`` and
    ``RuntimeError`` as such (a refused config, a failed step), anything else as a
    ``RuntimeError`` naming its kind."""
    if error.kind == "ValueError":
        raise ValueError(error.message)
    if error.kind == "TypeError":
        raise TypeError(error.message)
    if error.traceback:
        log.debug("simulation worker traceback:\n%s", error.traceback)
    if error.kind == "RuntimeError":
        raise RuntimeError(error.message)
    raise RuntimeError(f"{error.kind}: {error.message}")
