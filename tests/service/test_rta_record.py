"""The run-time assurance's hand-overs (``rta_reason``) and the run's outcome (``run_outcome``)
reach the published record from a :class:`DockingTick`, in process (the tick loop) and from
the simulation worker (the tick pickled through its pipe, then :class:`ProcessTick`)."""

from __future__ import annotations

import json
import multiprocessing
from typing import Any, get_args

import numpy as np

from app.model.tick import RunOutcome, TickRecord
from app.service import records
from app.service.clock import FakeClock
from app.service.sim_worker.proxy import ProcessTick
from app.service.sim_worker.wire import TickMessage
from app.service.sim_worker.worker import ComputedTick, WorkerState
from app.service.telemetry import STREAM_EXCLUDE
from app.service.tick_loop import TickLoop
from app.sim.docking.outcomes import OUTCOMES
from app.sim.docking.results import DockingTick
from app.sim.sim_config import SimConfig
from tests.support.fake_sim import FakeSimState
from tests.support.inline_sim import inline_sim

BREAK_AWAY = "break-away: missed the drogue by 0.199 m"
ENVELOPE = "envelope: α 10.2° above 10.0°"


def test_the_records_outcome_classes_are_the_simulations() -> None:
    assert get_args(RunOutcome) == OUTCOMES


def test_the_tick_loop_publishes_the_hand_overs_and_the_outcome() -> None:
    plan = [(None, None), (BREAK_AWAY, None), (ENVELOPE, None), (None, "departure")]

    class Source:
        def __init__(self) -> None:
            self.k = 0

        @property
        def done(self) -> bool:
            return self.k >= len(plan)

        def step(self) -> FakeSimState:
            reason, outcome = plan[self.k]
            self.k += 1
            return FakeSimState(t_s=0.1 * self.k, rta_reason=reason, run_outcome=outcome)

    loop = TickLoop(
        SimConfig(tick_hz=10.0),
        None,
        source_factory=inline_sim(lambda config, calibration: Source()),
        clock=FakeClock(),
        auto_restart_s=None,
    )
    got: list[TickRecord] = []
    loop.bus.subscribe(lambda record, raw: got.append(record))
    loop.start_sim()
    loop.run_iterations(10 * len(plan))  # the fake clock's waits between the deadlines too
    assert [(r.rta_reason, r.run_outcome) for r in got] == plan
    # the telemetry WebSocket's JSON keeps both fields
    sent = [json.loads(r.model_dump_json(exclude=STREAM_EXCLUDE)) for r in got]
    assert [(m["rta_reason"], m["run_outcome"]) for m in sent] == plan


def _docking_tick(rta_reason: str | None, run_outcome: str | None) -> DockingTick:
    z = np.zeros(3)
    image = np.zeros((4, 6), np.uint8)
    return DockingTick(
        t_s=1.5,
        phase="breakaway",
        drogue_truth_m=z,
        drogue_normal=np.array([-1.0, 0.0, 0.0]),
        drogue_measured_m=None,
        drogue_estimate_m=z,
        probe_tip_m=z,
        uav_state=np.zeros(12),
        reference_m=z,
        control=np.zeros(4),
        lock=False,
        lock_reason="no LEDs",
        pose=None,
        left_image=image,
        right_image=image,
        led_truth_cam_mm=None,
        captured=False,
        miss_m=None,
        rel_position_m=z,
        rta_reason=rta_reason,
        run_outcome=run_outcome,
    )


def test_the_worker_pipe_carries_the_hand_overs_and_the_outcome() -> None:
    """What the worker sends for a step (its :class:`TickMessage`: the tick without its
    images) through a real pipe, read back as the parent does (:class:`ProcessTick`)."""

    class Sim:
        def __init__(self, tick: DockingTick) -> None:
            self.tick = tick
            self.done = tick.run_outcome is not None

        def step(self) -> DockingTick:
            return self.tick

    state = WorkerState(None, epoch=1, image_period_s=float("inf"))
    parent, child = multiprocessing.Pipe(duplex=True)
    got: list[TickRecord] = []
    try:
        for reason, outcome in [(ENVELOPE, None), (None, "departure")]:
            sim: Any = Sim(_docking_tick(reason, outcome))
            computed = state.step(sim)
            assert isinstance(computed, ComputedTick), computed
            child.send(computed.released(7, 1, 10.0, 10.001, 0))  # as worker_main sends
            msg = parent.recv()
            assert isinstance(msg, TickMessage)
            assert (msg.sid, msg.gen, msg.deadline_s, msg.released_s) == (7, 1, 10.0, 10.001)
            assert msg.tick.left_image is None  # the images travel apart
            raw = ProcessTick.of(msg, None, received_s=10.002)
            assert (raw.state.rta_reason, raw.state.run_outcome) == (reason, outcome)
            assert msg.done == (outcome is not None)
            t = records.from_sim(raw.state, step_ms=1.0, raw=raw)
            got.append(records.to_record(t, seq=len(got), clock_s=0.0, run=3))
    finally:
        parent.close()
        child.close()
    assert [(r.rta_reason, r.run_outcome, r.phase) for r in got] == [
        (ENVELOPE, None, "breakaway"),
        (None, "departure", "breakaway"),
    ]
