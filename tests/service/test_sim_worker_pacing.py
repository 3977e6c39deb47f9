"""The tick schedule kept by the simulation worker (``app.service.sim_worker``) and the tick
loop relaying a paced source (``app.service.tick_loop``); the step latency's definition."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from app.service.clock import FakeClock
from app.service.sim_worker import proxy, worker
from app.service.tick_loop import TickLoop
from app.sim.sim_config import SimConfig
from tests.support.fake_sim import FakeSimState
from tests.support.inline_sim import inline_sim


def test_pace_serves_deadlines_a_period_apart_and_counts_the_missed_ones() -> None:
    pace = worker.Pace(sid=1, gen=1, period_s=0.1, first_deadline=10.0)
    assert pace.due(10.0) == (10.0, 0)
    assert pace.next_t == pytest.approx(10.1)
    assert pace.due(10.13) == (pytest.approx(10.1), 0)  # late, but before the next deadline
    # at 10.45 the deadlines 10.2, 10.3 and 10.4 have all passed: the latest is served
    deadline, missed = pace.due(10.45)
    assert deadline == pytest.approx(10.4) and missed == 2  # 10.2 and 10.3 skipped
    assert pace.next_t == pytest.approx(10.5)


def test_worker_releases_ticks_on_its_own_schedule_and_pause_keeps_the_simulation() -> None:
    from app.geometry.calibration import StereoCalibration
    from app.service.settings import DEFAULT_CALIBRATION

    hz = 20.0
    factory = proxy.process_source_factory()
    try:
        src = factory(SimConfig(tick_hz=hz), StereoCalibration.load(DEFAULT_CALIBRATION))
        assert src.paced
        t_start = time.monotonic()
        ticks = [src.step() for _ in range(10)]
        t_end = time.monotonic()
        src.pause()
        time.sleep(0.3)  # no schedule: nothing is released meanwhile
        t_resume = time.monotonic()
        after = [src.step() for _ in range(3)]
        assert factory.worker.policy in ("rr", "nice", "default")
    finally:
        factory.close()
    period = 1.0 / hz
    deadlines = np.array([t.deadline_s for t in ticks])
    # deadlines a whole number of periods apart: 1 + the deadlines missed in between
    gaps = np.diff(deadlines) / period
    missed = np.array([t.missed_deadlines for t in ticks[1:]])
    np.testing.assert_allclose(gaps, 1 + missed, atol=1e-6)
    assert ticks[0].deadline_s >= t_start  # the schedule starts at the first step
    # released at (or after) the deadline, never before: the loop keeps its rate, it does not
    # run as fast as it can (10 ticks span 9 periods at least)
    for t in ticks + after:
        assert t.released_s >= t.deadline_s and t.received_s >= t.released_s
        assert t.extra_timings_ms["sim"] > 0
    assert t_end - t_start >= 9 * period - 1e-3
    # after the pause a new schedule: its first deadline is not a stale one
    assert after[0].deadline_s >= t_resume
    # the simulation went on where it was (the ticks computed ahead were kept, none skipped)
    t_s = [t.state.t_s for t in ticks + after]
    dt = float(np.median(np.diff(t_s)))
    np.testing.assert_allclose(np.diff(t_s), dt, rtol=1e-9, atol=1e-9)


@dataclass
class _PacedTick:
    """What a paced source's tick carries (``app.service.sim_worker.proxy.ProcessTick``)."""

    t_s: float
    deadline_s: float
    released_s: float
    missed_deadlines: int
    paced: bool = True
    extra_timings_ms: dict[str, float] = field(default_factory=dict)
    received_s: float | None = None

    @property
    def state(self) -> FakeSimState:
        return FakeSimState(t_s=self.t_s)


class _PacedSource:
    """In-process stand-in for the worker: each ``step()`` is a tick released at a deadline."""

    paced = True

    def __init__(self, plan: list[tuple[float, int]]) -> None:
        self.plan = list(plan)  # (release lateness s, missed deadlines) per tick
        self.steps = 0
        self.paused = 0
        self.deadline = time.monotonic() - 1.0  # released in the past: relayed at once

    @property
    def done(self) -> bool:
        return self.steps >= len(self.plan)

    def step(self) -> Any:
        late, missed = self.plan[self.steps]
        self.steps += 1
        self.deadline += (1 + missed) * 0.05
        return _PacedTick(0.05 * self.steps, self.deadline, self.deadline + late, missed)

    def pause(self) -> None:
        self.paused += 1


def _started_loop(source: Any, clock: FakeClock, hz: float) -> tuple[TickLoop, list[Any]]:
    """A started loop (not its thread: ``run_iterations`` drives it) and its records."""
    loop = TickLoop(
        SimConfig(tick_hz=hz),
        None,
        source_factory=lambda config, calibration: source,
        clock=clock,
        auto_restart_s=None,
    )
    records: list[Any] = []
    loop.bus.subscribe(lambda record, raw: records.append(record))
    loop.start_sim()
    return loop, records


def test_loop_relays_a_paced_source_without_its_own_schedule() -> None:
    plan = [(0.001, 0), (0.002, 0), (0.040, 3), (0.0, 0)]
    source = _PacedSource(plan)
    clock = FakeClock()
    loop, records = _started_loop(source, clock, 20.0)
    loop.run_iterations(len(plan))  # no waiting on the loop's clock: the source paces
    assert clock.now() == 0.0 and source.steps == len(plan) and loop.ticks == len(plan)
    # the step latency is the source's: its deadline → its release (ms)
    steps = [r.timings_ms["step"] for r in records]
    np.testing.assert_allclose(steps, [1e3 * late for late, _ in plan], atol=1e-6)
    assert all(r.timings_ms["relay"] >= s for r, s in zip(records, steps, strict=True))
    assert loop.dropped == 3  # the source's missed deadlines are counted here
    # a finished paced source: the loop falls back to its own schedule (nothing to step)
    loop.run_iterations(3)
    assert source.steps == len(plan)
    # stop_sim pauses the source's schedule
    loop.stop_sim()
    assert source.paused == 1


def test_step_latency_counts_from_the_workers_deadline() -> None:
    """The worker's deadline is where the latency starts: a worker that wakes up late adds its
    lateness to the step time (the worker's loop in this process, on the fake clock)."""

    class Steady:
        done = False

        def __init__(self, config: Any, calibration: Any) -> None:
            pass

        def step(self) -> Any:
            return FakeSimState()

    clock = FakeClock()
    loop = TickLoop(
        SimConfig(tick_hz=10.0),
        None,
        source_factory=inline_sim(Steady, clock=clock),
        clock=clock,
        auto_restart_s=None,
    )
    records: list[Any] = []
    loop.bus.subscribe(lambda record, raw: records.append(record))
    loop.start_sim()
    loop.run_iterations(1)  # deadline 0: on time
    clock.advance(0.1 + 0.03)  # the next deadline (0.1) passed 30 ms ago
    loop.run_iterations(1)
    assert len(records) == 2 and loop.dropped == 0
    assert records[0].timings_ms["step"] < 30.0
    assert records[1].timings_ms["step"] >= 30.0 - 1e-6
    assert records[1].timings_ms["relay"] >= records[1].timings_ms["step"]


def test_service_controls_never_wait_for_the_paced_tick_thread(tmp_path: Any) -> None:
    """The tick thread waits for the worker's next tick without holding a lock: requests
    (ping, a new config, stop/start) go ahead at once, and stopping pauses the worker's
    schedule (no tick, no error) until the simulation is started again."""
    from fastapi.testclient import TestClient

    from app.server.main import create_app
    from app.service.settings import Settings

    settings = Settings(
        viser_enabled=False, recordings_dir=tmp_path / "rec", sim_auto_restart_s=None
    )
    with TestClient(create_app(settings)) as c:
        st = c.app.state.aar  # type: ignore[attr-defined]
        loop, worker = st.loop, st.sim_worker
        t0 = time.monotonic()
        while loop.ticks < 5:
            assert time.monotonic() - t0 < 10, "no ticks"
            time.sleep(0.02)
        t = time.monotonic()
        assert worker.ping() == worker.pid
        r = c.put("/api/v1/sim/config", json={"seed": 3})
        assert r.status_code == 200
        assert time.monotonic() - t < 3.0  # not starved by the tick thread (a run: ≈ 20 s)
        assert c.post("/api/v1/sim/stop").status_code == 200
        time.sleep(0.1)
        n = loop.ticks
        time.sleep(0.5)
        assert loop.ticks == n and worker._pacing is None  # paused: nothing released
        assert c.post("/api/v1/sim/start").status_code == 200
        while loop.ticks < n + 5:
            assert time.monotonic() - t < 15, "no ticks after the restart"
            time.sleep(0.02)
        assert loop.errors == 0 and worker.restarts == 0
