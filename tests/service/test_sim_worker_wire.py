"""The simulation worker's pipe (``app.service.sim_worker.wire``): frozen, typed messages that
pickle whole, and the calibration carried bit for bit."""

from __future__ import annotations

import dataclasses
import json
import pickle
from dataclasses import FrozenInstanceError

import numpy as np
import pytest

from app.geometry.calibration import StereoCalibration
from app.resources import load_default_calibration
from app.service.sim_source import docking_config
from app.service.sim_worker import wire
from app.sim.sim_config import SimConfig

MESSAGES = [
    wire.Run(sid=3, gen=2, period_s=1 / 30, first_deadline_s=12.5),
    wire.Pause(),
    wire.Ping(),
    wire.Stop(),
    wire.Ready(pid=42, policy="nice"),
    wire.Built(sid=3, done=False),
    wire.Pong(pid=42),
    wire.ErrorReply("ValueError", "bad config", "Traceback ..."),
    wire.TickError(sid=3, gen=2, error=wire.ErrorReply("RuntimeError", "stale", "")),
]


@pytest.mark.parametrize("msg", MESSAGES, ids=lambda m: type(m).__name__)
def test_every_message_is_a_frozen_record_that_pickles_whole(msg: object) -> None:
    assert dataclasses.is_dataclass(msg) and not isinstance(msg, tuple)
    assert pickle.loads(pickle.dumps(msg)) == msg
    for field in dataclasses.fields(msg):
        with pytest.raises(FrozenInstanceError):
            setattr(msg, field.name, None)


def test_the_requests_and_replies_are_the_records() -> None:
    assert set(wire.Request.__args__) == {wire.Build, wire.Run, wire.Pause, wire.Ping, wire.Stop}
    assert wire.STREAM == (wire.TickMessage, wire.TickError)
    assert set(wire.STREAM) <= set(wire.Reply.__args__)


def _nudged(calibration: StereoCalibration) -> StereoCalibration:
    """The calibration with R moved by an ulp (not exactly orthonormal: from_dict would
    re-orthonormalise it)."""
    R = calibration.R.copy()
    R[0, 1] = np.nextafter(R[0, 1], 1.0)
    return dataclasses.replace(calibration, R=R)


def test_the_calibration_crosses_bit_for_bit() -> None:
    calibration = _nudged(load_default_calibration())
    sent = wire.calibration_to_wire(calibration)
    assert sent == calibration.to_dict()  # the layout the recordings and MCAP logs use
    build = wire.Build(1, config=docking_config(SimConfig()), calibration=sent)
    got = pickle.loads(pickle.dumps(build))
    assert got.config == build.config and got.calibration is not None
    back = wire.calibration_from_wire(got.calibration)
    from_json = wire.calibration_from_wire(json.loads(json.dumps(sent)))  # the upload workers
    for rebuilt in (back, from_json):
        assert rebuilt.image_size == calibration.image_size
        for name in ("R", "T"):
            assert getattr(rebuilt, name).tobytes() == getattr(calibration, name).tobytes()
        for cam in ("left", "right"):
            for name in ("K", "dist"):
                a, b = (
                    getattr(getattr(rebuilt, cam), name),
                    getattr(getattr(calibration, cam), name),
                )
                assert a.tobytes() == b.tobytes()


@pytest.mark.parametrize(
    ("kind", "raised"),
    [("ValueError", ValueError), ("TypeError", TypeError), ("KeyError", RuntimeError)],
)
def test_an_error_reply_is_raised_in_the_parent(kind: str, raised: type[Exception]) -> None:
    with pytest.raises(raised, match="the message"):
        wire.raise_remote(wire.ErrorReply(kind, "the message", ""))
